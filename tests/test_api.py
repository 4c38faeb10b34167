"""The Python API (docs/api.md): ibrtools.load_scene, Scene.render, RenderResult, top-level names,
lazy imports, doctests of the public modules, and every bad input of the API."""
from __future__ import annotations

import copy
import doctest
import gc
import json
import pickle
import subprocess
import sys
import threading
import weakref
from pathlib import Path

import numpy as np
import pytest

import ibrtools
from ibrtools import api
from ibrtools.errors import BadValueError, DtypeError, FormatError, MissingFileError, ParamError

SIZE = (64, 48)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from ibrtools import synth
    from ibrtools.formats import native

    d = tmp_path_factory.mktemp("api") / "scene"
    native.save(synth.make_scene("objects", size=SIZE, views=4, holdout_targets=1, path_frames=2), d)
    return d


@pytest.fixture
def scene(scene_dir):
    return ibrtools.load_scene(scene_dir)


# --- doctests: the examples in the docstrings run -----------------------------------------------------
@pytest.mark.parametrize("module", [ibrtools, api], ids=lambda m: m.__name__)
def test_doctests(module, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert res.attempted > 0
    assert res.failed == 0


def test_api_page_examples(tmp_path, monkeypatch):
    """docs/api.md's examples of every API function run as written."""
    monkeypatch.chdir(tmp_path)
    page = Path(__file__).resolve().parents[1] / "docs" / "api.md"
    res = doctest.testfile(str(page), module_relative=False,
                           optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert res.attempted >= 10 and res.failed == 0


def test_pipeline_functions_reject_bad_arguments(scene, tmp_path):
    with pytest.raises(DtypeError, match="save_scene: scene: expected an ibrtools.Scene"):
        ibrtools.save_scene("scene", tmp_path / "s")  # type: ignore[arg-type]
    with pytest.raises(DtypeError, match="import_dataset: source: expected a str"):
        ibrtools.import_dataset(3, tmp_path / "s")  # type: ignore[arg-type]
    with pytest.raises(BadValueError, match="unknown preset"):
        ibrtools.import_dataset("synth:nope", tmp_path / "s")
    with pytest.raises(BadValueError, match="synth: unknown option"):
        ibrtools.import_dataset("synth:objects", tmp_path / "s", synth={"colour": 1})
    with pytest.raises(BadValueError, match="synth: only for a synth:NAME source"):
        ibrtools.import_dataset(tmp_path, tmp_path / "s", synth={"views": 2})
    with pytest.raises(MissingFileError, match="preprocess: .*no scene.json"):
        ibrtools.preprocess(tmp_path)
    with pytest.raises(DtypeError, match="render_job: scene: expected an ibrtools.Scene"):
        ibrtools.render_job(None, tmp_path / "o")  # type: ignore[arg-type]
    with pytest.raises(DtypeError, match="bench: grid: expected a dict"):
        ibrtools.bench(scene, "dibr", [1, 2])  # type: ignore[arg-type]
    assert not (tmp_path / "s").exists() and not (tmp_path / "o").exists()  # nothing half-written


# --- load_scene -----------------------------------------------------------------------------------------
def test_load_scene(scene_dir):
    s = ibrtools.load_scene(scene_dir)
    assert isinstance(s, ibrtools.Scene)
    assert [v.name for v in s.views] == ["v000", "v001", "v002", "v003"]
    assert s.views[0].color.shape == (SIZE[1], SIZE[0], 3)
    # str path and the scene.json itself are accepted too
    assert [t.name for t in ibrtools.load_scene(str(scene_dir / "scene.json")).targets] == ["t000"]


def test_load_scene_bad_input(tmp_path, scene_dir):
    with pytest.raises(MissingFileError, match=r"load_scene: .*nothere: no such directory"):
        ibrtools.load_scene(tmp_path / "nothere")
    f = tmp_path / "image.png"
    f.write_bytes(b"not a scene")
    with pytest.raises(FormatError, match=r"load_scene: .*image.png: a file, not a scene directory"):
        ibrtools.load_scene(f)
    with pytest.raises(FormatError, match=r"load_scene: .*: no scene.json in this directory"):
        ibrtools.load_scene(tmp_path)
    with pytest.raises(DtypeError, match="load_scene: path: expected a str or os.PathLike, got int"):
        ibrtools.load_scene(3)  # type: ignore[arg-type]
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "scene.json").write_text("{\"format\": \"something else\"}")
    with pytest.raises(FormatError, match="not an ibrtools scene"):
        ibrtools.load_scene(bad)


# --- Scene.render -----------------------------------------------------------------------------------------
def test_render_camera_forms(scene):
    by_name = ibrtools.render(scene, "t000", method="reference")
    by_cam = ibrtools.render(scene, scene.target("t000").camera, method="reference")
    by_dict = ibrtools.render(scene, scene.target("t000").camera.to_dict(), method="reference")
    by_view = ibrtools.render(scene, "v001", method="reference")
    for r in (by_name, by_cam, by_dict, by_view):
        assert isinstance(r, api.RenderResult)
        assert r.method == "reference"
        assert r.color.shape == (SIZE[1], SIZE[0], 3) and r.color.dtype == np.float32
        assert r.color.flags.c_contiguous
        assert r.depth is not None and r.depth.shape == (SIZE[1], SIZE[0])
        assert r.hole is not None and r.hole.dtype == np.bool_
        assert r.selection is None
        assert set(r.times_ms) == {"raycast_shade", "total"}
        assert set(r.setup_ms) == {"bvh"}
    # one deterministic ray caster: the three forms of one camera give one image
    np.testing.assert_array_equal(by_name.color, by_cam.color)
    np.testing.assert_array_equal(by_name.color, by_dict.color)
    # the reference renderer made the synthetic views: it reproduces v001 (PNG quantisation:
    # 8-bit sRGB steps are at most ~1/255 * 1/0.0031 ~ 0.005 in linear at the bright end)
    truth = scene.view("v001").color
    assert np.abs(by_view.color - truth).max() < 0.01


def test_render_auto_and_params(scene):
    r = ibrtools.render(scene, "t000")
    assert r.method == "dibr"  # colour + depth views: auto picks DIBR
    assert r.hole is not None and 0.5 < r.coverage <= 1.0
    assert "confidence" in r.outputs
    assert {"select", "warp", "blend", "total"} <= set(r.times_ms)
    r2 = ibrtools.render(scene, "t000", method="dibr", inputs=["v000", "v001"], blend_exponent=3)
    assert r2.prepared and r2.method == "dibr"


def test_render_matches_ibr_render_job(scene, tmp_path):
    """Scene.render is the job's renderer: the float image ibr-render writes is the same, bit for bit."""
    from ibrtools.imageio import read_image
    from ibrtools.pipeline import job
    from ibrtools.pipeline import plan as planning
    r = ibrtools.render(scene, "t000", method="dibr", inputs=2)
    j = planning.plan(scene, targets=["t000"])
    job.run(j, "dibr", tmp_path / "out", params={"inputs": 2}, float_out=True)
    written = read_image(tmp_path / "out" / "t000.exr")
    np.testing.assert_array_equal(r.color, written)
    assert r.hole is not None and r.hole.any()
    assert r.color[r.hole].any()  # holes filled by default, as the job writes them
    black = ibrtools.render(scene, "t000", method="dibr", inputs=2, inpaint="none")
    assert not black.color[black.hole].any()  # inpaint none: black holes
    np.testing.assert_array_equal(black.color[~black.hole], r.color[~r.hole])


def test_render_prepares_once(scene, monkeypatch):
    from ibrtools import methods

    created: list[str] = []
    real_create = methods.create

    def counting_create(name, params=None):
        created.append(name)
        return real_create(name, params)

    monkeypatch.setattr(methods, "create", counting_create)
    first = ibrtools.render(scene, "t000", method="dibr", inputs=2)
    cams = scene.paths["orbit"]
    rest = [ibrtools.render(scene, c, method="dibr", inputs=2) for c in cams]
    assert first.prepared and not any(r.prepared for r in rest)
    assert created == ["dibr"]
    assert rest[0].setup_ms == first.setup_ms  # the setup paid by the first call, reported again
    # "auto" resolves to dibr on this scene and shares the prepared method
    assert not ibrtools.render(scene, "t000", inputs=2).prepared
    # other parameters (order-independent key) = another preparation; a list value is fine
    assert ibrtools.render(scene, "t000", method="dibr", inputs=["v000", "v002"], seed=1).prepared
    assert not ibrtools.render(scene, "t000", method="dibr", seed=1, inputs=["v000", "v002"]).prepared
    assert created == ["dibr", "dibr"]
    # replacing the views (another list of other View objects) invalidates the prepared methods
    scene.views = scene.views[:3]
    assert ibrtools.render(scene, "t000", method="dibr", inputs=2).prepared
    ibrtools.clear_render_cache(scene)
    assert ibrtools.render(scene, "t000", method="dibr", inputs=2).prepared
    assert len(created) == 4


def test_render_cache_and_lazy_meshes(scene_dir):
    # A loaded scene's meshes are read when a method asks: dibr never does, reference once; the
    # cache compares the mapping and its version, so reading a mesh does not prepare again, and
    # replacing one does.
    s = ibrtools.load_scene(scene_dir)
    assert ibrtools.render(s, "t000", method="dibr", inputs=2).prepared
    assert "not read yet" in repr(s.meshes)
    assert not ibrtools.render(s, "t000", method="dibr", inputs=2).prepared
    assert ibrtools.render(s, "t000", method="reference").prepared
    assert "not read yet" not in repr(s.meshes)
    assert not ibrtools.render(s, "t000", method="reference").prepared
    s.meshes["ground_truth"] = s.meshes["ground_truth"]  # set again: another mesh as far as caches know
    assert ibrtools.render(s, "t000", method="reference").prepared


def test_render_cache_goes_with_the_scene(scene_dir):
    s = ibrtools.load_scene(scene_dir)
    ibrtools.render(s, "t000", method="reference")
    # pickling / copying (Dask scatters scenes) ships no prepared method
    s2 = pickle.loads(pickle.dumps(s))
    assert ibrtools.render(s2, "t000", method="reference").prepared
    assert ibrtools.render(copy.deepcopy(s), "t000", method="reference").prepared
    ref = weakref.ref(s)
    del s
    gc.collect()
    assert ref() is None  # the prepared methods did not keep the scene alive


def test_core_accepts_unpickled_arrays():
    """An array that crossed a pickle (Dask workers) has an equal dtype that is another object;
    the C++ boundary (cpp/bindings/array.h) compares dtypes by equality, not identity."""
    from ibrtools import _core

    a = pickle.loads(pickle.dumps(np.zeros((4, 3), np.float32)))
    assert a.dtype == np.float32 and a.dtype is not np.dtype(np.float32)
    scene = _core.RayScene(a, pickle.loads(pickle.dumps(np.array([[0, 1, 2]], np.int32))))
    assert scene.num_faces == 1
    with pytest.raises(DtypeError, match="vertices: expected float32"):
        _core.RayScene(a.astype(">f4"), np.array([[0, 1, 2]], np.int32))


def test_render_threads(scene):
    """Calls from several threads on one scene are serialised and give the same image."""
    ref = ibrtools.render(scene, "t000", method="dibr", inputs=2).color
    out: list[np.ndarray] = []
    ts = [threading.Thread(target=lambda: out.append(ibrtools.render(scene, "t000", method="dibr", inputs=2).color))
          for _ in range(3)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert len(out) == 3
    for o in out:
        np.testing.assert_array_equal(o, ref)


def test_result_save(scene, tmp_path):
    from ibrtools.imageio import read_image

    r = ibrtools.render(scene, "t000", method="reference")
    p = r.save(tmp_path / "t000.exr")
    np.testing.assert_array_equal(read_image(p), r.color)


def test_render_bad_input(scene):
    with pytest.raises(BadValueError, match=r"method: unknown method 'nerf' \(expected one of auto, "):
        ibrtools.render(scene, "t000", method="nerf")
    with pytest.raises(DtypeError, match="method: expected a method name"):
        ibrtools.render(scene, "t000", method=3)  # type: ignore[arg-type]
    with pytest.raises(BadValueError, match=r"camera 'nowhere': not a target or view of the scene "
                                            r"\(targets: t000; views: v000, v001, v002, v003\)"):
        ibrtools.render(scene, "nowhere")
    with pytest.raises(FormatError, match=r"camera: missing key 'fx'"):
        ibrtools.render(scene, {"model": "pinhole", "width": 8, "height": 6, "cam_from_world": np.eye(4).tolist()})
    scaled = np.diag([2.0, 2.0, 2.0, 1.0]).tolist()
    with pytest.raises(BadValueError, match=r"camera.cam_from_world: not a rigid pose"):
        ibrtools.render(scene, {"model": "pinhole", "width": 8, "height": 6, "fx": 5, "fy": 5, "cx": 4, "cy": 3,
                      "cam_from_world": scaled})
    with pytest.raises(DtypeError, match="camera: expected a Camera, a target or view name"):
        ibrtools.render(scene, 42)  # type: ignore[arg-type]
    with pytest.raises(BadValueError, match=r"method 'dibr' has no parameter\(s\) \['colour'\]"):
        ibrtools.render(scene, "t000", method="dibr", colour=1)
    with pytest.raises(ParamError, match="parameter blend_exponent: expected a finite number > 0 and <= 16, got -1"):
        ibrtools.render(scene, "t000", method="dibr", blend_exponent=-1)
    with pytest.raises(DtypeError, match="scene: expected an ibrtools.Scene"):
        api.render("not a scene", "t000")  # type: ignore[arg-type]


def test_render_not_built_for_the_data():
    """auto on views without depth nor a mesh: the typed NotBuiltError that says what to do."""
    cam = ibrtools.Camera.from_fov(8, 6, 60.0)
    s = ibrtools.Scene(views=[ibrtools.View.create("a", cam, color=np.zeros((6, 8, 3), np.float32))])
    with pytest.raises(ibrtools.NotBuiltError, match="method 'auto'"):
        ibrtools.render(s, "a")


# --- the package's top level ------------------------------------------------------------------------
def test_top_level_names():
    assert ibrtools.load_scene is api.load_scene
    assert ibrtools.RenderResult is api.RenderResult
    for name in ibrtools.__all__:
        assert getattr(ibrtools, name) is not None
        assert name in dir(ibrtools)
    assert ibrtools.synth.make_scene is not None  # lazy sub-module
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        ibrtools.nope  # noqa: B018


def test_import_is_light():
    """``import ibrtools`` loads neither the C++ engine nor open3d nor the render methods."""
    code = ("import sys, ibrtools; heavy = [m for m in ('ibrtools._core', 'open3d', 'ibrtools.api', "
            "'ibrtools.methods', 'ibrtools.pipeline', 'OpenImageIO') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert json.loads(out.replace("'", '"')) == []
