"""Typed method parameters (ibrtools.params): one dataclass per method, defaults and bounds defined
once, errors that name the parameter in the library and the flag in the commands."""
from __future__ import annotations

import dataclasses
import pickle

import pytest

from ibrtools import methods
from ibrtools import params as P
from ibrtools.errors import BadValueError, NotBuiltError, ParamError
from ibrtools_cli import bench, render

from conftest import synth_scene_dir


def test_every_built_method_has_typed_parameters_whose_defaults_pass_their_own_checks():
    for name in methods.BUILT:
        cls = methods.PARAMS[name]
        p = methods.check_params(name)
        assert type(p) is cls and dataclasses.is_dataclass(p)
        assert p.as_dict() == P.defaults(cls)  # the defaults are values the checks accept unchanged
        assert cls.from_dict(p) is p and cls.from_dict(p.as_dict()) == p
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(p, "x", 1)


def test_strings_of_param_flags_are_converted():
    p = methods.check_params("dibr", {"inputs": "2", "blend_exponent": "3", "stretched_holes": "off",
                                      "samples": "100", "quality": "shape"})
    assert (p.inputs, p.blend_exponent, p.stretched_holes, p.samples, p.quality) == (2, 3.0, False, 100, "shape")
    assert methods.check_params("depthwarp", {"ground": "Auto", "layers": 2.0}).as_dict()["ground"] == "auto"
    assert methods.check_params("hybrid", {"geo_threshold": "0.5", "pvm_floor": "0.25"}).geo_threshold == 0.5


def test_replace_checks_the_new_values():
    p = methods.check_params("ulr")
    assert p.replace(k=8).k == 8 and p.k == 4
    with pytest.raises(ParamError, match="parameter k: expected an integer >= 1 and <= 64, got 65"):
        p.replace(k=65)


@pytest.mark.parametrize("name, params, param, detail", [
    ("dibr", {"blend_exponent": 0}, "blend_exponent", "expected a finite number > 0 and <= 16, got 0"),
    ("dibr", {"samples": 10**6}, "samples", "expected an integer >= 1 and <= 100000, got 1000000"),
    ("dibr", {"quality": "best"}, "quality", "expected 'side', 'shape', 'depth' or 'normal', got 'best'"),
    ("warp", {"inputs": 3}, "inputs", "method 'warp' uses one input view"),
    ("depthwarp", {"umbra": "maybe"}, "umbra", "expected true or false, got 'maybe'"),
    ("depthwarp", {"ground": -1}, "ground", "expected auto, none or an object id"),
    ("pvm", {"sigma": 32, "radius_sigmas": 3}, "sigma * radius_sigmas", "expected <= 64 pixels"),
    ("hybrid", {"sigma": 40}, "sigma", "<= 32"),  # the PVM renderer's bound, through the hybrid
    ("hybrid", {"pvm_floor": "high"}, "pvm_floor", "expected 'auto' or a weight in [0, 1]"),
    ("reference", {"ambient": float("inf")}, "ambient", "expected a finite number"),
    ("tm", {"k": 3}, None, "method 'tm' has no parameter(s) ['k'] (parameters: none)"),
])
def test_bad_values_name_the_parameter(name, params, param, detail):
    with pytest.raises(ParamError) as e:
        methods.create(name, params)
    assert e.value.param == param and detail in e.value.detail
    assert str(e.value) == (detail if param is None else f"parameter {param}: {e.value.detail}")
    assert isinstance(e.value, BadValueError)
    again = pickle.loads(pickle.dumps(e.value))  # Dask workers send it back to the client
    assert (again.param, again.detail, str(again)) == (e.value.param, e.value.detail, str(e.value))


def test_unknown_or_unbuilt_methods():
    with pytest.raises(BadValueError, match="method: expected one of"):
        methods.check_params("nope")
    with pytest.raises(BadValueError):
        methods.check_params("auto")  # a name to resolve, not a method with parameters
    for name in set(methods.METHODS) - set(methods.BUILT) - {"auto"}:
        with pytest.raises(NotBuiltError):
            methods.check_params(name)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return synth_scene_dir(tmp_path_factory, "--views", "4", "--size", "32x24", name="params")


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def test_commands_name_the_flag_the_user_typed(scene_dir, tmp_path, capsys):
    base = [str(scene_dir), "--method", "dibr", "--holdout", "v001", "-o", str(tmp_path / "r")]
    assert render.main([*base, "--blend-exponent", "17"]) == 2
    assert _error(capsys) == "ibr-render: error: --blend-exponent: expected a finite number > 0 and <= 16, got 17"
    assert render.main([*base, "--param", "blend_exponent=17"]) == 2
    assert _error(capsys).startswith("ibr-render: error: --param blend_exponent: expected a finite number")
    assert render.main([*base, "--param", "colour=1"]) == 2
    assert _error(capsys).startswith("ibr-render: error: --param: method 'dibr' has no parameter(s) ['colour']")
    assert render.main([*base, "--inputs", "v000,nope"]) == 2  # found when the scene is read
    assert _error(capsys).startswith("ibr-render: error: --inputs: view(s) ['nope'] not among the input views")
    out = tmp_path / "b"
    assert bench.main([str(scene_dir), "--method", "dibr", "--sweep", "samples=10:0", "-o", str(out)]) == 2
    assert _error(capsys) == "ibr-bench: error: --sweep samples: expected an integer >= 1 and <= 100000, got 0"
    assert bench.main([str(scene_dir), "--method", "dibr", "--param", "seed=-1", "-o", str(out)]) == 2
    assert _error(capsys) == "ibr-bench: error: --param seed: expected an integer >= 0, got -1"
    assert not out.exists() and not (tmp_path / "r").exists()


def test_the_api_takes_the_typed_form(scene_dir, tmp_path):
    import ibrtools

    scene = ibrtools.load_scene(scene_dir)
    typed = methods.check_params("dibr", {"inputs": 2})
    report = ibrtools.render_job(scene, tmp_path / "o", "dibr", holdout=["v001"], params=typed, metrics="psnr")
    assert report["params"] == typed.as_dict() and len(report["frames"]) == 1
    by_dict = ibrtools.render_job(scene, tmp_path / "d", "dibr", holdout=["v001"], params={"inputs": 2},
                                  metrics="psnr")
    assert report["frames"][0]["metrics"]["psnr"] == by_dict["frames"][0]["metrics"]["psnr"]
