"""Numerical stress suite (issue 9, item 1): every bound kernel family at the edges of its input
domain, with hypothesis (bounded: few examples, small images, no deadline; derandomised so a CI
failure reproduces).

Edges drawn: depth near 0 (down to float32 denormals) and near float32 max, depth ranges
1e-3 .. 1e6 in one map, focal lengths 1 .. 1e6 px, the camera on or behind the surface, motion
of 0 and of thousands of pixels, images of 1x1 / 1xN / Nx1 / odd sizes / sizes just past the
16-pixel tiles, constant images, all-hole masks, denormal colours. Properties: no NaN (and no
Inf where the output is a colour or a weight) in any output, outputs within the range of the
inputs where the operation is a convex combination, identical results for 1 and 2 threads, and
a typed ibrtools error (InputError) instead of a crash where the input is invalid.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from ibrtools import Camera, _core, look_at
from ibrtools.errors import InputError

N = 20  # examples per property: the whole file runs in well under a minute on 2 cores
STRESS = settings(max_examples=N, deadline=None, derandomize=True, database=None,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                         HealthCheck.filter_too_much])
F32_MAX = float(np.finfo(np.float32).max)
DENORMAL = float(np.finfo(np.float32).tiny) / 8  # 1.5e-39: a float32 subnormal

SIZES = st.sampled_from([(1, 1), (1, 7), (7, 1), (3, 3), (5, 9), (17, 16), (16, 17), (33, 31), (24, 40)])
BIG_SIZES = st.sampled_from([(7, 7), (9, 13), (17, 16), (16, 17), (33, 31), (24, 40)])  # >= 7x7 (SSIM, pyramids)


def threads(n: int):
    """Context: run the engine with ``n`` threads, then restore."""
    class _T:
        def __enter__(self):
            self.old = _core.get_num_threads()
            _core.set_num_threads(n)

        def __exit__(self, *a):
            _core.set_num_threads(self.old)
    return _T()


def same_for_1_and_2_threads(fn):
    with threads(1):
        a = fn()
    with threads(2):
        b = fn()
    for x, y in zip(a if isinstance(a, tuple) else (a,), b if isinstance(b, tuple) else (b,)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg="result depends on the thread count")
    return a


@st.composite
def depth_maps(draw, h, w, *, holes=True):
    """float32 depth (h, w) spanning a drawn range inside [denormal, float max], with zeros (unknown)."""
    lo = draw(st.sampled_from([DENORMAL, 1e-30, 1e-3, 0.5, 1.0]))
    hi = draw(st.sampled_from([1e-3, 1.0, 10.0, 1e6, 1e30, F32_MAX]))
    lo, hi = min(lo, hi), max(lo, hi)
    seed = draw(st.integers(0, 2**16))
    rng = np.random.default_rng(seed)
    kind = draw(st.sampled_from(["log-uniform", "constant", "two-level"]))
    if kind == "constant":
        d = np.full((h, w), hi, np.float64)
    elif kind == "two-level":
        d = np.where(rng.uniform(size=(h, w)) < 0.5, lo, hi)
    else:
        d = np.exp(rng.uniform(np.log(lo), np.log(hi), (h, w)))
    d = d.astype(np.float32)
    if holes and draw(st.booleans()):
        frac = draw(st.sampled_from([0.1, 0.5, 1.0]))
        d[rng.uniform(size=(h, w)) < frac] = 0.0
    return d


@st.composite
def colours(draw, h, w, c=3):
    kind = draw(st.sampled_from(["noise", "constant", "denormal", "black"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    if kind == "noise":
        return rng.uniform(0, 1, (h, w, c)).astype(np.float32)
    if kind == "constant":
        return np.full((h, w, c), draw(st.sampled_from([0.25, 1.0])), np.float32)
    if kind == "denormal":
        return np.full((h, w, c), DENORMAL, np.float32)
    return np.zeros((h, w, c), np.float32)


def pinhole(h, w, f, eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, 1.0)):
    return Camera.pinhole(w, h, f, f, w / 2, h / 2, look_at(list(eye), list(target)))


FOCALS = st.sampled_from([1.0, 3.7, 100.0, 1e4, 1e6])
MOTIONS = st.sampled_from([0.0, 1e-6, 0.01, 0.3, 5.0, 1e3])


# --- cameras -----------------------------------------------------------------------------------------
@STRESS
@given(size=SIZES, f=FOCALS, data=st.data())
def test_camera_unproject_project_round_trip(size, f, data):
    h, w = size
    cam = Camera.pinhole(w, h, f, f * data.draw(st.sampled_from([1.0, 0.5, 2.0])), w / 2, h / 2,
                         look_at([0.3, -0.2, -1.0], [0.0, 0.1, 2.0]))
    depth = data.draw(depth_maps(h, w, holes=False))
    assume(float(depth.min()) >= 1e-3 and float(depth.max()) <= 1e6)  # the metric range
    pts = cam.unproject(depth)
    assert np.all(np.isfinite(pts))
    uv, z = cam.project(pts)
    assert not np.any(np.isnan(uv)) and not np.any(np.isnan(z))
    np.testing.assert_allclose(z, depth, rtol=1e-9)  # float64 geometry: exact to rounding
    ys, xs = np.mgrid[0:h, 0:w]
    # pixel centres at +0.5; |uv| error ~ eps * |pose translation| * f / z: 1e-9 px relative to f
    np.testing.assert_allclose(uv[..., 0], xs + 0.5, atol=1e-6 * max(1.0, f / float(depth.min())) + 1e-9)
    np.testing.assert_allclose(uv[..., 1], ys + 0.5, atol=1e-6 * max(1.0, f / float(depth.min())) + 1e-9)


@STRESS
@given(size=SIZES, data=st.data())
def test_camera_equirect_round_trip(size, data):
    h, w = size
    cam = Camera.equirect(w, h, (-170, 170), (-80, 80), look_at([0, 0, 0], [0, 0, 1]))
    depth = data.draw(depth_maps(h, w, holes=False))
    assume(float(depth.min()) >= 1e-3 and float(depth.max()) <= 1e6)
    uv, z = cam.project(cam.unproject(depth))
    assert np.all(np.isfinite(uv)) and np.all(np.isfinite(z))
    np.testing.assert_allclose(z, depth, rtol=1e-9)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_camera_bad_focal_is_typed(bad):
    with pytest.raises(InputError):
        Camera.pinhole(4, 4, bad, 1.0, 2, 2)


# --- DIBR forward warp + blending (RVS) -------------------------------------------------------------
@STRESS
@given(size=SIZES, f=FOCALS, motion=MOTIONS, data=st.data())
def test_dibr_forward_warp_and_blend(size, f, motion, data):
    h, w = size
    depth = data.draw(depth_maps(h, w))
    col = data.draw(colours(h, w))
    src = pinhole(h, w, f)
    dst = pinhole(h, w, f, eye=(motion, 0.0, data.draw(st.sampled_from([0.0, -motion, 1.0]))),
                  target=(motion, 0.0, 10.0))

    def run():
        c, d, wt = _core.forward_warp(col, depth, src.to_core(), dst.to_core(), _core.WarpOptions())
        acc = _core.DibrAccumulator(dst.to_core())
        acc.add_view(col, depth, src.to_core(), _core.WarpOptions())
        acc.add_view(col, depth, dst.to_core(), _core.WarpOptions())
        return (c, d, wt) + tuple(acc.result())

    try:
        c, d, wt, bc, bd, conf, hole = same_for_1_and_2_threads(run)
    except InputError:
        assert min(h, w) < 2  # a view needs 2 x 2 pixels to form a triangle: typed refusal
        return
    for name, a in (("colour", c), ("weight", wt), ("blended colour", bc), ("confidence", conf)):
        assert np.all(np.isfinite(a)), f"{name}: NaN/Inf"
    assert not np.any(np.isnan(d)) and not np.any(np.isnan(bd))
    assert np.all(wt >= 0) and np.all(conf >= 0)
    # blending is a weighted mean of input colours: inside their range (float32 rounding slack)
    lo, hi = float(col.min()), float(col.max())
    covered = ~hole.astype(bool)
    if covered.any():
        assert bc[covered].min() >= lo - 1e-5 and bc[covered].max() <= hi + 1e-5


# --- warp with background-depth holes (metameric inpainting's warp) --------------------------------
@STRESS
@given(size=SIZES, f=FOCALS, motion=MOTIONS, data=st.data())
def test_warp_with_holes(size, f, motion, data):
    h, w = size
    depth = data.draw(depth_maps(h, w))
    assume(np.any(depth > 0))
    col = data.draw(colours(h, w))
    src, dst = pinhole(h, w, f), pinhole(h, w, f, eye=(motion, 0.0, 0.0), target=(motion, 0.0, 10.0))
    try:
        out, d, m = same_for_1_and_2_threads(
            lambda: _core.warp_with_holes(col, depth, src.to_core(), dst.to_core()))
    except InputError:
        return  # e.g. a depth the front refuses: typed, fine
    assert np.all(np.isfinite(out)) and not np.any(np.isnan(d))
    lo, hi = float(col.min()), float(col.max())
    assert out.min() >= min(lo, 0.0) - 1e-5 and out.max() <= hi + 1e-5


# --- push-pull ---------------------------------------------------------------------------------------
@STRESS
@given(size=SIZES, data=st.data())
def test_pushpull(size, data):
    from ibrtools.inpaint import pushpull

    h, w = size
    img = data.draw(colours(h, w))
    rng = np.random.default_rng(data.draw(st.integers(0, 999)))
    hole = rng.uniform(size=(h, w)) < data.draw(st.sampled_from([0.0, 0.3, 0.9, 1.0]))
    depth = data.draw(st.one_of(st.none(), depth_maps(h, w)))
    try:
        out = same_for_1_and_2_threads(lambda: pushpull(img, hole, depth))
    except InputError:
        assert hole.all() or depth is not None  # only "nothing to fill from" may be refused
        return
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[~hole], img[~hole])  # known pixels untouched
    if (~hole).any():  # fills are weighted means of known pixels
        assert out.min() >= img[~hole].min() - 1e-5 and out.max() <= img[~hole].max() + 1e-5


# --- steerable pyramid ---------------------------------------------------------------------------------
@STRESS
@given(size=BIG_SIZES, data=st.data())
def test_steerable_analyse_synthesise(size, data):
    from ibrtools import steerable

    h, w = size
    img = data.draw(colours(h, w))
    levels = data.draw(st.integers(0, steerable.max_levels(h, w)))
    orient = data.draw(st.sampled_from([2, 4]))
    out = same_for_1_and_2_threads(lambda: steerable.synthesise(steerable.analyse(img, levels, orient)))
    assert out.shape == img.shape and np.all(np.isfinite(out))
    if float(img.max()) == float(img.min()):
        # a constant image stays constant up to the fitted 5x5 filters' DC gain error (1.5 %, the
        # bound tests/test_steerable.py pins for a constant image)
        np.testing.assert_allclose(out, img, rtol=0.015, atol=1e-30)


# --- metameric inpainting and foveation ---------------------------------------------------------------
@STRESS
@given(size=BIG_SIZES, data=st.data())
def test_metameric(size, data):
    from ibrtools.metameric import metameric

    h, w = size
    img = data.draw(colours(h, w))
    rng = np.random.default_rng(data.draw(st.integers(0, 999)))
    hole = rng.uniform(size=(h, w)) < data.draw(st.sampled_from([0.0, 0.3, 0.9, 1.0]))
    try:
        out = same_for_1_and_2_threads(lambda: metameric(img, hole, levels=2, seed=1))
    except InputError:
        assert hole.all()
        return
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[~hole], img[~hole])


@STRESS
@given(size=BIG_SIZES, data=st.data())
def test_foveate(size, data):
    from ibrtools.foveate import foveate

    h, w = size
    img = data.draw(colours(h, w))
    fix = (data.draw(st.sampled_from([0.0, 0.5, 1.0])), data.draw(st.sampled_from([0.0, 0.5, 1.0])))
    pooling = data.draw(st.sampled_from([0.0, 0.5, 4.0]))
    out = same_for_1_and_2_threads(lambda: foveate(img, fix, levels=2, pooling=pooling))
    assert out.shape == img.shape and np.all(np.isfinite(out))


# --- SSIM --------------------------------------------------------------------------------------------
@STRESS
@given(size=BIG_SIZES, data=st.data())
def test_ssim(size, data):
    from ibrtools.metrics import ssim

    h, w = size
    a, b = data.draw(colours(h, w)), data.draw(colours(h, w))
    v = same_for_1_and_2_threads(lambda: ssim(a, b))
    assert np.isfinite(v) and -1.0 - 1e-6 <= v <= 1.0 + 1e-6
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-5)  # constant and denormal images included
    assert ssim(a, b) == pytest.approx(ssim(b, a), abs=1e-6)  # symmetric


# --- iterative depth warping ------------------------------------------------------------------------
@STRESS
@given(size=SIZES, f=FOCALS, motion=MOTIONS, data=st.data())
def test_depthwarp(size, f, motion, data):
    from ibrtools.depthwarp import DepthWarpParams, warp_depth

    h, w = size
    depth = data.draw(depth_maps(h, w))
    src = pinhole(h, w, f)
    dst = pinhole(h, w, f, eye=(motion, 0.0, -motion), target=(motion, 0.0, 10.0))
    try:
        r = same_for_1_and_2_threads(lambda: warp_depth(depth, src, dst, DepthWarpParams()).depth)
    except InputError:
        return
    assert not np.any(np.isnan(r)) and np.all(r >= 0)


# --- occlusion culling (N-buffers over the warped depth) ---------------------------------------------
@STRESS
@given(size=SIZES, f=FOCALS, data=st.data())
def test_culling(size, f, data):
    from ibrtools.culling import cull_objects

    h, w = size
    depth = data.draw(depth_maps(h, w))
    hole = data.draw(st.sampled_from([None, "none", "all"]))
    hole = None if hole is None else np.full((h, w), hole == "all")
    scale = data.draw(st.sampled_from([1e-3, 1.0, 1e3, 1e6]))
    boxes = np.array([[[-1, -1, 1], [1, 1, 2]], [[-1, -1, -2], [1, 1, -1]], [[-1, -1, 0], [1, 1, 0]]],
                     np.float32) * scale  # in front, behind the camera, through the camera
    res = same_for_1_and_2_threads(lambda: np.asarray(cull_objects(depth, hole, pinhole(h, w, f), boxes).visible))
    assert res.shape == (3,)
    assert not res[1]  # behind the camera: never visible
    if hole is not None and hole.all():
        assert res[0]  # holes never occlude: a box in the frustum stays


# --- ray casting (reference renderer): degenerate triangles, camera on the surface ------------------
@STRESS
@given(size=SIZES, f=FOCALS, data=st.data())
def test_raycast_degenerate_and_on_surface(size, f, data):
    from ibrtools.mesh import Mesh
    from ibrtools.render.reference import ReferenceRenderer

    h, w = size
    s = data.draw(st.sampled_from([1e-3, 1.0, 1e3]))
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [0, 0, 0], [0, 0, 0]], np.float32) * s
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 4, 5], [0, 0, 1]], np.int32)  # two degenerate
    r = ReferenceRenderer(Mesh(v, faces))
    z = data.draw(st.sampled_from([-1.0, -1e-6, 0.0, 1.0]))  # in front, almost on, on, behind
    cam = pinhole(h, w, f, eye=(0.1 * s, 0.2 * s, z * s), target=(0.1 * s, 0.2 * s, (z + 1) * s))
    out = same_for_1_and_2_threads(lambda: tuple(r.render(cam, outputs=("color", "depth")).values()))
    for a in out:
        assert not np.any(np.isnan(a))
    col = out[0]
    assert np.all(np.isfinite(col))


# --- the failures the properties found, pinned -------------------------------------------------------
@pytest.mark.parametrize("depth_value", [DENORMAL, 4.3e-38, F32_MAX], ids=["subnormal", "tiny", "float-max"])
def test_found_forward_warp_extreme_depth_is_finite(depth_value):
    """Depth 1.5e-39 / 4.3e-38 gave NaN colours, depth 3.4e38 gave inf (forward_warp.cpp, InvDepth)."""
    h, w = 5, 9
    col = np.random.default_rng(0).uniform(0, 1, (h, w, 3)).astype(np.float32)
    depth = np.full((h, w), depth_value, np.float32)
    cam = pinhole(h, w, 1.0)
    try:
        c, d, wt = _core.forward_warp(col, depth, cam.to_core(), cam.to_core(), _core.WarpOptions())
    except InputError:
        # a library loaded earlier in the same process (under pytest-xdist) may have set the CPU's
        # denormals-are-zero mode: the subnormal depth is then 0 = unknown, refused typed
        assert depth_value == DENORMAL
        return
    assert np.all(np.isfinite(c)) and np.all(np.isfinite(wt)) and not np.any(np.isnan(d))
    out, d2, _ = _core.warp_with_holes(col, depth, cam.to_core(), cam.to_core())
    assert np.all(np.isfinite(out)) and not np.any(np.isnan(d2))
    inner = (slice(1, -1), slice(1, -1))
    np.testing.assert_allclose(out[inner], col[inner], atol=1e-5)  # identity warp: the same colours


# --- the array boundary: wrong dtype, shape, strides, read-only, NaN ---------------------------------
def _boundary_cases():
    h, w = 12, 16
    rng = np.random.default_rng(3)
    col = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    dep = rng.uniform(1, 3, (h, w)).astype(np.float32)
    hole = rng.uniform(size=(h, w)) < 0.3
    cam = pinhole(h, w, 12.0).to_core()
    return {
        "forward_warp": (lambda c, d: _core.forward_warp(c, d, cam, cam, _core.WarpOptions()), [col, dep]),
        "warp_with_holes": (lambda c, d: _core.warp_with_holes(c, d, cam, cam), [col, dep]),
        "inpaint.pushpull": (lambda c, m: __import__("ibrtools.inpaint", fromlist=["x"]).pushpull(c, m), [col, hole]),
        "metrics.ssim": (lambda a, b: __import__("ibrtools.metrics", fromlist=["x"]).ssim(a, b), [col, col]),
        "steerable.analyse": (lambda c: __import__("ibrtools.steerable", fromlist=["x"]).analyse(c, 2), [col]),
        "depthwarp.warp_depth": (lambda d: __import__("ibrtools.depthwarp", fromlist=["x"]).warp_depth(
            d, pinhole(h, w, 12.0), pinhole(h, w, 12.0)), [dep]),
    }


MUTATIONS = ["float64", "int32", "transposed", "strided", "read-only", "extra-dim", "flattened", "empty",
             "nan", "inf", "list"]


def _mutate(a: np.ndarray, how: str):
    if how == "float64":
        return a.astype(np.float64)
    if how == "int32":
        return a.astype(np.int32)
    if how == "transposed":
        return np.swapaxes(a, 0, 1)
    if how == "strided":
        big = np.repeat(a, 2, axis=1)
        return big[:, ::2]  # same shape and values, not contiguous
    if how == "read-only":
        b = a.copy()
        b.setflags(write=False)
        return b
    if how == "extra-dim":
        return a[..., None]
    if how == "flattened":
        return a.reshape(-1)
    if how == "empty":
        return a[:0]
    if how in ("nan", "inf"):
        b = a.astype(a.dtype)
        if b.dtype.kind == "f":
            b.flat[5] = np.nan if how == "nan" else np.inf
        return b
    return a.tolist()


@pytest.mark.parametrize("entry", list(_boundary_cases()))
@pytest.mark.parametrize("how", MUTATIONS)
def test_array_boundary_is_typed(entry, how):
    """Every mutated argument: a result (read-only, strided inputs are fine) or an InputError
    naming the argument; never a crash, a pybind11 TypeError or silent garbage (no NaN out)."""
    fn, args = _boundary_cases()[entry]
    for i in range(len(args)):
        mutated = list(args)
        mutated[i] = _mutate(args[i], how)
        try:
            out = fn(*mutated)
        except InputError as e:
            assert str(e)
            continue
        if how in ("read-only", "strided"):
            continue  # a valid input in another layout: accepted
        arrays = [o for o in (out if isinstance(out, tuple) else (out,)) if isinstance(o, np.ndarray)]
        for o in arrays:
            if o.dtype.kind == "f" and how not in ("inf",):
                assert not np.any(np.isnan(o)), f"{entry}: {how} argument {i} gave NaN output"
