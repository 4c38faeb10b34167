"""--method dibr (dibr/method.py): parameters, wiring into ibr-render and report.json, and
accuracy on real data (benchmarks/bench_dibr_accuracy.py protocols)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import need_data, shared_data
from ibrtools import _core
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, InputError, ParamError
from ibrtools import methods
from ibrtools.dibr.method import DibrMethod, DibrParams
from ibrtools.scene import Scene, View
from ibrtools_cli import render
from conftest import synth_scene_dir

needs_kernel = pytest.mark.skipif(not hasattr(_core, "DibrAccumulator"),
                                  reason="_core.DibrAccumulator (the DIBR kernel) is not built")


def _plane_scene(n=3, depth_ok=True):
    views = []
    for i in range(n):
        cam = Camera.from_fov(32, 24, 60, look_at((0.2 * i, 0, -2), (0, 0, 0)))
        depth = np.full((24, 32), 2.0, np.float32) if depth_ok else None
        views.append(View.create(f"v{i}", cam, color=np.full((24, 32, 3), 0.5, np.float32), depth=depth))
    return Scene(views=views)


# --- parameters --------------------------------------------------------------------------
def test_params_defaults_and_forms():
    p = DibrParams.from_dict(None)
    assert p.inputs == 4 and p.quality == "side" and p.blend_exponent == 5.0
    assert DibrParams.from_dict({"inputs": "2"}).inputs == 2
    assert DibrParams.from_dict({"inputs": "v1, v2"}).inputs == ["v1", "v2"]
    assert DibrParams.from_dict({"inputs": ["a"]}).inputs == ["a"]
    for q in ("side", "shape", "depth", "normal"):
        assert DibrParams.from_dict({"quality": q}).quality == q


@pytest.mark.parametrize("params, flag", [
    ({"inputs": 0}, "inputs"), ({"inputs": -2}, "inputs"), ({"inputs": 2.5}, "inputs"),
    ({"inputs": "a,,b"}, "inputs"), ({"inputs": "a,a"}, "inputs"), ({"inputs": True}, "inputs"),
    ({"inputs": {}}, "inputs"),
    ({"quality": "best"}, "quality"), ({"quality": 3}, "quality"),
    ({"blend_exponent": 0}, "blend_exponent"), ({"blend_exponent": -1}, "blend_exponent"),
    ({"blend_exponent": "x"}, "blend_exponent"), ({"blend_exponent": float("nan")}, "blend_exponent"),
    ({"side_threshold": -1}, "side_threshold"), ({"samples": 0}, "samples"), ({"seed": 1.5}, "seed"),
    ({"bogus": 1}, "no parameter"),
])
def test_bad_params_name_the_option(params, flag):
    with pytest.raises(ParamError, match=flag) as e:
        DibrMethod(params)
    assert e.value.param == (None if flag == "no parameter" else flag)


def test_prepare_rejects_views_without_depth_and_unknown_inputs():
    with pytest.raises(InputError, match="method .dibr.: needs depth"):
        DibrMethod().prepare(_plane_scene(depth_ok=False))
    with pytest.raises(InputError, match="no input views"):
        DibrMethod().prepare(Scene(views=[]))
    with pytest.raises(ParamError, match="parameter inputs: .*'nope'"):
        DibrMethod({"inputs": "v0,nope"}).prepare(_plane_scene())
    s = _plane_scene()
    s.views[1] = View.create("v1", s.views[1].camera, color=s.views[1].color,
                             depth=lambda: np.zeros((24, 32), np.float32))
    with pytest.raises(InputError, match="no valid depth"):  # found when prepare loads it
        DibrMethod().prepare(s)


def test_auto_picks_dibr_for_depth_views_and_reference_otherwise():
    assert methods.resolve("auto", _plane_scene()) == "dibr"
    from ibrtools.errors import NotBuiltError
    with pytest.raises(NotBuiltError, match="dibr needs depth"):
        methods.resolve("auto", _plane_scene(depth_ok=False))
    assert methods.resolve("dibr", _plane_scene()) == "dibr"


def test_selection_uses_listed_inputs_only():
    m = DibrMethod({"inputs": "v2,v0"})
    m.prepare(_plane_scene())
    sel = m.select(_plane_scene().views[1].camera)
    assert sorted(sel.indices) == [0, 2]


# --- end to end --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return synth_scene_dir(tmp_path_factory, "--views", "8", "--size", "96x72", name="dibr")


@needs_kernel
def test_cli_holdout_report_lists_selection_and_stage_times(scene_dir, tmp_path):
    out = tmp_path / "o"
    assert render.main([str(scene_dir), "--method", "dibr", "--holdout", "v003", "--inputs", "3",
                        "--blend-exponent", "5", "--quality", "side", "-o", str(out), "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["method"] == "dibr" and rep["params"]["inputs"] == 3
    f = rep["frames"][0]
    assert 1 <= len(f["selected"]) <= 3 and "v003" not in f["selected"]
    assert f["skipped_no_overlap"] >= 0 and f["candidates"] == 7
    for stage in ("select", "warp", "blend"):
        assert f["time_ms"][stage] >= 0
    # Synthetic objects from 3 neighbouring views: measured 24.0 dB on covered object pixels
    # (shading differs between views, 96x72 inputs resample coarsely); 22 dB catches a broken
    # warp (a wrong pose or axis gives < 15 dB) without flaking. The background has no depth,
    # so coverage is about the objects' share of the image.
    assert f["metrics"]["psnr_covered"] > 22 and f["metrics"]["coverage"] > 0.3


@needs_kernel
def test_cli_named_inputs_and_bad_values(scene_dir, tmp_path, capsys):
    out = tmp_path / "n"
    assert render.main([str(scene_dir), "--method", "dibr", "--holdout", "v003", "--inputs", "v002,v004",
                        "-o", str(out), "-q"]) == 0
    f = json.loads((out / "report.json").read_text())["frames"][0]
    assert set(f["selected"]) <= {"v002", "v004"} and f["candidates"] == 2
    for argv, msg in ((["--inputs", "0"], "--inputs"), (["--inputs", "v003"], "--inputs"),
                      (["--quality", "nice"], "--quality"), (["--blend-exponent", "-1"], "--blend-exponent")):
        assert render.main([str(scene_dir), "--method", "dibr", "--holdout", "v003", *argv,
                            "-o", str(tmp_path / "bad"), "-q"]) == 2
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err


# --- real data ---------------------------------------------------------------------------
DATA = shared_data()


@pytest.fixture(scope="module")
def bench(dibr_accuracy_bench):
    return dibr_accuracy_bench


_need = need_data


def test_bench_scoring_three_ways(bench):
    # Synthetic check of the bench's scoring: a 4x4 frame equal to the truth except one hole
    # (black) whose truth equals its neighbours: excluded and nearest-filled are exact (PSNR
    # capped by metrics.psnr), black is not; hole fraction 1/16.
    pytest.importorskip("scipy")
    truth = np.full((4, 4, 3), 0.5, np.float32)
    color = truth.copy()
    hole = np.zeros((4, 4), bool)
    hole[1, 2] = True
    color[hole] = 0.0
    t = bench.three_ways(color, truth, hole)
    assert t["hole"] == pytest.approx(1 / 16)
    assert t["excluded"] > 60 and t["filled"] > 60 and t["black"] < 20
    assert bench.nearest_fill(color, hole)[1, 2] == pytest.approx(truth[1, 2])


def test_default_side_threshold_is_rvs():
    # RVS 4.0: q = clamp(10000 - 1000 L, 1, 10000), i.e. T = 10 target pixels (docs/dibr.md).
    assert DibrParams.from_dict({}).side_threshold == 10.0


# Floors ~0.5 dB below what was measured (docs/dibr.md, T = 10 px, stretched-only pixels as
# holes): lego r_0 object / all; ICL holes excluded 33.46, nearest-filled 32.57; Teddy holes
# excluded 29.27, nearest-filled 29.00; Cones 27.92 / 27.61 dB. They guard against regressions (a warp offset of one
# pixel costs 4-5 dB on Middlebury); they are below the RVS targets, which are not all reached.
@needs_kernel
def test_real_lego_heldout(bench):
    _need("nerf_lego")
    r = bench.lego(DATA, heldout=("r_0",))
    # r_50 and r_150 reach 28 dB: each has a near-duplicate camera among the inputs; r_0 and
    # r_100 do not, and the 8-bit depth (steps ~0.8 % of the depth) misregisters by ~1 px there.
    assert r["psnr_object"] > 19.2 and r["psnr_all"] > 22.8


@needs_kernel
def test_real_icl_frame4_from_1_and_5(bench):
    _need("icl_nuim_livingroom")
    r = bench.icl(DATA)
    assert r["psnr_visible"] > 32.6 and r["hole"] < 0.1
    if r["all"]["filled"] is not None:
        assert r["all"]["filled"] > 32.0


@needs_kernel
@pytest.mark.parametrize("name, excluded, filled", [("Teddy", 28.7, 28.5), ("Cones", 27.4, 27.1)])
def test_real_middlebury_right_from_left(bench, name, excluded, filled):
    _need(f"middlebury/{name}")
    r = bench.middlebury(DATA, name)
    # "filled" is RVS's protocol (holes take the nearest covered colour). Holes black is not
    # floored: stretched-only pixels are holes by design, so it measures hole count.
    assert r["vis"]["excluded"] > excluded and r["hole_visible"] < 0.03
    if r["vis"]["filled"] is not None:
        assert r["vis"]["filled"] > filled
