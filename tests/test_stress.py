"""Numerical stress suite: every bound kernel family at the edges of its input
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
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st

from ibrtools import Camera, _core, look_at
from ibrtools.errors import InputError

pytestmark = [pytest.mark.asan, pytest.mark.kernel, pytest.mark.tsan]

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
    from ibrtools.inpaint.pushpull import pushpull

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


# --- the completion's kernels: background lookup, hole sides ------------------------------------------
@STRESS
@given(size=SIZES, f=FOCALS, data=st.data())
def test_background_lookup_and_hole_sides(size, f, data):
    h, w = size
    rng = np.random.default_rng(data.draw(st.integers(0, 999)))
    colour = data.draw(colours(h, w))
    depth = data.draw(depth_maps(h, w))
    depth[rng.uniform(size=(h, w)) < data.draw(st.sampled_from([0.0, 0.5, 1.0]))] = np.inf  # background
    clear = rng.uniform(size=(h, w)) < 0.7
    hole = rng.uniform(size=(h, w)) < data.draw(st.sampled_from([0.0, 0.3, 1.0]))
    yaw = data.draw(st.sampled_from([0.0, 0.2, 3.0]))
    target = pinhole(h, w, f, target=(np.sin(yaw), 0.1, np.cos(yaw)))
    inputs = [(pinhole(h, w, f).to_core(), depth, clear, colour),
              (Camera.equirect(w, h, cam_from_world=np.eye(4)).to_core(), depth, clear, colour)]
    base = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    near, far = data.draw(st.sampled_from([(0.0, 0.0), (0.05, 50.0), (1e-6, 1e6)]))  # without / with the ray test

    def lookup():
        out = base.copy()
        return _core.background_lookup(target.to_core(), inputs, hole, out, near=near, far=far), out
    state, out = same_for_1_and_2_threads(lookup)
    assert set(np.unique(state)) <= {0, 1, 2} and (state[~hole] == 0).all()
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[state != 2], base[state != 2])
    if (state == 2).any():  # bilinear over background pixels: within the inputs' colour range
        assert out[state == 2].min() >= colour.min() - 1e-6 and out[state == 2].max() <= colour.max() + 1e-6
    known = np.where(~hole & np.isfinite(depth), depth, 0).astype(np.float32)
    sides, around = same_for_1_and_2_threads(lambda: _core.hole_sides(hole, ~hole & np.isposinf(depth), known, 1.5))
    assert (sides[~hole] == 0).all()
    # An occluder is a surface side nearer than another: never every side found.
    occluders = sum(((sides >> (2 * k)) & 3) == _core.SIDE_OCCLUDER for k in range(4))
    found = sum(((sides >> (2 * k)) & 3) != _core.SIDE_NONE for k in range(4))
    assert (occluders < np.maximum(found, 1)).all()
    assert np.all(np.isfinite(around)) and (around >= 0).all() and (around <= known.max(initial=0)).all()


# --- steerable pyramid ---------------------------------------------------------------------------------
@STRESS
@given(size=BIG_SIZES, data=st.data())
def test_steerable_analyse_synthesise(size, data):
    from ibrtools.metamers import steerable

    h, w = size
    img = data.draw(colours(h, w))
    levels = data.draw(st.integers(0, steerable.max_levels(h, w)))
    orient = data.draw(st.sampled_from([2, 4]))
    out = same_for_1_and_2_threads(lambda: steerable.synthesise(steerable.analyse(img, levels, orient)))
    assert out.shape == img.shape and np.all(np.isfinite(out))
    if float(img.max()) == float(img.min()):
        # a constant image stays constant up to the fitted 5x5 filters' DC gain error (1.5 %, the
        # bound tests/metamers/test_steerable.py pins for a constant image)
        np.testing.assert_allclose(out, img, rtol=0.015, atol=1e-30)


# --- metameric inpainting and foveation ---------------------------------------------------------------
@STRESS
@given(size=BIG_SIZES, data=st.data())
def test_metameric(size, data):
    from ibrtools.inpaint.metameric import metameric

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
    from ibrtools.metamers.foveate import foveate

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
    from ibrtools.depthwarp.core import DepthWarpParams, warp_depth

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
    from ibrtools.depthwarp.culling import cull_objects

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
    from ibrtools.raycast.reference import ReferenceRenderer

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
        "inpaint.pushpull": (lambda c, m: __import__("ibrtools.inpaint.pushpull", fromlist=["x"]).pushpull(c, m), [col, hole]),
        "metrics.ssim": (lambda a, b: __import__("ibrtools.metrics", fromlist=["x"]).ssim(a, b), [col, col]),
        "steerable.analyse": (lambda c: __import__("ibrtools.metamers.steerable", fromlist=["x"]).analyse(c, 2), [col]),
        "depthwarp.warp_depth": (lambda d: __import__("ibrtools.depthwarp.core", fromlist=["x"]).warp_depth(
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


# === the newer kernels: Y-map/N-buffer queries, motion buffers, max-flow,
# Poisson, per-pixel ULR, the harmonise kernels, PVM rasterisation and clustered filtering ===========

# --- Y-map / N-buffer max-depth queries (depthwarp.MaxDepthQuery) ------------------------------------
@STRESS
@given(size=SIZES, data=st.data())
def test_ymap_max_depth_is_conservative_and_tight_to_the_image(size, data):
    """true max over the clipped box <= answer <= max of the whole image; empty boxes +inf."""
    from ibrtools.depthwarp.core import MaxDepthQuery

    h, w = size
    depth = data.draw(depth_maps(h, w))
    levels = data.draw(st.sampled_from([0, 1, 2, 5]))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    x = rng.integers(-3, w + 3, (12, 2))
    y = rng.integers(-3, h + 3, (12, 2))
    boxes = np.stack([x.min(1), y.min(1), x.max(1) + rng.integers(0, 2, 12), y.max(1) + rng.integers(0, 2, 12)],
                     1).astype(np.int32)
    boxes[0] = (0, 0, w, h)          # the whole image
    boxes[1] = (-1000, -1000, 10**6, 10**6)  # far past every side: clipped to the image
    boxes[2] = (w, 0, w + 5, h)      # entirely outside: empty
    got = same_for_1_and_2_threads(lambda: MaxDepthQuery(depth, mip_levels=levels).max_depth(boxes))
    assert got.shape == (12,) and not np.any(np.isnan(got))
    for (x0, y0, x1, y1), g in zip(boxes, got):
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
        if x0 >= x1 or y0 >= y1:
            assert g == np.inf
        else:
            assert depth[y0:y1, x0:x1].max() <= g <= depth.max()
    assert got[0] == depth.max() and got[1] == depth.max()


# --- motion buffers (depthwarp.motion_buffer): motion of 0 and of thousands of pixels -----------------
@STRESS
@given(size=SIZES, f=FOCALS, data=st.data())
def test_motion_buffer_matches_projection(size, f, data):
    """Finite motion; zero motion for the same camera; elsewhere the motion equals the float64
    projection of the un-projected point (relative 1e-4 of the motion + 1e-3 px: float32)."""
    from ibrtools.depthwarp.core import motion_buffer

    h, w = size
    depth = data.draw(depth_maps(h, w))
    motion = data.draw(st.sampled_from([0.0, 1e-6, 1.0, 1e3]))
    src = pinhole(h, w, f)
    dst = pinhole(h, w, f, eye=(motion, 0.0, 0.0), target=(motion, 0.0, 1.0))
    mv, dz = same_for_1_and_2_threads(lambda: motion_buffer(depth, src, dst))
    assert mv.shape == (h, w, 2) and np.all(np.isfinite(mv)) and np.all(np.isfinite(dz)) and np.all(dz >= 0)
    assert np.all(mv[depth == 0] == 0) and np.all(dz[depth == 0] == 0)
    assert np.all(mv[dz == 0] == 0)  # invalid pixels: motion 0
    # A subnormal depth may read as 0 (invalid; flush-to-zero / denormals-are-zero, see the
    # forward warp's pinned cases): normal depths must be valid for a camera that did not move.
    normal = depth >= np.finfo(np.float32).tiny
    # ... and whose camera-space point fits float32 (x = (u - cx) / f * z overflows near float max)
    x, y = src.pixel_grid()
    fits = np.maximum(np.abs(x - src.cx), np.abs(y - src.cy)) / f * depth.astype(np.float64) < F32_MAX / 2
    if motion == 0.0:
        np.testing.assert_allclose(mv, 0.0, atol=1e-3)
        good = normal & fits
        np.testing.assert_allclose(dz[good], depth[good], rtol=1e-5)
        return
    ok = dz > 0
    if not ok.any():
        return
    # reference: float64 un-projection and projection (ibrtools.camera)
    uv, zz = dst.project(src.unproject(depth))
    want = uv[ok] - np.stack([x[ok], y[ok]], -1)
    tol = 1e-4 * np.abs(want) + 1e-3  # float32 arithmetic in the kernel
    assert np.all(np.abs(mv[ok] - want) <= tol)
    np.testing.assert_allclose(dz[ok], zz[ok], rtol=1e-4)


# --- max-flow (solvers.grid_maxflow): degenerate grids, zero and huge capacities -----------------------
def _cut_value(labels, src, snk, right, down):
    """Capacity of the cut given by a sink-side labelling (exact in Python ints)."""
    lab = labels.astype(bool)
    v = int(src[lab].sum()) + int(snk[~lab].sum())
    v += int(right[:, :-1][lab[:, :-1] != lab[:, 1:]].sum())
    v += int(down[:-1, :][lab[:-1, :] != lab[1:, :]].sum())
    return v


@STRESS
@given(size=st.sampled_from([(1, 1), (1, 2), (1, 7), (7, 1), (2, 3), (3, 3)]), data=st.data())
def test_grid_maxflow_is_the_minimum_cut(size, data):
    """int64 capacities from 0 to 2^40 (huge but the sums fit int64): the returned flow equals the
    capacity of the returned cut and the brute-force minimum over every labelling (<= 9 pixels)."""
    import itertools

    from ibrtools.solvers import grid_maxflow

    h, w = size
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    scale = data.draw(st.sampled_from([0, 1, 1000, 2**40]))
    kind = data.draw(st.sampled_from(["random", "zero terminals", "zero edges", "equal"]))

    def caps():
        return (rng.integers(0, 4, (h, w)) * scale).astype(np.int64) if kind != "equal" \
            else np.full((h, w), scale, np.int64)

    src, snk, right, down = caps(), caps(), caps(), caps()
    if kind == "zero terminals":
        src[:] = 0
    if kind == "zero edges":
        right[:] = 0
        down[:] = 0
    flow, labels = same_for_1_and_2_threads(lambda: grid_maxflow(src, snk, right, down))
    assert labels.shape == (h, w) and labels.dtype == np.bool_
    assert int(flow) == _cut_value(labels, src, snk, right, down)
    best = min(_cut_value(np.array(bits, bool).reshape(h, w), src, snk, right, down)
               for bits in itertools.product([False, True], repeat=h * w))
    assert int(flow) == best


@pytest.mark.parametrize("dtype", [np.int64, np.float64])
def test_grid_maxflow_capacity_sums_past_the_type_are_refused_or_exact(dtype):
    """Capacities whose sums overflow int64 (or lose every unit in float64) must not give a
    silently wrong cut: either a typed refusal or the exact answer."""
    from ibrtools.solvers import grid_maxflow

    big = np.iinfo(np.int64).max // 2 if dtype == np.int64 else 1e300
    src = np.full((2, 3), big, dtype)
    snk = np.full((2, 3), big, dtype)
    z = np.zeros((2, 3), dtype)
    try:
        flow, labels = grid_maxflow(src, snk, z, z)
    except InputError:
        return
    # every pixel is cut on one side: flow = 6 * big
    assert float(flow) == pytest.approx(6 * float(big), rel=1e-12)


# --- Poisson blending (solvers.poisson_blend): 1x1 / 1xN grids, constant guidance, scales -------------
@STRESS
@given(size=SIZES, data=st.data())
def test_poisson_blend_harmonic_stays_within_the_boundary(size, data):
    """Constant source (zero guidance): the solution is harmonic, so within the range of the
    boundary values (maximum principle; slack = tol relative + float32 rounding); a constant
    boundary is reproduced; outside the mask the boundary is copied; 1 = 2 threads."""
    from ibrtools.solvers import poisson_blend

    h, w = size
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    scale = data.draw(st.sampled_from([DENORMAL, 1e-20, 1.0, 1e20]))
    const = data.draw(st.booleans())
    boundary = (np.full((h, w, 3), 0.5, np.float32) if const else rng.uniform(0, 1, (h, w, 3)).astype(np.float32))
    boundary = (boundary * np.float32(scale)).astype(np.float32)
    source = np.full((h, w, 3), data.draw(st.sampled_from([0.0, 7.0])), np.float32)
    frac = data.draw(st.sampled_from([0.0, 0.3, 0.9, 1.0]))
    mask = rng.uniform(size=(h, w)) < frac
    try:
        out, info = same_for_1_and_2_threads(lambda: poisson_blend(boundary, source, mask))
    except InputError:
        assert mask.all()  # no boundary at all: refused (the solution would be defined up to a constant)
        return
    assert not mask.all()
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[~mask], boundary[~mask])
    if not mask.any():
        return
    lo, hi = float(boundary[~mask].min()), float(boundary[~mask].max())
    slack = 1e-4 * max(abs(lo), abs(hi)) + 1e-6 * scale
    assert out[mask].min() >= lo - slack and out[mask].max() <= hi + slack
    if const:
        np.testing.assert_allclose(out[mask], boundary[0, 0, 0], rtol=1e-4)


# --- per-pixel ULR (_core.ulr_blend) --------------------------------------------------------------------
@STRESS
@given(size=SIZES, f=FOCALS, data=st.data())
def test_ulr_blend_is_a_convex_combination(size, f, data):
    """Colour inside the inputs' range where counted, 0 where no view sees the point, counts <= k,
    no NaN for G-buffer depths from subnormal to float max and views on / behind the point."""
    h, w = size
    gdepth = data.draw(depth_maps(h, w))
    k = data.draw(st.sampled_from([1, 2, 4]))
    novel = pinhole(h, w, f)
    views = []
    for i in range(3):
        off = data.draw(st.sampled_from([0.0, 0.01, 1.0, 1e3]))
        cam = pinhole(h, w, f, eye=(off * (i - 1), 0.0, 0.0), target=(off * (i - 1), 0.0, 1.0))
        # the G-buffer's own depth (consistent where the view sits at the novel camera) or unrelated
        vd = gdepth if data.draw(st.booleans()) else data.draw(depth_maps(h, w, holes=False))
        views.append((cam.to_core(), data.draw(colours(h, w)), vd))
    lo = min(float(v[1].min()) for v in views)
    hi = max(float(v[1].max()) for v in views)
    col, count = same_for_1_and_2_threads(
        lambda: _core.ulr_blend(novel.to_core(), gdepth, views, k=k))
    assert np.all(np.isfinite(col)) and count.max() <= k
    seen = count > 0
    event(f"ULR pixels seen: {'some' if seen.any() else 'none'}")
    assert np.all(col[~seen] == 0)
    if seen.any():
        assert col[seen].min() >= lo - 1e-5 and col[seen].max() <= hi + 1e-5


# --- the harmonise kernels --------------------------------------------------------------------------------
@STRESS
@given(size=SIZES, f=FOCALS, data=st.data())
def test_cross_view_prediction_in_range(size, f, data):
    """The predicted colour is a quantile of the source colours that see the point: inside their
    range where n_seen > 0, 0 elsewhere; extreme depths give no NaN; 1 = 2 threads."""
    h, w = size
    depth = data.draw(depth_maps(h, w))
    tol = data.draw(st.sampled_from([1e-6, 0.01, 10.0]))
    q = data.draw(st.sampled_from([0.0, 0.5, 1.0]))
    cam = pinhole(h, w, f)
    cams, depths, imgs = [], [], []
    for i in range(2):
        off = data.draw(st.sampled_from([0.0, 0.01, 1e3]))
        cams.append(pinhole(h, w, f, eye=(off, 0.0, 0.0), target=(off, 0.0, 1.0)).to_core())
        depths.append(data.draw(depth_maps(h, w)))
        imgs.append(data.draw(colours(h, w)))
    pred, n = same_for_1_and_2_threads(
        lambda: _core.cross_view_prediction(cam.to_core(), depth, cams, depths, imgs, tol, q))
    assert np.all(np.isfinite(pred)) and n.min() >= 0 and n.max() <= 2
    seen = n > 0
    event(f"predicted pixels: {'some' if seen.any() else 'none'}")
    assert np.all(pred[~seen] == 0)
    if seen.any():
        lo, hi = min(float(i.min()) for i in imgs), max(float(i.max()) for i in imgs)
        # a subnormal colour may read as 0 (flush-to-zero set by another library in the process)
        floor = 0.0 if lo < np.finfo(np.float32).tiny else lo
        assert pred[seen].min() >= floor and pred[seen].max() <= hi


@STRESS
@given(size=SIZES, data=st.data())
def test_interpolate_vertex_attribute_convex(size, data):
    """Barycentric interpolation with weights in [0, 1] summing to <= 1 (Embree's u, v): inside the
    range of the triangle's vertex values (float32 slack), 0 where no triangle; values up to 1e30."""
    h, w = size
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    scale = data.draw(st.sampled_from([DENORMAL, 1.0, 1e30]))
    values = (rng.uniform(-1, 1, (5, 2)) * scale).astype(np.float32)
    faces = rng.integers(0, 5, (4, 3)).astype(np.int32)
    prim = rng.integers(-1, 4, (h, w)).astype(np.int32)
    u = rng.uniform(0, 1, (h, w)).astype(np.float32)
    v = (rng.uniform(0, 1, (h, w)) * (1 - u)).astype(np.float32)
    bary = np.stack([u, v], -1)
    out = same_for_1_and_2_threads(lambda: _core.interpolate_vertex_attribute(prim, bary, faces, values))
    assert out.shape == (h, w, 2) and np.all(np.isfinite(out))
    assert np.all(out[prim < 0] == 0)
    hit = prim >= 0
    fv = values[faces[prim[hit]]]  # (n, 3, 2)
    slack = 1e-5 * scale + 1e-30
    assert np.all(out[hit] >= fv.min(1) - slack) and np.all(out[hit] <= fv.max(1) + slack)


# --- PVM: per-view meshes, tiles, rasterisation and the clustered filter (hybrid.pvm_render) -------------
PVM_SIZES = st.sampled_from([(2, 2), (2, 9), (9, 2), (5, 7), (17, 16), (24, 40)])


@STRESS
@given(size=PVM_SIZES, f=st.sampled_from([1.0, 30.0, 1e4]), data=st.data())
def test_pvm_render_edges(size, f, data):
    """Views whose depths are constant, two-level or log-uniform over 1e-3 .. 1e6 (with holes), the
    novel camera at an input view, moved, or inside the scene: colour inside the inputs' range where
    valid, finite depth > 0 where valid, no NaN anywhere; 1 = 2 threads, filtered and unfiltered."""
    from ibrtools.hybrid.pvm import build_tiles
    from ibrtools.hybrid.pvm_render import PvmRenderer
    from ibrtools.scene import Scene, View

    h, w = size
    views = []
    for i in range(2):
        cam = pinhole(h, w, f, eye=(0.1 * i, 0.0, 0.0), target=(0.1 * i, 0.0, 1.0))
        d = data.draw(depth_maps(h, w))
        d = np.where(d > 0, np.clip(d, 1e-3, 1e6), 0).astype(np.float32)
        if not d.any():
            d[0, 0] = 1.0  # a view needs one known depth (View.create refuses an all-unknown map, typed)
        views.append(View.create(f"v{i}", cam, color=data.draw(colours(h, w)), depth=d))
    scene = Scene(views=views)
    try:
        tiles = build_tiles({v.name: v.camera for v in views}, {v.name: v.depth for v in views})
    except InputError:
        return  # e.g. no triangle in any view: typed
    r = PvmRenderer(scene, None, tiles=tiles, images={v.name: v.color for v in views})
    z = data.draw(st.sampled_from([0.0, -1.0, 0.5]))
    novel = pinhole(h + 1, w, f, eye=(0.05, 0.0, z), target=(0.05, 0.0, z + 1.0))
    filtered = data.draw(st.booleans())
    res = same_for_1_and_2_threads(lambda: (lambda o: (o.color, o.depth, o.valid))(r.render(novel, filtered=filtered)))
    col, depth, valid = res
    assert np.all(np.isfinite(col)) and not np.any(np.isnan(depth))
    lo = min(float(v.color.min()) for v in views)
    hi = max(float(v.color.max()) for v in views)
    event(f"PVM valid pixels: {'some' if valid.any() else 'none'}")
    if valid.any():
        assert col[valid].min() >= lo - 1e-5 and col[valid].max() <= hi + 1e-5
        assert np.all(np.isfinite(depth[valid])) and np.all(depth[valid] > 0)
