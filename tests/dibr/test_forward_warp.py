"""Forward mesh warp and streaming blending (cpp/kernels/dibr/forward_warp.h, blend.h, _core DIBR API).

Tolerances:
* Identity warp: PSNR > 60 dB away from borders. Vertices land within 1/512 px of pixel
  centres after the 1/256 px snap, so barycentrics are exact to ~1e-5 and colour to float
  rounding (~1e-7): > 100 dB expected; 60 dB is the issue's bound.
* Analytic plane: depth rtol 1e-4 -- vertex positions snapped to 1/256 px change the
  interpolated 1/z by at most slope * 1/512 px (~1e-5 relative here) plus float rounding.
  Position: the warped texture is a linear ramp in x, so colour = ramp at the analytic source
  position; 1e-3 of the ramp range = 0.03 px, above the 1/512 px snap, far below a
  half-pixel convention error (0.5 px = 1.7e-2 here).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from gil import runs_python_during

from ibrtools import BadValueError, Camera, DtypeError, ShapeError, _core, look_at

pytestmark = [pytest.mark.asan, pytest.mark.kernel]


def psnr(a, b):
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return math.inf if mse == 0 else -10 * math.log10(mse)


def noise_image(h, w, seed=0):
    return np.random.default_rng(seed).random((h, w, 3), dtype=np.float32)


@pytest.fixture
def restore_threads():
    yield
    _core.set_num_threads(0)


def test_identity_warp_reproduces_input():
    cam = Camera.from_fov(96, 64, 60, look_at([0, 0, 0], [0, 0, 1]))
    col = noise_image(64, 96)
    dep = (3 + np.random.default_rng(1).random((64, 96))).astype(np.float32)
    c, d, w = _core.forward_warp(col, dep, cam.to_core(), cam.to_core(), _core.WarpOptions())
    inner = (slice(1, -1), slice(1, -1))
    assert psnr(c[inner], col[inner]) > 60
    np.testing.assert_allclose(d[inner], dep[inner], rtol=1e-5)
    assert (w[inner] > 0).all() and np.isfinite(w).all()


def test_fronto_parallel_plane_translation_analytic():
    w_, h_, z = 80, 60, 4.0
    src = Camera.from_fov(w_, h_, 60, look_at([0, 0, 0], [0, 0, 1]))
    shift = np.array([0.3, -0.1, 0.5])  # target camera moved right, up, forward
    dst = Camera.from_fov(w_, h_, 60, look_at(shift, shift + [0, 0, 1]))
    ramp = np.broadcast_to(np.arange(w_, dtype=np.float32)[None, :, None] + 0.5, (h_, w_, 3)).copy()
    dep = np.full((h_, w_), z, np.float32)
    c, d, wt = _core.forward_warp(ramp, dep, src.to_core(), dst.to_core(), _core.WarpOptions())
    cov = wt > 0
    assert cov.mean() > 0.5
    np.testing.assert_allclose(d[cov], z - shift[2], rtol=1e-4)
    # Analytic: the target pixel centre at depth z - tz is a world point on the plane; its
    # source x is where the source camera sees it (camera.py's own projection, float64).
    xy, _ = src.project(dst.unproject(np.full((h_, w_), z - shift[2])))
    expect = xy[..., 0]
    np.testing.assert_allclose(c[..., 0][cov], expect[cov], atol=1e-3 * w_)
    # coverage = the target pixels whose source position is inside the pixel-centre hull
    inside = (expect > 0.5 + 1e-3) & (expect < w_ - 0.5 - 1e-3) & (xy[..., 1] > 0.5 + 1e-3) & (xy[..., 1] < h_ - 0.5 - 1e-3)
    outside = (expect < 0.5 - 1e-3) | (expect > w_ - 0.5 + 1e-3) | (xy[..., 1] < 0.5 - 1e-3) | (xy[..., 1] > h_ - 0.5 + 1e-3)
    assert cov[inside].all() and not cov[outside].any()


def test_two_inputs_fill_complementary_holes():
    cam = Camera.from_fov(64, 48, 60, look_at([0, 0, 0], [0, 0, 1]))
    col = noise_image(48, 64)
    dep = np.full((48, 64), 3.0, np.float32)
    left, right = dep.copy(), dep.copy()
    left[:, 40:] = 0.0   # unknown on the right
    right[:, :20] = 0.0  # unknown on the left
    acc = _core.DibrAccumulator(cam.to_core())
    acc.add_view(col, left, cam.to_core(), _core.WarpOptions())
    _, _, _, hole1 = acc.result()
    assert hole1[1:-1, 45:-1].all()
    acc.add_view(col, right, cam.to_core(), _core.WarpOptions())
    c, d, conf, hole = acc.result()
    assert acc.num_views == 2
    assert not hole[1:-1, 1:-1].any()
    assert psnr(c[1:-1, 1:-1], col[1:-1, 1:-1]) > 60
    assert np.isfinite(c).all() and np.isfinite(d).all() and np.isfinite(conf).all()
    # overlap (both views) has twice the confidence of the single-view parts
    assert conf[10, 30] == pytest.approx(2 * conf[10, 5], rel=1e-6)


def test_equirect_to_perspective_and_back():
    # A sphere of radius 5 around the camera, textured by longitude.
    eq = Camera.equirect(256, 128)
    x, y = np.meshgrid(np.arange(256) + 0.5, np.arange(128) + 0.5)
    lon = -math.pi + x / 256 * 2 * math.pi
    col = np.stack([np.sin(lon) * 0.5 + 0.5, np.cos(lon) * 0.5 + 0.5, y / 128], -1).astype(np.float32)
    dep = np.full((128, 256), 5.0, np.float32)
    persp = Camera.from_fov(64, 64, 60, look_at([0, 0, 0], [1, 0, 1]))
    c, d, w = _core.forward_warp(col, dep, eq.to_core(), persp.to_core(), _core.WarpOptions())
    assert (w > 0).all()
    # pinhole depth is z = 5 cos(angle from the axis)
    rays = persp.rays_in_cam(*persp.pixel_grid())
    np.testing.assert_allclose(d, 5.0 / np.linalg.norm(rays, axis=-1), rtol=1e-3)
    # back: the perspective view into the equirect; covered where it looks (around lon = 45 deg)
    c2, d2, w2 = _core.forward_warp(c, d, persp.to_core(), eq.to_core(), _core.WarpOptions())
    cov = w2 > 0
    assert cov[64, 160] and not cov[64, 40]  # lon 45 deg seen; lon -120 deg not
    np.testing.assert_allclose(d2[cov], 5.0, rtol=1e-3)
    assert psnr(c2[cov], col[cov]) > 30  # two resamplings of a smooth texture


def test_rotated_camera_no_holes():
    src = Camera.from_fov(128, 96, 90, look_at([0, 0, 0], [0, 0, 1]))
    dst = Camera.from_fov(64, 48, 40, look_at([0, 0, 0], [0.2, 0.1, 1]))  # inside the source's fov
    rng = np.random.default_rng(2)
    dep = (2 + 3 * rng.random((96, 128))).astype(np.float32)
    c, d, w = _core.forward_warp(noise_image(96, 128), dep, src.to_core(), dst.to_core(), _core.WarpOptions())
    assert (w > 0).all()


def test_no_cracks_dense_random_depth():
    """Pure rotation of a random-depth mesh: the warped mesh is a fold-free map of the input
    grid, so every target pixel inside the projected hull is covered exactly once. Coverage
    count: warp a constant-1 colour with 'nearest' test and check the hull interior is full;
    exactly-once: sum over the two triangle sets of each block is tested via identity warps of
    random depth (weights finite, all covered)."""
    rng = np.random.default_rng(3)
    cam = Camera.from_fov(128, 128, 70, look_at([0, 0, 0], [0, 0, 1]))
    dep = np.exp(rng.normal(1.0, 0.8, (128, 128))).astype(np.float32)
    tgt = Camera.from_fov(100, 100, 55, look_at([0, 0, 0], [0.1, -0.05, 1]))
    c, d, w = _core.forward_warp(noise_image(128, 128), dep, cam.to_core(), tgt.to_core(), _core.WarpOptions())
    assert (w > 0).all() and np.isfinite(w).all() and np.isfinite(c).all()
    # translated: random depths fold the mesh, but no pixel may get NaN/inf and coverage stays dense
    tgt2 = Camera.from_fov(100, 100, 55, look_at([0.05, 0, 0], [0.05, 0, 1]))
    c2, d2, w2 = _core.forward_warp(noise_image(128, 128), dep, cam.to_core(), tgt2.to_core(), _core.WarpOptions())
    assert np.isfinite(w2).all() and np.isfinite(c2).all() and np.isfinite(d2).all()
    assert (w2 > 0).mean() > 0.95


def test_exact_coverage_of_the_hull():
    """Sub-pixel translation of a constant-depth plane: the covered target pixels are exactly
    those whose centre maps inside the source's pixel-centre rectangle (no crack inside, nothing
    outside), computed analytically with camera.py in float64."""
    src = Camera.from_fov(64, 64, 60, look_at([0, 0, 0], [0, 0, 1]))
    off = np.array([0.0123, 0.0071, 0.0])
    dst = Camera.from_fov(64, 64, 60, look_at(off, off + [0, 0, 1]))
    dep = np.full((64, 64), 2.0, np.float32)
    c, d, w = _core.forward_warp(noise_image(64, 64), dep, src.to_core(), dst.to_core(), _core.WarpOptions())
    xy, _ = src.project(dst.unproject(np.full((64, 64), 2.0)))
    margin = 1e-3  # px: stay clear of centres lying on the hull boundary (fill-rule ties)
    inside = ((xy > 0.5 + margin) & (xy < 63.5 - margin)).all(-1)
    outside = ((xy < 0.5 - margin) | (xy > 63.5 + margin)).any(-1)
    assert inside.sum() > 3500
    assert (w[inside] > 0).all() and not (w[outside] > 0).any()


def test_thread_count_does_not_change_results(restore_threads):
    rng = np.random.default_rng(4)
    src = Camera.from_fov(160, 120, 60, look_at([0, 0, 0], [0, 0, 1]))
    dst = Camera.from_fov(150, 130, 60, look_at([0.2, 0.1, 0], [0, 0, 4]))
    dep = (2 + 2 * rng.random((120, 160))).astype(np.float32)
    col = noise_image(120, 160)
    out = []
    for n in (1, 2):
        _core.set_num_threads(n)
        acc = _core.DibrAccumulator(dst.to_core())
        acc.add_view(col, dep, src.to_core(), _core.WarpOptions())
        acc.add_view(col[::-1].copy(), dep[::-1].copy(), src.to_core(), _core.WarpOptions())
        out.append(acc.result())
    for a, b in zip(*out):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("quality", ["side", "shape", "depth", "normal"])
def test_qualities_and_depth_test_run(quality):
    src = Camera.from_fov(64, 48, 60, look_at([0, 0, 0], [0, 0, 1]))
    dst = Camera.from_fov(64, 48, 60, look_at([0.3, 0, 0], [0, 0, 3]))
    dep = np.full((48, 64), 3.0, np.float32)
    dep[15:30, 20:40] = 1.5  # a foreground box: disocclusion and stretched triangles
    opts = _core.WarpOptions()
    opts.quality = quality
    for test in ("combined", "nearest"):
        opts.depth_test = test
        c, d, w = _core.forward_warp(noise_image(48, 64), dep, src.to_core(), dst.to_core(), opts)
        assert np.isfinite(w).all() and (w >= 0).all() and (w > 0).mean() > 0.8
        # the foreground box wins where it lands (its depth ~1.5 appears)
        assert (np.abs(d - 1.5) < 0.1).sum() > 100


def test_sky_at_infinity_equirect():
    eq = Camera.equirect(128, 64, cam_from_world=look_at([0, 0, 0], [0, 0, 1]))  # same axes as persp
    dep = np.full((64, 128), np.inf, np.float32)
    dep[40:] = 3.0  # ground band below
    persp = Camera.from_fov(48, 48, 60, look_at([0.1, 0, 0], [0.1, 0, 1]))
    acc = _core.DibrAccumulator(persp.to_core())
    acc.add_view(noise_image(64, 128), dep, eq.to_core(), _core.WarpOptions())
    c, d, conf, hole = acc.result()
    assert np.isfinite(c).all() and not np.isnan(d).any()
    assert np.isinf(d[5, 24]) and not hole[5, 24]


def test_gil_released(restore_threads):
    rng = np.random.default_rng(5)
    n = 512
    cam = Camera.from_fov(n, n, 60, look_at([0, 0, 0], [0, 0, 1]))
    dst = Camera.from_fov(n, n, 60, look_at([0.1, 0, 0], [0, 0, 3]))
    dep = (2 + rng.random((n, n))).astype(np.float32)
    col = noise_image(n, n)
    acc = _core.DibrAccumulator(dst.to_core())
    _core.set_num_threads(1)
    def work():
        for _ in range(6):
            acc.add_view(col, dep, cam.to_core())

    assert runs_python_during(work), "no Python ran during the warps (or they lasted < 20 ms)"


def test_result_never_nan_and_holes_black():
    cam = Camera.from_fov(32, 32, 60)
    acc = _core.DibrAccumulator(cam.to_core())
    c, d, conf, hole = acc.result()  # nothing added: all holes
    assert hole.all() and (c == 0).all() and (d == 0).all() and (conf == 0).all()


def test_bad_inputs():
    cam = Camera.from_fov(32, 24, 60)
    core = cam.to_core()
    col = noise_image(24, 32)
    dep = np.full((24, 32), 2.0, np.float32)
    acc = _core.DibrAccumulator(core)
    with pytest.raises(ShapeError, match="depth"):
        acc.add_view(col, dep[:, :30].copy(), core)  # size not matching the camera
    with pytest.raises(ShapeError, match="color"):
        acc.add_view(col[:20].copy(), dep, core)  # colour / depth size mismatch
    with pytest.raises(DtypeError, match="depth"):
        acc.add_view(col, dep.astype(np.float64), core)
    with pytest.raises(DtypeError, match="color"):
        acc.add_view([[0.0]], dep, core)
    with pytest.raises(ShapeError, match="C-contiguous"):
        acc.add_view(np.asfortranarray(col), dep, core)
    with pytest.raises(ShapeError, match="depth"):
        acc.add_view(np.zeros((0, 0, 3), np.float32), np.zeros((0, 0), np.float32), core)
    tiny = Camera.from_fov(1, 1, 60).to_core()
    with pytest.raises(ShapeError, match="2 x 2"):
        acc.add_view(np.zeros((1, 1, 3), np.float32), np.ones((1, 1), np.float32), tiny)
    with pytest.raises(BadValueError, match="no valid depth"):
        acc.add_view(col, np.zeros_like(dep), core)
    bad = dep.copy()
    bad[3, 4] = np.nan
    with pytest.raises(BadValueError, match="NaN"):
        acc.add_view(col, bad, core)
    with pytest.raises(BadValueError, match="no valid depth"):
        _core.forward_warp(col, np.zeros_like(dep), core, core, _core.WarpOptions())
    assert acc.num_views == 0 and acc.result()[3].all()  # rejected views never reached the sums
    opts = _core.WarpOptions()
    with pytest.raises(BadValueError, match="quality"):
        opts.quality = "pretty"
    with pytest.raises(BadValueError, match="depth_test"):
        opts.depth_test = "farthest"
    with pytest.raises(BadValueError, match="side_threshold"):
        opts.side_threshold = -1.0
    with pytest.raises(BadValueError, match="blend_exponent"):
        opts.blend_exponent = float("nan")


def test_segments_outside_the_target_change_nothing():
    """Input segments whose vertices all project left or right of the target are never scanned
    (forward_warp.h, "Parallel and deterministic"). A target twice as wide to the right (same
    fx, cx, pose: the same pixel coordinates for x < W) scans them, and its left half must equal
    the narrow target's result bit for bit -- also where triangles straddle the narrow edge."""
    rng = np.random.default_rng(7)
    src = Camera.from_fov(160, 120, 70, look_at([0, 0, 0], [0, 0, 1]))
    dep = (2 + 2 * rng.random((120, 160))).astype(np.float32)
    col = noise_image(120, 160)
    pose = look_at([0.3, 0.05, 0], [0.9, 0, 4])
    narrow = Camera(model="pinhole", width=96, height=110, fx=90.0, fy=90.0, cx=20.5, cy=55.0, cam_from_world=pose)
    wide = Camera(model="pinhole", width=192, height=110, fx=90.0, fy=90.0, cx=20.5, cy=55.0, cam_from_world=pose)
    opts = _core.WarpOptions()
    opts.side_threshold = 10.0  # the same T for both widths (the automatic T scales with the size)
    a = _core.forward_warp(col, dep, src.to_core(), narrow.to_core(), opts)
    b = _core.forward_warp(col, dep, src.to_core(), wide.to_core(), opts)
    assert (a[2] > 0).mean() > 0.5 and (b[2][:, 96:] > 0).any()  # content on both sides of the cut
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y[:, :96])
    # ... and to the left: cx + 96 puts the narrow image at x >= 96 of this one. The projected x
    # differs from the narrow one's + 96 by at most a rounding of the double sum (far below the
    # 1/256 px snap; it would have to straddle a snap boundary to change a vertex).
    left = Camera(model="pinhole", width=192, height=110, fx=90.0, fy=90.0, cx=116.5, cy=55.0, cam_from_world=pose)
    c = _core.forward_warp(col, dep, src.to_core(), left.to_core(), opts)
    assert (c[2][:, :96] > 0).any()
    for x, y in zip(a, c):
        np.testing.assert_array_equal(x, y[:, 96:])


def _rectified_pair(w_, h_, z=4.0, shift_px=0.25):
    """Source and target pinhole cameras of a rectified pair: the target is the source moved by
    shift_px * z / f along x, so a plane at depth z moves by exactly -shift_px (a multiple of the
    1/256 px snap) and every target pixel centre lies on a horizontal edge of the input mesh
    (its y equals a vertex row's)."""
    f = 100.0
    src = Camera(model="pinhole", width=w_, height=h_, fx=f, fy=f, cx=w_ / 2, cy=h_ / 2, cam_from_world=np.eye(4))
    moved = np.eye(4)
    moved[0, 3] = -shift_px * z / f  # the camera at x = +shift z / f: the scene moves left
    dst = Camera(model="pinhole", width=w_, height=h_, fx=f, fy=f, cx=w_ / 2, cy=h_ / 2, cam_from_world=moved)
    return src, dst


def _closed_triangle_coverage(valid: np.ndarray, shift_px: float) -> np.ndarray:
    """Expected coverage with inclusive edges for _rectified_pair: target centre (x + 0.5, y + 0.5)
    is the source point (x + 0.5 + shift, y + 0.5), on the horizontal edge from vertex (u, y) to
    (u + 1, y), u = x (0 < shift < 1). That edge belongs to triangle 0 of quad (u, y) (third vertex
    (u, y + 1)) and to triangle 1 of quad (u, y - 1) (third vertex (u + 1, y - 1)); the centre is
    covered iff the edge's two vertices are valid and so is one of the two third vertices. (The
    exclusive rule gave it to triangle 1 only: the third vertex (u + 1, y - 1) had to be valid.)"""
    h_, w_ = valid.shape
    assert 0.0 < shift_px < 1.0
    v = np.zeros((h_ + 2, w_ + 2), bool)  # padded: vertex (u, y) at [y + 1, u + 1]
    v[1:-1, 1:-1] = valid
    u = np.arange(w_)
    y = np.arange(h_)[:, None]
    edge = v[y + 1, u + 1] & v[y + 1, u + 2]
    return edge & (v[y + 2, u + 1] | v[y, u + 2])


@pytest.mark.parametrize("isa", ["baseline", "avx2"])
def test_inclusive_shared_edges_rectified_pair(isa):
    """Fill rule of the DIBR shader: a target centre exactly on the edge shared by two triangles
    is offered to both, so it stays covered when one of them is dropped (unknown depth). A
    rectified pair puts every target centre on a horizontal mesh edge. One unknown depth pixel
    drops the quads around it; the centre on the top edge of the quad below it (whose lower
    triangle is intact) must stay covered. Coverage everywhere equals the union of the closed
    valid triangles (computed independently above): no cracks, nothing else changed. Colour is
    a ramp in the source x, so it is checked analytically (tolerance: float32 interpolation of
    values < 64, 1e-4 absolute)."""
    if isa == "avx2" and not _core.cpu_has_avx2():
        pytest.skip("this CPU has no AVX2: only the baseline path runs")
    w_, h_, shift = 48, 32, 0.25
    src, dst = _rectified_pair(w_, h_, shift_px=shift)
    dep = np.full((h_, w_), 4.0, np.float32)
    u0, v0 = 20, 10
    dep[v0 - 1, u0] = 0.0  # drops triangle 1 of quad (u0 - 1, v0 - 1), the owner of row v0's edge
    rng = np.random.default_rng(11)
    dep[16:, :][rng.random((h_ - 16, w_)) < 0.1] = 0.0  # more unknown pixels in the lower half
    ramp = np.broadcast_to(np.arange(w_, dtype=np.float32)[None, :, None] + 0.5, (h_, w_, 3)).copy()
    _core.set_warp_isa(isa)
    try:
        c, d, wt = _core.forward_warp(ramp, dep, src.to_core(), dst.to_core(), _core.WarpOptions())
    finally:
        _core.set_warp_isa("auto")
    cov = wt > 0
    expect = _closed_triangle_coverage(dep > 0, shift)
    # the probe: target pixel (v0, u0 - 1) lies on the edge (u0 - 1, v0) - (u0, v0); the exclusive
    # rule would have lost it (its owner touches the unknown vertex), the inclusive rule keeps it
    exclusive_owner_ok = dep[v0 - 1, u0] > 0
    assert not exclusive_owner_ok and expect[v0, u0 - 1] and cov[v0, u0 - 1]
    np.testing.assert_array_equal(cov, expect)
    np.testing.assert_allclose(c[..., 0][cov], (np.arange(w_) + 0.5 + shift)[None, :].repeat(h_, 0)[cov], atol=1e-4)
    np.testing.assert_allclose(d[cov], 4.0, rtol=1e-5)
