"""Single-view warp with background-depth holes (cpp/kernels/dibr/forward_warp.h "Warp with
background-depth holes", _core.warp_with_holes / warp_flow, dibr/warp.py, --method warp).

Tolerances:
* Identity / integer shifts: vertices land exactly on pixel centres (1/256 px snap of an exact
  value), barycentrics are 0/1 up to float rounding of (E + bias) / area2: colour and depth to
  1e-6 relative.
* Disoccluded strip: its columns follow from the analytic shifts fx * b / z of the two planes
  (pixel centres are >= 0.1 px from the strip's ends in this set-up, far above the 1/512 px snap),
  so the strip is compared exactly; its depth is the background plane's z exactly (a flat write of
  a corner's 1 / (1 / z) in float: rtol 1e-6).
"""
from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from ibrtools import BadValueError, Camera, DtypeError, ShapeError, _core
from ibrtools.errors import InputError
from ibrtools.dibr.warp import WarpMethod, WarpParams
from ibrtools_cli import render
from conftest import synth_scene_dir

pytestmark = [pytest.mark.asan, pytest.mark.kernel]

H, W = 40, 60
SURF, DISOCC, UNCOV = _core.WARP_SURFACE, _core.WARP_DISOCCLUDED, _core.WARP_UNCOVERED


def _cam(tx=0.0):
    # Pinhole looking down +z from (tx, 0, -4) (OpenCV axes, identity rotation).
    m = np.eye(4)
    m[0, 3] = -tx
    m[2, 3] = 4.0
    return Camera(model="pinhole", width=W, height=H, fx=50.0, fy=50.0, cx=W / 2, cy=H / 2, cam_from_world=m)


def _square_scene():
    rng = np.random.default_rng(0)
    col = (0.2 + 0.1 * rng.random((H, W, 3))).astype(np.float32)   # background texture in [0.2, 0.3]
    depth = np.full((H, W), 8.0, np.float32)                        # background plane z = 8
    col[15:25, 25:35] = 0.9                                         # foreground square z = 2
    depth[15:25, 25:35] = 2.0
    return col, depth


def test_identity_warp_is_the_input():
    col, depth = _square_scene()
    c = _cam()
    out, d, m = _core.warp_with_holes(col, depth, c.to_core(), c.to_core())
    # The pixel-centre mesh spans centres 0.5 .. W - 0.5; the tie rule gives the centres on two of
    # its border edges to nobody (which two depends on the winding): one border row and one border
    # column are uncovered, never disoccluded; everything else is the input.
    assert not (m == DISOCC).any()
    assert (m[1:-1, 1:-1] == SURF).all() and (m == UNCOV).sum() == H + W - 1
    surf = m == SURF
    np.testing.assert_allclose(out[surf], col[surf], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(d[surf], depth[surf], rtol=1e-6)
    assert (out[m != SURF] == 0).all() and (d[m == UNCOV] == 0).all()


def test_disoccluded_strip_has_background_depth_and_no_foreground():
    col, depth = _square_scene()
    b = 0.42  # camera moved by -b in x: content moves right by fx * b / z
    out, d, m = _core.warp_with_holes(col, depth, _cam().to_core(), _cam(-b).to_core())
    s_fg, s_bg = 50.0 * b / 2.0, 50.0 * b / 8.0          # 10.5 px and 2.625 px (no centre on an edge)
    # Left of the square: the last background centre 24.5 lands at 27.125, the square's first
    # centre 25.5 at 36.0; the stretched quads between cover centres 27.5 .. 35.5, i.e. columns
    # 27 .. 35 of rows 15 .. 23 (rows 16 .. 23 tested: row 24's quads also reach row 25).
    lo, hi = int(np.ceil(24.5 + s_bg - 0.5)), int(np.ceil(25.5 + s_fg - 0.5))
    assert (lo, hi) == (27, 36)
    strip = (slice(16, 24), slice(lo, hi))
    assert (m[strip] == DISOCC).all()
    np.testing.assert_allclose(d[strip], 8.0, rtol=1e-6)   # background depth, analytic
    assert (out[strip] == 0).all()                          # holes carry no colour at all
    # No foreground colour (0.9) anywhere but on the moved square; every disoccluded pixel has
    # the background depth; the square itself is surface at z = 2.
    fg = np.isclose(out[..., 0], 0.9)
    cols = np.nonzero(fg.any(axis=0))[0]
    assert cols.min() == 36 and cols.max() == 44
    assert np.allclose(d[m == DISOCC], 8.0, rtol=1e-6)
    assert (m[16:24, 36:45] == SURF).all() and np.allclose(d[16:24, 36:45], 2.0, rtol=1e-6)
    # Left border: nothing of the input lands there (background moved 2.6 px right).
    assert (m[:, :3] == UNCOV).all()


def test_depth_aware_pushpull_fills_the_strip_with_background():
    # The point of the background depth: the depth-aware fill ignores the foreground square.
    # Background texture lies in [0.2, 0.3], the square is 0.9; classic push-pull bleeds it in.
    from ibrtools.inpaint.pushpull import pushpull

    col, depth = _square_scene()
    out, d, m = _core.warp_with_holes(col, depth, _cam().to_core(), _cam(-0.42).to_core())
    hole = m == DISOCC
    aware = pushpull(out, hole, np.where(m == UNCOV, 0, d).astype(np.float32))
    classic = pushpull(out, hole)
    # Means over the strip (Alg. 1's plain bilinear push still lets pixels next to the square read
    # a coarse all-square pixel, docs/inpaint.md; every pixel of this 9-px strip is within 5 px of
    # the square): measured 0.286 depth-aware vs 0.417 classic; background mean 0.25 within 0.05.
    assert abs(aware[hole].mean() - 0.25) < 0.05
    assert classic[hole].mean() > aware[hole].mean() + 0.1


def test_farthest_stretched_quad_wins_and_surface_beats_stretched():
    # Two foreground squares at different depths side by side in front of the background: the
    # disocclusions take the background (farthest corner), never a foreground depth.
    col, depth = _square_scene()
    depth[15:25, 30:35] = 3.0
    out, d, m = _core.warp_with_holes(col, depth, _cam().to_core(), _cam(-0.4).to_core())
    dis = m == DISOCC
    assert dis.sum() > 40
    # A pixel between the two foreground squares is covered by quads stretched between z=2 and z=3
    # and by quads stretched from z=3/z=2 to z=8: the farthest background depth present wins.
    assert set(np.unique(d[dis]).round(4)) <= {8.0, 3.0}
    assert np.isclose(d[dis], 8.0).mean() > 0.7


def test_magnified_smooth_surface_is_not_a_hole_unless_depth_jump_is_off():
    # A plane seen 3x closer: every quad is 3 px wide (> the 2 px threshold) but has no depth jump.
    col, depth = _square_scene()
    depth[:] = 8.0
    near = Camera(model="pinhole", width=W, height=H, fx=150.0, fy=150.0, cx=W / 2, cy=H / 2,
                  cam_from_world=_cam().cam_from_world)  # 3x the focal length: 3x magnification
    _, _, m = _core.warp_with_holes(col, depth, _cam().to_core(), near.to_core())
    assert (m != DISOCC).all() and (m[1:-1, 1:-1] == SURF).all()
    _, _, m0 = _core.warp_with_holes(col, depth, _cam().to_core(), near.to_core(), 2.0, 0.0)
    assert (m0[1:-1, 1:-1] == DISOCC).all()


@pytest.mark.parametrize("dx, dy", [(0, 0), (3, 0), (-2, 5)])
def test_flow_constant_is_a_shift(dx, dy):
    col, depth = _square_scene()
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0], flow[..., 1] = dx, dy
    out, d, m = _core.warp_flow(col, depth, flow)
    # Surface pixels are exactly the shifted input (one border row / column of the shifted mesh
    # is uncovered by the tie rule, as for the identity, unless shifted off-image); nothing is
    # disoccluded.
    surf = m == SURF
    assert surf.sum() == (H - abs(dy) - (dy >= 0)) * (W - abs(dx) - (dx >= 0)) and not (m == DISOCC).any()
    yy, xx = np.nonzero(surf)
    np.testing.assert_allclose(out[yy, xx], col[yy - dy, xx - dx], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(d[yy, xx], depth[yy - dy, xx - dx], rtol=1e-6)
    if (dx, dy) == (0, 0):
        c = _cam()
        ref = _core.warp_with_holes(col, depth, c.to_core(), c.to_core())
        for a, b in zip((out, d, m), ref):
            assert np.array_equal(a, b)


def test_flow_same_as_camera_warp_for_a_translation():
    # The camera warp's per-pixel motion, given as a flow, reproduces its holes and depth.
    col, depth = _square_scene()
    b = 0.4
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0] = 50.0 * b / depth
    ref = _core.warp_with_holes(col, depth, _cam().to_core(), _cam(-b).to_core())
    got = _core.warp_flow(col, depth, flow)
    assert np.array_equal(got[2], ref[2])
    np.testing.assert_allclose(got[1], ref[1], rtol=1e-5)
    np.testing.assert_allclose(got[0], ref[0], rtol=1e-5, atol=1e-6)


def test_dibr_is_unaffected():
    # The hole mode shares DIBR's rasteriser; forward_warp's own output is pinned by
    # test_forward_warp.py / test_dibr.py. Here: the same inputs through both, the surface agrees.
    col, depth = _square_scene()
    # DIBR's shader has inclusive edges, the hole mode the exclusive tie rule (forward_warp.h): a
    # centre exactly on a shared edge (here every centre: _cam(-0.4) is a rectified pair) may go to
    # different triangles. The target is moved off those ties by 0.0123 in y.
    m = np.eye(4)
    m[0, 3], m[1, 3], m[2, 3] = 0.4, 0.0123, 4.0
    c0 = _cam().to_core()
    c1 = Camera(model="pinhole", width=W, height=H, fx=50.0, fy=50.0, cx=W / 2, cy=H / 2, cam_from_world=m).to_core()
    o = _core.WarpOptions()
    o.depth_test = "nearest"
    o.discard_stretched = True
    o.side_threshold = 2.0
    dc, dd, dw = _core.forward_warp(col, depth, c0, c1, o)
    hc, hd, hm = _core.warp_with_holes(col, depth, c0, c1, 2.0)
    surf = hm == SURF
    np.testing.assert_allclose(hc[surf], dc[surf], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(hd[surf], dd[surf], rtol=1e-6)


@pytest.fixture
def restore_threads():
    yield
    _core.set_num_threads(0)


def test_thread_count_does_not_change_results(restore_threads):
    rng = np.random.default_rng(3)
    h, w = 150, 90  # several 32-row bands, odd width
    col = rng.random((h, w, 3), dtype=np.float32)
    depth = (3 + 2 * (rng.random((h, w)) > 0.7)).astype(np.float32)
    src = Camera(model="pinhole", width=w, height=h, fx=80.0, fy=80.0, cx=w / 2, cy=h / 2, cam_from_world=np.eye(4))
    m = np.eye(4)
    m[:3, 3] = (0.3, -0.1, 0.2)
    tgt = Camera(model="pinhole", width=w + 3, height=h - 5, fx=80.0, fy=80.0, cx=w / 2, cy=h / 2, cam_from_world=m)
    flow = rng.normal(0, 2, (h, w, 2)).astype(np.float32)
    res = []
    for n in (1, 2, 3):
        _core.set_num_threads(n)
        res.append(_core.warp_with_holes(col, depth, src.to_core(), tgt.to_core()) + _core.warp_flow(col, depth, flow))
    for r in res[1:]:
        for a, b in zip(res[0], r):
            assert np.array_equal(a, b)


def test_gil_released():
    col = np.random.default_rng(0).random((400, 400, 3), dtype=np.float32)
    depth = np.full((400, 400), 2.0, np.float32)
    flow = np.ones((400, 400, 2), np.float32)
    errors = []

    def work():
        try:
            for _ in range(3):
                _core.warp_flow(col, depth, flow)
        except Exception as e:  # pragma: no cover
            errors.append(e)

    ts = [threading.Thread(target=work) for _ in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert not errors


def test_bad_input():
    col, depth = _square_scene()
    c = _cam().to_core()
    flow = np.zeros((H, W, 2), np.float32)
    with pytest.raises(ShapeError, match="depth"):
        _core.warp_with_holes(col, depth[:, :-1], c, c)
    with pytest.raises(DtypeError, match="color"):
        _core.warp_with_holes(col.astype(np.float64), depth, c, c)
    bad = depth.copy()
    bad[3, 3] = np.nan
    with pytest.raises(BadValueError, match="NaN or negative"):
        _core.warp_with_holes(col, bad, c, c)
    with pytest.raises(BadValueError, match="no valid depth"):
        _core.warp_with_holes(col, np.zeros_like(depth), c, c)
    for t in (0.0, -1.0, float("inf"), float("nan")):
        with pytest.raises(BadValueError, match="stretch_threshold"):
            _core.warp_with_holes(col, depth, c, c, t)
        with pytest.raises(BadValueError, match="stretch_threshold"):
            _core.warp_flow(col, depth, flow, t)
    for j in (-0.1, float("inf"), float("nan")):
        with pytest.raises(BadValueError, match="depth_jump"):
            _core.warp_with_holes(col, depth, c, c, 2.0, j)
    with pytest.raises(ShapeError, match="flow"):
        _core.warp_flow(col, depth, flow[..., :1])
    with pytest.raises(ShapeError, match="color"):
        _core.warp_flow(col[:-1], depth, flow)
    nf = flow.copy()
    nf[1, 2, 0] = np.inf
    with pytest.raises(BadValueError, match="flow: 1 vectors"):
        _core.warp_flow(col, depth, nf)
    with pytest.raises(BadValueError, match="NaN or negative"):
        _core.warp_flow(col, bad, flow)
    with pytest.raises(ShapeError, match="2 x 2"):
        _core.warp_flow(col[:1], depth[:1], flow[:1])


# --- method and CLI -------------------------------------------------------------------------
@pytest.mark.parametrize("params, flag", [
    ({"inputs": 2}, "inputs"), ({"inputs": "a,b"}, "inputs"), ({"inputs": True}, "inputs"),
    ({"stretch_threshold": 0}, "stretch_threshold"), ({"stretch_threshold": "x"}, "stretch_threshold"),
    ({"depth_jump": -1}, "depth_jump"), ({"samples": 0}, "samples"), ({"bogus": 1}, "no parameter"),
])
def test_bad_params(params, flag):
    with pytest.raises(BadValueError, match=flag):
        WarpMethod(params)


def test_params_defaults():
    p = WarpParams.from_dict(None)
    assert p.inputs == 1 and p.stretch_threshold == 2.0
    assert WarpParams.from_dict({"inputs": "v002"}).inputs == "v002"
    assert WarpParams.from_dict({"inputs": "1"}).inputs == 1


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    # 16 views on the ring (22.5 degrees apart): the warp is meant for small view changes
    # (frame to frame); at 60 degrees most of the oblique ground plane is magnified past the
    # stretch threshold and becomes disocclusion.
    return synth_scene_dir(tmp_path_factory, "--views", "16", "--size", "64x48", name="warp")


def test_cli_holdout_inpaint_pushpull(scene_dir, tmp_path):
    base = [str(scene_dir), "--method", "warp", "--holdout", "v003", "-q", "--depth"]
    assert render.main([*base, "--inpaint", "none", "-o", str(tmp_path / "none")]) == 0
    assert render.main([*base, "--inpaint", "pushpull", "-o", str(tmp_path / "pp")]) == 0
    rep = json.loads((tmp_path / "pp/report.json").read_text())
    assert rep["method"] == "warp"
    f = rep["frames"][0]
    assert f["selected"] and f["selected"][0] != "v003"
    assert {"select", "warp", "inpaint"} <= set(f["time_ms"])
    # Depth-aware push-pull (the kernel falls back to classic where no background data exists).
    assert f["inpaint"] == "pushpull" and f["metrics"]["psnr"] > 10
    assert (tmp_path / "pp/v003.hole.png").is_file() and (tmp_path / "pp/v003.depth.exr").is_file()
    assert render.main([*base, "--inputs", "v002", "-o", str(tmp_path / "named")]) == 0
    assert json.loads((tmp_path / "named/report.json").read_text())["frames"][0]["selected"] == ["v002"]


def test_cli_poses_and_bad_input(scene_dir, tmp_path, capsys):
    doc = json.loads((scene_dir / "scene.json").read_text())
    cam = next(iter(doc["views"]))["camera"] if isinstance(doc["views"], list) else None
    if cam is None:
        pytest.skip("scene.json views are not a list")
    (tmp_path / "poses.json").write_text(json.dumps([cam]))
    assert render.main([str(scene_dir), "--method", "warp", "--poses", str(tmp_path / "poses.json"),
                        "-o", str(tmp_path / "p"), "-q"]) == 0
    assert (tmp_path / "p/pose_000.png").is_file()
    assert render.main([str(scene_dir), "--method", "warp", "--holdout", "v003", "--inputs", "v003",
                        "-o", str(tmp_path / "b"), "-q"]) == 2
    assert "--inputs" in capsys.readouterr().err


def test_prepare_needs_depth():
    cam = _cam()
    from ibrtools.scene import Scene, View

    s = Scene(views=[View.create("a", cam, color=np.zeros((H, W, 3), np.float32))])
    m = WarpMethod()
    with pytest.raises(InputError, match="needs depth for every input view.*ibr-preprocess"):
        m.prepare(s)
