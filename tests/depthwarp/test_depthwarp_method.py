"""--method depthwarp (ibrtools.depthwarp.method) and the issue-4 synthetic paths: parameters,
depth scores, the report, the command's flags and bad input. The warp itself is
ibrtools.depthwarp.core's (tested in its own files); the end-to-end tests need it built."""
from __future__ import annotations

import json

import numpy as np
import pytest

from ibrtools import synth
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, InputError
from ibrtools.pipeline import job as render_job
from ibrtools.pipeline import plan as planning
from ibrtools.depthwarp.method import (DepthWarpMethod, DepthWarpMethodParams, depth_scores, far_depth, fill_background,
                                       visualise)
from ibrtools.scene import Scene, View

try:
    import ibrtools.depthwarp.core  # noqa: F401

    HAVE_WARP = True
except ImportError:
    HAVE_WARP = False
needs_warp = pytest.mark.skipif(not HAVE_WARP, reason="ibrtools.depthwarp.core (the warp kernels) not built yet")

SIZE = (96, 54)


@pytest.fixture(scope="module")
def crowd():
    return synth.make_scene("crowd", size=SIZE, views=1, holdout_targets=0, path_frames=4)


# --- parameters ------------------------------------------------------------------------------
def test_params_defaults_and_checks():
    p = DepthWarpMethodParams.from_dict(None)
    assert (p.layers, p.seeds, p.iters, p.forward, p.ground) == (3, 16, 3, "none", "none")
    assert DepthWarpMethodParams.from_dict({"layers": "2", "umbra": "true", "ground": "none"}).umbra is True
    for bad, msg in [({"layers": 0}, "layers"), ({"seeds": -1}, "seeds"), ({"iters": 0.5}, "iters"),
                     ({"forward": "splat"}, "forward"), ({"threshold": 0}, "threshold"),
                     ({"umbra": "maybe"}, "umbra"), ({"ground": -2}, "ground"), ({"bound": "loose"}, "bound"),
                     ({"nope": 1}, "no parameter")]:
        with pytest.raises(BadValueError, match=msg):
            DepthWarpMethodParams.from_dict(bad)


# --- scores ----------------------------------------------------------------------------------
def test_depth_scores_definition():
    rng = np.random.default_rng(0)
    ref = rng.uniform(2.0, 8.0, (32, 40)).astype(np.float32)
    s = depth_scores(ref.copy(), np.zeros(ref.shape, bool), ref, 10.0)
    assert s["depth_psnr"] is None and s["depth_ssim"] == pytest.approx(1.0) and s["hole_fraction"] == 0
    # A uniform error of 0.1 (1 % of far = 10): PSNR = 10 log10(1 / 0.01^2) = 40 dB (float32 rounding).
    s = depth_scores(ref + 0.1, None, ref, 10.0)
    assert s["depth_psnr"] == pytest.approx(40.0, abs=1e-3)
    # Holes take the background depth around them: a hole on a step edge between a near
    # (2 m) and a far (6 m) half is filled from the far side; a frame that is all hole is far.
    step = np.full((16, 16), 2.0, np.float32)
    step[:, 8:] = 6.0
    hole = np.zeros(step.shape, bool)
    hole[:, 6:10] = True
    filled = fill_background(np.where(hole, 0, step).astype(np.float32), hole, 10.0)
    assert (filled[:, 6:10] == 6.0).all() and (filled[~hole] == step[~hole]).all()
    assert (fill_background(np.zeros((4, 4), np.float32), np.ones((4, 4), bool), 10.0) == 10.0).all()
    s = depth_scores(np.where(hole, 0, step).astype(np.float32), hole, np.where(hole, 6.0, step), 10.0)
    assert s["depth_psnr"] is None and s["hole_fraction"] == 0.25
    # Scored as culling sees them, the holes are at far (10): columns 6-7 (near half, 2 m) are off by
    # 0.8 of far and columns 8-9 (6 m) by 0.4: MSE = (2 * 0.8^2 + 2 * 0.4^2) / 16 of z / far.
    s = depth_scores(np.where(hole, 0, step).astype(np.float32), hole, step, 10.0, holes="far")
    assert s["depth_psnr"] == pytest.approx(10 * np.log10(16 / (2 * 0.8**2 + 2 * 0.4**2)), abs=1e-3)
    with pytest.raises(BadValueError, match="far"):
        depth_scores(ref, None, ref, 0.0)
    with pytest.raises(BadValueError, match="holes"):
        depth_scores(ref, None, ref, 10.0, holes="zero")


def test_far_depth_and_visualise():
    cam = Camera.from_fov(8, 6, 60.0, look_at((0, 0, -5), (0, 0, 0), (0, -1, 0)))
    assert far_depth(np.array([[-1.0, -1, -1], [1, 1, 1]]), cam) == pytest.approx(6.0)
    img = visualise(np.array([[0.0, 3.0], [6.0, 12.0]], np.float32), 6.0)
    assert img.shape == (2, 2, 3) and img.dtype == np.float32
    assert img[0, 0, 0] == 0 and img[1, 0, 0] == 0 and img[1, 1, 0] == 0 and 0 < img[0, 1, 0] < 1


# --- method set-up errors --------------------------------------------------------------------
def test_scene_without_geometry_is_an_input_error():
    cam = Camera.from_fov(16, 12, 60.0)
    scene = Scene(views=[View.create("v", cam, color=np.zeros((12, 16, 3), np.float32))])
    with pytest.raises(InputError, match="geometry"):
        DepthWarpMethod().prepare(scene)


@needs_warp
def test_bad_ground_and_camera(crowd):
    with pytest.raises(BadValueError, match="ground"):
        DepthWarpMethod({"ground": 99999}).prepare(crowd)
    with pytest.raises(BadValueError, match="layers >= 2"):
        DepthWarpMethod({"ground": 0, "layers": 1}).prepare(crowd)
    m = DepthWarpMethod()
    m.prepare(crowd)
    with pytest.raises(BadValueError, match="not supported by depthwarp"):
        m.render(Camera.equirect(32, 16))


# --- end to end --------------------------------------------------------------------------------
@needs_warp
def test_static_camera_warps_exactly(crowd):
    """Zero motion: the warp returns the previous frame's depth, which is the reference."""
    cam = crowd.paths["walk"][1]
    job = planning.Job(crowd, [planning.Frame("a", cam), planning.Frame("b", cam)])
    # No dilation: it would (rightly) fill sky pixels next to the horizon, which the reference
    # leaves empty.
    m = DepthWarpMethod({"layers": 1, "seeds": 4, "dilate": False, "far_plane": False})
    m.prepare(crowd)
    out0, st0 = m.render(cam)
    assert m.frame_report()["depthwarp"]["source"] is None and "reference" in st0
    out1, st1 = m.render(cam)
    ref = out0["depth"]
    np.testing.assert_array_equal(out1["depth"], ref)
    np.testing.assert_array_equal(out1["hole"], ref == 0)
    # With the far plane (default), the sky warps too: no hole at all, sky reported empty.
    m2 = DepthWarpMethod({"layers": 1, "seeds": 4, "dilate": False})
    m2.prepare(crowd)
    m2.render(cam)
    out2, _ = m2.render(cam)
    np.testing.assert_array_equal(out2["depth"], ref)
    assert not out2["hole"].any()
    s = m2.frame_metrics()
    assert s["depth_psnr"] is None and s["depth_ssim"] == pytest.approx(1.0)
    assert {"peel", "reference"} <= set(st1) and m.frame_report()["depthwarp"]["layers"] == 1
    del job


@needs_warp
@pytest.mark.parametrize("params", [{"layers": 2, "seeds": 4, "umbra": True, "cull": True, "ground": "auto"},
                                    {"layers": 2, "forward": "vfw"}])
def test_path_report(crowd, tmp_path, params):
    job = planning.plan(crowd, path="walk")
    rep = render_job.run(job, "depthwarp", tmp_path / "o", params=params, depth_out=True)
    assert rep["method"] == "depthwarp" and len(rep["frames"]) == 4
    f0, f1 = rep["frames"][0], rep["frames"][1]
    assert f0["depthwarp"]["source"] is None
    dw = f1["depthwarp"]
    assert dw["layers"] == 2 and dw["reference_ms"] > 0 and dw["warp_ms"] >= 0
    assert bool(dw["ground_layer"]) == (params.get("ground") == "auto")  # the default is plain peeling
    assert {"peel", "reference"} <= set(f1["time_ms"]) and "motion" in f1["time_ms"] or params.get("forward")
    m = f1["metrics"]
    assert m["depth_ssim"] > 0.5 and 0 <= m["hole_fraction"] <= 1
    if params.get("cull"):
        c = f1["cull"]
        assert c["objects"] == crowd.meshes["ground_truth"].num_objects and "falsely_culled_large" in c
        assert "cull" in f1["time_ms"]
        assert dw["dilate"] is False and dw["stats"]["dilated_pixels"] == 0  # culling needs conservative holes
    assert (tmp_path / "o" / f1["depth"]).is_file() and (tmp_path / "o" / f1["image"]).is_file()
    assert "mean_depth_ssim" in rep["summary"]
    json.dumps(rep, allow_nan=False)


@needs_warp
def test_cli_depthwarp(tmp_path, capsys):
    from ibrtools_cli import preprocess, render

    d = tmp_path / "s"
    assert preprocess.main(["synth:crowd", "-o", str(d), "--views", "1", "--size", "64x36", "-q"]) == 0
    out = tmp_path / "o"
    assert render.main([str(d), "--method", "depthwarp", "--path", "walk", "--layers", "2", "--seeds", "4",
                        "--iters", "2", "--oriented-bounds", "--umbra", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "depth PSNR" in text
    rep = json.loads((out / "report.json").read_text())
    assert rep["params"] == {"layers": 2, "seeds": 4, "iters": 2, "oriented_bounds": True, "umbra": True}


def test_cli_depthwarp_flags_need_the_method(tmp_path, capsys):
    from ibrtools_cli import preprocess, render

    d = tmp_path / "s"
    assert preprocess.main(["synth:objects", "-o", str(d), "--views", "2", "--size", "32x24", "-q"]) == 0
    assert render.main([str(d), "--method", "reference", "--path", "orbit", "--layers", "2",
                        "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "--layers: only with --method depthwarp" in err and "Traceback" not in err
    assert render.main([str(d), "--method", "depthwarp", "--path", "orbit", "--seeds", "0",
                        "-o", str(tmp_path / "o")]) == 2
    assert "--seeds" in capsys.readouterr().err
    assert not (tmp_path / "o" / "report.json").exists()


# --- synthetic paths ---------------------------------------------------------------------------
@pytest.mark.parametrize("preset", ["crowd", "city"])
def test_walk_and_stress_motion(preset):
    """Average maximal motion at 1920x1080, measured at 480x270 (image motion in pixels scales
    with the focal length, i.e. the width: x4; the max over pixels at 1/4 resolution differs from
    the full-resolution one by < 1 px x 4, hence the 2 px margin inside 15-35)."""
    mesh, built = synth.build_mesh(preset, size=(480, 270), views=1, holdout_targets=0, path_frames=6)
    walk = 4.0 * synth.path_motion(mesh, built.paths["walk"]).mean()
    stress = 4.0 * synth.path_motion(mesh, built.paths["stress"]).mean()
    assert 17.0 <= walk <= 33.0, walk
    assert stress >= 100.0, stress


def test_spheres_preset_is_high_polygon():
    mesh, built = synth.build_mesh("spheres", size=(32, 18), views=2, holdout_targets=1, path_frames=2)
    assert len(mesh.faces) > 1_000_000 and mesh.num_objects == 15
    assert {"orbit", "walk", "stress"} <= set(built.paths)


def test_path_motion_bad_input():
    mesh, built = synth.build_mesh("crowd", size=(32, 18), views=1, holdout_targets=0, path_frames=2)
    with pytest.raises(BadValueError, match="at least 2"):
        synth.path_motion(mesh, built.paths["walk"][:1])
    # A static pair has no motion.
    cam = built.paths["walk"][0]
    assert synth.path_motion(mesh, [cam, cam]).max() == pytest.approx(0.0, abs=1e-6)
