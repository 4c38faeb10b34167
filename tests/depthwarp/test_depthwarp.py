"""Iterative backward depth warping (ibrtools.depthwarp.core; Lee, Kim, Eisemann 2018 sec. 3, 4.1).

Scenes are analytic (fronto-parallel planes seen by pinhole cameras) so that every expected depth
and motion is known exactly; tolerances are stated next to each comparison."""
from __future__ import annotations

import numpy as np
import pytest

from gil import runs_python_during
from ibrtools import _core
from ibrtools.camera import Camera
from ibrtools.depthwarp.core import (DepthWarpParams, WarpResult, forward_warp_depth, motion_buffer,
                                warp_depth)
from ibrtools.errors import BadValueError, DtypeError, ShapeError

pytestmark = [pytest.mark.asan, pytest.mark.kernel]

W, H, F = 96, 72, 80.0


@pytest.fixture
def restore_threads():
    yield
    _core.set_num_threads(0)


def cam_at(centre=(0.0, 0.0, 0.0), w=W, h=H, f=F) -> Camera:
    """Pinhole looking down world +z (axes = world axes), centred at `centre`."""
    pose = np.eye(4)
    pose[:3, 3] = -np.asarray(centre, dtype=np.float64)
    return Camera.pinhole(w, h, f, f, w / 2, h / 2, pose)


def plane(z, h=H, w=W) -> np.ndarray:
    return np.full((h, w), z, np.float32)


def test_zero_motion_returns_input_exactly():
    rng = np.random.default_rng(0)
    d = (1 + 9 * rng.random((H, W))).astype(np.float32)
    d[rng.random((H, W)) < 0.1] = 0  # empty pixels stay holes
    cam = cam_at()
    for params in (DepthWarpParams(), DepthWarpParams(seeds=1, oriented=True, bound="global", dilate=False)):
        r = warp_depth(d, cam, cam, params)
        assert isinstance(r, WarpResult)
        # dilation may fill isolated empty input pixels; without it the output is the input bit for bit
        if not params.dilate:
            np.testing.assert_array_equal(r.depth, d)
            np.testing.assert_array_equal(r.hole, d == 0)
        else:
            np.testing.assert_array_equal(r.depth[~r.hole & (d > 0)], d[~r.hole & (d > 0)])
            assert not r.hole[d > 0].any()
        assert set(r.times_ms) >= {"motion", "mipmap", "warp", "dilate"}
        assert set(r.stats) >= {"converged_fraction", "early_exit_fraction", "dilated_pixels", "hole_fraction"}
    # two layers: layer 0 wins everywhere it is non-empty
    deep = np.stack([d, np.where(d > 0, d + 1, 5).astype(np.float32)])
    r = warp_depth(deep, cam, cam, DepthWarpParams(dilate=False))
    np.testing.assert_array_equal(r.depth, np.where(d > 0, d, 5).astype(np.float32))
    np.testing.assert_array_equal(r.layer, np.where(d > 0, 0, 1).astype(np.int8))


@pytest.mark.parametrize("shift", [(0.3, 0.1, 0.0), (-0.25, 0.4, 0.0), (0.5, 0.0, 0.0)])
def test_plane_translation_is_exact(shift):
    z = 4.0
    src, dst = cam_at(), cam_at(shift)
    motion, dz = motion_buffer(plane(z), src, dst)
    # Analytic image motion of a fronto-parallel plane: -f t / z (float32 rounding of ~10 px: 1e-4).
    expect = np.array([-F * shift[0] / z, -F * shift[1] / z], np.float32)
    np.testing.assert_allclose(motion, np.broadcast_to(expect, motion.shape), atol=1e-4)
    np.testing.assert_array_equal(dz, plane(z))
    for params in (DepthWarpParams(), DepthWarpParams(bound="global", seeds=4), DepthWarpParams(oriented=True),
                   DepthWarpParams(tile=1, pixel_step=False), DepthWarpParams(tile=16, early_exit=0.0)):
        r = warp_depth(plane(z), src, dst, params)
        # Pixel p has a source iff p - v lies in the source image (samples outside are rejected).
        xs = np.arange(W) + 0.5 - expect[0]
        ys = np.arange(H) + 0.5 - expect[1]
        inside = ((ys >= 0) & (ys < H))[:, None] & ((xs >= 0) & (xs < W))[None, :]
        np.testing.assert_array_equal(r.depth[inside], z)  # exact: the plane's z is the same everywhere
        np.testing.assert_array_equal(r.hole, ~inside)
        np.testing.assert_array_equal(r.layer, np.where(inside, 0, -1).astype(np.int8))
    for kind in ("vfw", "afw"):
        f = forward_warp_depth(plane(z), src, dst, kind)
        np.testing.assert_allclose(f.depth[inside], z, rtol=1e-6)  # 1/z interpolation of a constant
        # the half-pixel expansion covers at most one extra row/column at the uncovered border
        assert f.hole[inside].sum() == 0 and f.hole.sum() >= (~inside).sum() - (W + H)


def test_forward_baselines_cover_a_magnified_plane():
    # Camera moves towards the plane: magnification z / (z - 1.5) = 1.6 (pixels spread to 1.6 px).
    z = 4.0
    src, dst = cam_at(), cam_at((0, 0, 1.5))
    inner = (slice(H // 4, 3 * H // 4), slice(W // 4, 3 * W // 4))
    for kind in ("vfw", "afw"):
        f = forward_warp_depth(plane(z), src, dst, kind)
        assert not f.hole[inner].any(), kind
        np.testing.assert_allclose(f.depth[inner], z - 1.5, rtol=1e-6)
    # The backward search is a fixed-point iteration whose contraction factor is the motion
    # gradient (0.6 px/px at 1.6x: a per-frame zoom far beyond the paper's "moderate motion", where
    # T = 3 does not converge); at a moderate 1.11x zoom it is exact.
    dst = cam_at((0, 0, 0.4))
    r = warp_depth(plane(z), src, dst)
    assert not r.hole[inner].any()
    np.testing.assert_allclose(r.depth[inner], z - 0.4, rtol=1e-6)


def two_plane_scene(fg_z=2.0, bg_z=8.0, box=(36, 24, 60, 48)):
    """Layer 0: a square at fg_z in front of a plane at bg_z; layer 1: the plane behind the square."""
    x0, y0, x1, y1 = box
    l0 = plane(bg_z)
    l0[y0:y1, x0:x1] = fg_z
    l1 = np.zeros((H, W), np.float32)
    l1[y0:y1, x0:x1] = bg_z
    return np.stack([l0, l1])


def truth_two_planes(dst: Camera, fg_z=2.0, bg_z=8.0, box=(36, 24, 60, 48)) -> np.ndarray:
    """Analytic depth of the two-plane scene seen by a translated camera (axes = world axes)."""
    x0, y0, x1, y1 = box
    t = dst.centre
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    # world point of the ray at depth zc (camera z) is t + zc * ((u - cx) / f, (v - cy) / f, 1)
    zc = fg_z - t[2]
    wx = t[0] + zc * (u - W / 2) / F
    wy = t[1] + zc * (v - H / 2) / F
    # the square spans source pixels [x0, x1) at fg_z seen from the origin
    sx = wx * F / fg_z + W / 2
    sy = wy * F / fg_z + H / 2
    on_fg = (sx >= x0) & (sx < x1) & (sy >= y0) & (sy < y1)
    return np.where(on_fg, fg_z - t[2], bg_z - t[2]).astype(np.float32), on_fg


def test_disocclusion_stays_a_hole_and_never_gets_a_wrong_depth():
    deep = two_plane_scene()
    src, dst = cam_at(), cam_at((0.4, 0.0, 0.0))
    truth, on_fg = truth_two_planes(dst)
    r1 = warp_depth(deep[0], src, dst, DepthWarpParams(dilate=False))
    got = ~r1.hole
    # Every converged depth is one of the true surfaces at that pixel, except within 1.5 px of the
    # square's edges in the target (the 0.5 px threshold plus the nearest lookup's 0.5 px cell).
    edge = np.zeros_like(on_fg)
    for dy in (-1, 0, 1):
        for dx in (-2, -1, 0, 1, 2):
            edge |= np.roll(on_fg, (dy, dx), (0, 1)) != on_fg
    wrong = got & (np.abs(r1.depth - truth) > 1e-5 * truth) & ~edge
    assert wrong.sum() == 0
    # The background revealed by the motion (hidden in the single source layer) has no solution.
    v_bg = -F * 0.4 / 8.0  # background moves by -4 px, the square by -16 px: 12 px revealed
    revealed = ~on_fg & ~edge
    u = np.arange(W) + 0.5
    src_x = u - v_bg  # where the revealed background came from in the source
    hidden = ((src_x >= 36) & (src_x < 60))[None, :] & (np.arange(H)[:, None] >= 24) & (np.arange(H)[:, None] < 48)
    lost = revealed & hidden
    assert lost.sum() > 200
    assert r1.hole[lost].all()
    # With dilation on, a hole this large (12 px wide) stays a hole.
    r1d = warp_depth(deep[0], src, dst, DepthWarpParams(dilate=True))
    inner_lost = lost & np.roll(lost, 2, 1) & np.roll(lost, -2, 1) & np.roll(lost, 2, 0) & np.roll(lost, -2, 0)
    assert r1d.hole[inner_lost].all()
    # The second layer fills it (Fig. 6 cross-layer seeding), with the exact background depth.
    r2 = warp_depth(deep, src, dst, DepthWarpParams(dilate=False))
    np.testing.assert_array_equal(r2.depth[lost], truth[lost])
    assert (r2.layer[lost] == 1).all()
    ok = ~edge & ~r2.hole
    np.testing.assert_allclose(r2.depth[ok], truth[ok], rtol=1e-5)


def test_oriented_bounds_and_degenerate_pca():
    src = cam_at()
    # Pure translation: all motions equal -> no principal direction -> axis-aligned bound.
    r = warp_depth(plane(4.0), src, cam_at((0.2, 0.2, 0)), DepthWarpParams(oriented=True))
    assert r.stats["bound_axes"] == ["aab (degenerate pca)"]
    ref = warp_depth(plane(4.0), src, cam_at((0.2, 0.2, 0)), DepthWarpParams(oriented=False))
    assert ref.stats["bound_axes"] == ["aab"]
    np.testing.assert_array_equal(r.depth, ref.depth)
    # Two depths and a diagonal translation: motions spread along the diagonal -> oriented axes
    # (zero-width box along the normal, smaller than the axis-aligned one).
    deep = two_plane_scene()[0]
    dst = cam_at((0.3, 0.3, 0))
    ro = warp_depth(deep, src, dst, DepthWarpParams(oriented=True, dilate=False))
    assert ro.stats["bound_axes"] == ["oriented"]
    ra = warp_depth(deep, src, dst, DepthWarpParams(oriented=False, dilate=False))
    truth, on_fg = truth_two_planes(dst)
    edge = np.zeros_like(on_fg)
    for dy in (-2, -1, 0, 1, 2):
        for dx in (-2, -1, 0, 1, 2):
            edge |= np.roll(on_fg, (dy, dx), (0, 1)) != on_fg
    for r in (ro, ra):  # both find the exact surface away from the square's edges (see above)
        ok = ~r.hole & ~edge
        assert ok.mean() > 0.75
        np.testing.assert_array_equal(r.depth[ok], truth[ok])


def test_extreme_motion_and_camera_behind_geometry_report_holes():
    src = cam_at()
    d = two_plane_scene()
    # > 500 px motion: everything leaves the image; no crash, all holes.
    r = warp_depth(d, src, cam_at((60.0, 0.0, 0.0)))
    assert r.hole.all() and (r.depth == 0).all() and (r.layer == -1).all()
    m, _ = motion_buffer(d[0], src, cam_at((60.0, 0.0, 0.0)))
    assert np.abs(m[..., 0]).min() > 500
    # 600 px motion of the foreground object only: it leaves the image, the background it covered
    # in the single source layer has no source (holes), the rest of the background is exact.
    ids = np.where(d[0] < 5, 0, -1).astype(np.int32)
    move = np.eye(4)[None].copy()
    move[0, 0, 3] = 15.0  # 15 world units at z = 2: 600 px
    r = warp_depth(d[0], src, src, DepthWarpParams(seeds=64), object_ids=ids, object_motion=move)
    assert r.hole[26:46, 38:58].all()
    np.testing.assert_array_equal(r.depth[:20], 8.0)
    # Target camera behind the geometry (beyond both planes, and looking away from them).
    for pose_centre in ((0, 0, 9.0), (0, 0, 20.0)):
        r = warp_depth(d, src, cam_at(pose_centre))
        assert r.hole.all()
        for kind in ("vfw", "afw"):
            assert forward_warp_depth(d, src, cam_at(pose_centre), kind).hole.all()
    back = np.diag([-1.0, 1.0, -1.0, 1.0])  # rotated 180 degrees about y
    r = warp_depth(d, src, Camera.pinhole(W, H, F, F, W / 2, H / 2, back))
    assert r.hole.all()
    m, dz = motion_buffer(d[0], src, Camera.pinhole(W, H, F, F, W / 2, H / 2, back))
    assert (dz == 0).all() and (m == 0).all()


def test_object_motion_moves_only_the_object():
    d = two_plane_scene()[0]
    ids = np.where(d < 5, 0, -1).astype(np.int32)  # the square is object 0
    move = np.eye(4)[None].copy()
    move[0, 0, 3] = 0.1  # object moves +0.1 in world x between the frames
    cam = cam_at()
    m, dz = motion_buffer(d, cam, cam, object_ids=ids, object_motion=move)
    np.testing.assert_allclose(m[ids == 0], np.broadcast_to([F * 0.1 / 2.0, 0], m[ids == 0].shape), atol=1e-4)
    np.testing.assert_array_equal(m[ids < 0], 0)
    np.testing.assert_array_equal(dz, d)
    r = warp_depth(d, cam, cam, DepthWarpParams(dilate=False), object_ids=ids, object_motion=move)
    # the square moved right by 4 px: its new columns 40..63 hold 2.0, the 4 revealed columns are holes
    np.testing.assert_array_equal(r.depth[24:48, 40:64], 2.0)
    assert r.hole[24:48, 36:40].all()
    f = forward_warp_depth(d, cam, cam, "afw", object_ids=ids, object_motion=move)
    np.testing.assert_array_equal(f.depth[24:48, 41:63], 2.0)


def test_results_identical_for_1_and_2_threads(restore_threads):
    rng = np.random.default_rng(3)
    deep = two_plane_scene()
    deep[0] += (0.05 * rng.random((H, W))).astype(np.float32)
    src = cam_at()
    dst = Camera.pinhole(80, 90, 70.0, 75.0, 41.0, 44.0, np.array(
        [[0.995, 0, 0.0998, -0.3], [0, 1, 0, 0.1], [-0.0998, 0, 0.995, 0.2], [0, 0, 0, 1]]))
    ids = np.where(deep > 5, -1, 0).astype(np.int32)
    move = np.eye(4)[None].copy()
    move[0, 1, 3] = 0.05
    out = []
    for n in (1, 2):
        _core.set_num_threads(n)
        res = [warp_depth(deep, src, dst, DepthWarpParams(seeds=8, oriented=True, seed=7),
                          object_ids=ids, object_motion=move),
               warp_depth(deep, src, dst, DepthWarpParams(bound="global")),
               forward_warp_depth(deep, src, dst, "vfw"), forward_warp_depth(deep, src, dst, "afw")]
        out.append(res)
    for a, b in zip(*out):
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.layer, b.layer)
    assert out[0][0].stats["samples"] == out[1][0].stats["samples"]


def test_seed_changes_only_the_jitter():
    deep = two_plane_scene()
    src, dst = cam_at(), cam_at((0.3, 0.2, 0.1))
    a = warp_depth(deep, src, dst, DepthWarpParams(seed=1))
    b = warp_depth(deep, src, dst, DepthWarpParams(seed=1))
    np.testing.assert_array_equal(a.depth, b.depth)


def test_warp_releases_the_gil(restore_threads):
    big = 384
    d = np.full((big, big), 4.0, np.float32)
    src = Camera.pinhole(big, big, 300.0, 300.0, big / 2, big / 2)
    dst = cam_at((0.2, 0.1, 0.3), big, big, 300.0)
    _core.set_num_threads(1)
    assert runs_python_during(lambda: [warp_depth(np.stack([d, d + 1]), src, dst, DepthWarpParams(seeds=32))
                                       for _ in range(3)]), "no Python ran during the warps (or they lasted < 20 ms)"


def test_bad_inputs():
    cam = cam_at()
    d = plane(4.0)
    eq = Camera.equirect(W, H)
    with pytest.raises(BadValueError, match="not supported by depthwarp"):
        warp_depth(d, eq, cam)
    with pytest.raises(BadValueError, match="not supported by depthwarp"):
        motion_buffer(d, cam, Camera.equirect(W, H))
    with pytest.raises(DtypeError, match="layers"):
        warp_depth(d.astype(np.float64), cam, cam)
    with pytest.raises(DtypeError, match="layers"):
        warp_depth(d.tolist(), cam, cam)
    with pytest.raises(ShapeError, match="layers"):
        warp_depth(d[:-1], cam, cam)
    with pytest.raises(ShapeError, match="depth"):
        motion_buffer(np.stack([d, d]), cam, cam)
    with pytest.raises(DtypeError, match="src"):
        warp_depth(d, "cam", cam)
    bad = d.copy()
    bad[3, 3] = np.nan
    with pytest.raises(BadValueError, match="layers"):
        warp_depth(bad, cam, cam)
    bad[3, 3] = -1
    with pytest.raises(BadValueError, match="negative"):
        forward_warp_depth(bad, cam, cam)
    for params, name in ((DepthWarpParams(seeds=0), "seeds"), (DepthWarpParams(iters=-1), "iters"),
                         (DepthWarpParams(threshold=0), "threshold"), (DepthWarpParams(bound="box"), "bound"),
                         (DepthWarpParams(early_exit=-1), "early_exit"), (DepthWarpParams(steps=-2), "steps"),
                         (DepthWarpParams(dilate_min_neighbors=9), "dilate_min_neighbors"),
                         (DepthWarpParams(threshold=float("nan")), "threshold"), (DepthWarpParams(tile=0), "tile"),
                         (DepthWarpParams(tile=17), "tile"), (DepthWarpParams(seed=2**32), "seed")):
        with pytest.raises(BadValueError, match=name):
            warp_depth(d, cam, cam, params)
    with pytest.raises(DtypeError, match="oriented"):
        warp_depth(d, cam, cam, DepthWarpParams(oriented="yes"))
    with pytest.raises(DtypeError, match="pixel_step"):
        warp_depth(d, cam, cam, DepthWarpParams(pixel_step=1))
    with pytest.raises(DtypeError, match="unseen_reject"):
        warp_depth(d, cam, cam, DepthWarpParams(unseen_reject="no"))
    for bad_edge in (-0.5, float("inf")):
        with pytest.raises(BadValueError, match="edge_motion"):
            warp_depth(d, cam, cam, DepthWarpParams(edge_motion=bad_edge))
    with pytest.raises(DtypeError, match="edge_motion"):
        warp_depth(d, cam, cam, DepthWarpParams(edge_motion="half"))
    # The binding's own checks (the front never sends these).
    packed = _core.dw_motion(d[None], cam.to_core(), cam.to_core(), None, None)
    mips = _core.dw_build_mips(packed)
    with pytest.raises(BadValueError, match="seen_src, seen_dst"):
        _core.dw_warp(packed, mips, H, W, seen_src=cam.to_core())
    with pytest.raises(DtypeError, match="seen_src"):
        _core.dw_warp(packed, mips, H, W, seen_src="cam", seen_dst=cam.to_core())
    with pytest.raises(ShapeError, match="seen_src"):
        _core.dw_warp(packed, mips, H, W, seen_src=cam_at(w=W + 1).to_core(), seen_dst=cam.to_core())
    with pytest.raises(BadValueError, match="not supported by depthwarp"):
        _core.dw_warp(packed, mips, H, W, seen_src=eq.to_core(), seen_dst=cam.to_core())
    with pytest.raises(BadValueError, match="edge_motion"):
        _core.dw_warp(packed, mips, H, W, edge_motion=float("nan"))
    with pytest.raises(DtypeError, match="params"):
        warp_depth(d, cam, cam, {"seeds": 4})
    ids = np.zeros((H, W), np.int32)
    move = np.eye(4)[None]
    with pytest.raises(BadValueError, match="object_ids"):
        warp_depth(d, cam, cam, object_ids=ids)
    with pytest.raises(BadValueError, match="object_ids"):
        warp_depth(d, cam, cam, object_ids=ids + 1, object_motion=move)
    with pytest.raises(DtypeError, match="object_ids"):
        warp_depth(d, cam, cam, object_ids=ids.astype(np.int64), object_motion=move)
    with pytest.raises(ShapeError, match="object_motion"):
        warp_depth(d, cam, cam, object_ids=ids, object_motion=np.eye(4))
    nonrigid = move.copy()
    nonrigid[0, 3, 0] = 1
    with pytest.raises(BadValueError, match="object_motion"):
        motion_buffer(d, cam, cam, object_ids=ids, object_motion=nonrigid)
    with pytest.raises(BadValueError, match="kind"):
        forward_warp_depth(d, cam, cam, "splat")


def test_silhouette_test_keeps_the_foreground_to_its_footprint():
    # A square at z = 2 in front of a plane at z = 8, sideways step with fractional motions (square
    # -6.4 px, plane -1.6 px; a 4x4 patch at z = 1.5 in a corner, -8.5 px, widens the global bound
    # so that seeds reach the square from beyond its edge). The square's edges lie on source pixel
    # edges, so its true image in the target is its source pixels moved exactly (truth_two_planes).
    # Without the silhouette test a seed in a square pixel converges when that pixel's centre
    # moves within 0.5 px of p even if p lies beyond the square's moved edge: the square grows on
    # its leading side (here the column of centres 29.5, 0.1 px beyond the edge at 29.6).
    deep = two_plane_scene()
    deep[0, :4, :4] = 1.5
    src, dst = cam_at(), cam_at((0.16, 0.0, 0.0))
    truth, on_fg = truth_two_planes(dst)
    rows = slice(12, 60)  # away from the corner patch (truth_two_planes does not know it)
    grown = {}
    for edge in (0.0, 0.5):
        r = warp_depth(deep, src, dst, DepthWarpParams(dilate=False, edge_motion=edge, bound="global"))
        fg = ~r.hole[rows] & (r.depth[rows] == np.float32(2.0))
        grown[edge] = int((fg & ~on_fg[rows]).sum())
        assert fg[on_fg[rows]].all(), edge  # every pixel of the square's true image is found
    assert grown[0.0] >= 20, grown  # the 24-row leading edge column (measured: 24)
    assert grown[0.5] == 0


def test_unseen_space_rejects_deep_samples_behind_the_frame_border():
    # Layer 0: a plane at z = 2 filling the source image (and beyond it); layer 1: a plane at z = 8
    # behind it. The target steps left by 0.6: its left strip sees the near plane's continuation,
    # which the source never saw (outside its frame: source x = u - 24 < 0), so layer 0 has no
    # solution there. Layer 1's plane converges at u > 6 (source x = u - 6), but the near plane
    # hides it: accepting it gives depth 8 where the truth is 2. With the unseen-space test these
    # pixels stay holes (never a wrong depth); elsewhere the near plane is found as before.
    deep = np.stack([plane(2.0), plane(8.0)])
    src, dst = cam_at(), cam_at((-0.6, 0.0, 0.0))
    u = np.arange(W) + 0.5
    strip = np.broadcast_to(((u > 6 + 1) & (u < 24 - 1))[None, :], (H, W))
    seen = np.broadcast_to((u > 24 + 1)[None, :], (H, W))
    off = warp_depth(deep, src, dst, DepthWarpParams(dilate=False, unseen_reject=False))
    assert (off.depth[strip] == 8.0).all() and (off.layer[strip] == 1).all()
    on = warp_depth(deep, src, dst, DepthWarpParams(dilate=False))
    assert on.hole[strip].all()
    np.testing.assert_array_equal(on.depth[seen], 2.0)
    # The disocclusion case (test_disocclusion_stays_a_hole...) is a sideways step too: there the
    # ray leaves the source's view only near the camera, far in front of the surface at that
    # border, and layer 1 is still accepted (asserted there).


def test_skip_farther_does_not_change_the_two_plane_result():
    # The skip only drops searches whose layer cannot hold a nearer sample (depthwarp.h "skip");
    # on this scene no cross-layer climb leaves the bound, so the outputs are identical.
    deep = two_plane_scene()
    src, dst = cam_at(), cam_at((0.4, -0.2, 0.3))
    a = warp_depth(deep, src, dst, DepthWarpParams(skip_farther=True))
    b = warp_depth(deep, src, dst, DepthWarpParams(skip_farther=False))
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.layer, b.layer)
    assert a.stats["searches"] < b.stats["searches"]


def test_synthetic_frame_pair_against_the_reference_depth():
    # Frames 9 -> 10 of the crowd preset's walk path at 192x108, reference depth by Embree. The
    # floors are well below what we measure (L=1: 30.6 dB / SSIM 0.979, L=3: 31.7 dB / 0.981; VFW
    # and AFW ~22.7 dB / 0.930): they catch a broken warp, not a small drift. At equal L ours beats
    # both forward baselines (paper Table 1: their expanded splats bleed over every edge).
    from ibrtools import metrics, synth
    from ibrtools.raycast.reference import ReferenceRenderer

    mesh, built = synth.build_mesh("crowd", size=(192, 108), path_frames=11)
    c0, c1 = built.paths["walk"][9], built.paths["walk"][10]
    rr = ReferenceRenderer(mesh)
    ref = rr.render(c1, outputs=("depth",))["depth"]
    far = float(ref.max())
    for L in (1, 3):
        deep = rr.peel(c0, L, ground_object=0 if L > 1 else None).depth
        ours = warp_depth(deep, c0, c1, DepthWarpParams(seeds=16, dilate=False)).depth
        p_ours, s_ours = metrics.psnr(ours / far, ref / far), metrics.ssim(ours / far, ref / far)
        assert p_ours > 25 and s_ours > 0.9, (L, p_ours, s_ours)
        for kind in ("vfw", "afw"):
            fw = forward_warp_depth(deep, c0, c1, kind).depth
            assert p_ours > metrics.psnr(fw / far, ref / far) + 3, (L, kind)
            assert s_ours > metrics.ssim(fw / far, ref / far), (L, kind)


def test_scratch_reuse_between_calls_does_not_leak_results():
    # warp_depth keeps this thread's motion buffer and mipmaps for the next call of the same shape.
    deep = two_plane_scene()
    other = np.stack([plane(3.0), plane(6.0)])
    src, dst = cam_at(), cam_at((0.3, 0.1, 0.2))
    first = warp_depth(deep, src, dst, DepthWarpParams(oriented=True))
    warp_depth(other, src, cam_at((-0.2, 0, 0)))
    again = warp_depth(deep, src, dst, DepthWarpParams(oriented=True))
    np.testing.assert_array_equal(first.depth, again.depth)
    np.testing.assert_array_equal(first.layer, again.layer)
    assert first.stats == again.stats


def test_dilation_closes_cracks_but_not_wide_holes():
    # Zero motion: the warp reproduces the input, holes where it is empty. A 1-px crack has 6
    # converged neighbours (>= 5: filled with the smaller of its edge neighbours' depths); a 3-px
    # band's middle column has none and its border columns 3 (< 5): the band stays a hole.
    d = np.where(np.arange(W)[None, :] < W // 2, 4.0, 6.0).astype(np.float32).repeat(H, 0)
    d[:, 20] = 0           # crack between 4.0 and 4.0
    d[:, W // 2] = 0       # crack between 4.0 (left) and 6.0 (right)
    d[:, 70:73] = 0        # 3 px band
    cam = cam_at()
    off = warp_depth(d, cam, cam, DepthWarpParams(dilate=False))
    np.testing.assert_array_equal(off.hole, d == 0)
    on = warp_depth(d, cam, cam, DepthWarpParams(dilate=True))
    # (rows 0 and H-1: only 4 neighbours exist there, so the crack's end pixels stay holes)
    np.testing.assert_array_equal(on.depth[1:-1, 20], 4.0)
    np.testing.assert_array_equal(on.depth[1:-1, W // 2], 4.0)  # nearest neighbours tie: the smaller depth
    assert on.hole[[0, -1]][:, [20, W // 2]].all()
    assert on.hole[:, 70:73].all()
    assert on.stats["dilated_pixels"] == 2 * (H - 2)
    assert (on.layer[1:-1, 20] == 0).all()


# Proven occluder depth (warp_depth(..., surface_ids=...): cpp/kernels/depthwarp/depthwarp.h "proof").

def test_proof_of_a_shifted_plane_stops_at_the_seam_between_two_surfaces():
    # A plane at z = 4 seen after a sideways step of (0.125, 0.0625): every pixel moves by exactly
    # (-2.5, -1.25) px, so target pixel (x, y) has its preimage at source (x + 3, y + 1.75): half-way
    # between source columns x + 2 and x + 3, a quarter row below row y + 1's centre. Surface ids 1
    # (columns < 48) and 2: the target column whose preimage straddles columns 47 | 48 (x = 45) lies
    # between the two surfaces' samples and is not proven; every other pixel whose preimage has
    # source centres on both sides is proven, at one float ulp above 4 (the triangles' farthest z).
    ids = np.where(np.arange(W)[None, :] < 48, 1, 2).astype(np.int32) * np.ones((H, 1), np.int32)
    src, dst = cam_at(), cam_at((0.125, 0.0625, 0.0))
    r = warp_depth(plane(4.0), src, dst, DepthWarpParams(dilate=False), surface_ids=ids)
    expected = np.zeros((H, W), np.float32)
    expected[:70, :93] = np.nextafter(np.float32(4.0), np.float32(np.inf))  # x + 3 <= 95.5, y + 1.75 <= 71.5
    expected[:, 45] = 0
    np.testing.assert_array_equal(r.occluder, expected)
    # The depth is the converged samples' (exactly 4 where a source pixel exists), proof or not.
    plain = warp_depth(plane(4.0), src, dst, DepthWarpParams(dilate=False))
    np.testing.assert_array_equal(r.depth, plain.depth)
    np.testing.assert_array_equal(r.layer, plain.layer)
    assert plain.occluder is None and r.stats["proven_fraction"] == pytest.approx((70 * 92) / (H * W))


def test_proof_is_never_nearer_than_the_reference_depth():
    """Crowd walk frames at 160 x 90, three peeled layers (ibr-render --cull's warp): wherever a depth
    is proven it is >= the depth the reference renderer sees there (the proof's meaning; the bound is
    one ulp above a triangle corner's float z, the reference's float z is within 1e-6 relative of the
    exact one), nothing is proven where the reference sees no surface, and the depth and layer
    outputs are the same as without surface_ids."""
    from ibrtools import synth
    from ibrtools.depthwarp.method import warp_with_far_plane
    from ibrtools.raycast.reference import ReferenceRenderer

    mesh, built = synth.build_mesh("crowd", size=(160, 90), views=1, holdout_targets=0, path_frames=4)
    ref = ReferenceRenderer(mesh)
    cams = built.paths["walk"]
    p = DepthWarpParams(seeds=4, dilate=False)
    proven = 0
    for t in (1, 2, 3):
        deep = ref.peel(cams[t - 1], 3)
        a = warp_with_far_plane(deep.depth, cams[t - 1], cams[t], mesh.bounds(), "none", p)
        b = warp_with_far_plane(deep.depth, cams[t - 1], cams[t], mesh.bounds(), "none", p,
                                surface_ids=deep.object_id)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.layer, b.layer)
        truth = ref.render(cams[t], outputs=("depth",), lights=[])["depth"]
        occ = b.occluder
        assert not np.any(occ[truth <= 0])
        m = occ > 0
        assert np.all(occ[m] >= truth[m] * np.float32(1 - 1e-6))
        proven += int(m.sum())
    assert proven > 0.4 * 3 * 160 * 90  # measured 48 %: the ground and the boxes; ~40 % is sky


def test_surface_ids_bad_inputs():
    src, dst = cam_at(), cam_at((0.1, 0.0, 0.0))
    with pytest.raises(DtypeError, match="surface_ids"):
        warp_depth(plane(4.0), src, dst, surface_ids=np.zeros((H, W), np.int64))
    with pytest.raises(ShapeError, match="surface_ids"):
        warp_depth(plane(4.0), src, dst, surface_ids=np.zeros((2, H, W), np.int32))
    with pytest.raises(DtypeError, match="surface_ids"):
        warp_depth(plane(4.0), src, dst, surface_ids=[[1]])
    # The binding's own checks (the front never sends these).
    packed = _core.dw_motion(plane(4.0)[None], src.to_core(), dst.to_core(), None, None)
    mips = _core.dw_build_mips(packed)
    with pytest.raises(ShapeError, match="surface_ids"):
        _core.dw_warp(packed, mips, H, W, surface_ids=np.zeros((1, H, W + 1), np.int32))
    assert _core.dw_warp(packed, mips, H, W)[3] is None
