"""Visibility across views in the streaming blend (cpp/kernels/dibr/blend.h): stretched fragments
and the depth tolerance. Exact answers: constant colours, so any mixing shows."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import BadValueError, Camera, _core

pytestmark = [pytest.mark.asan, pytest.mark.kernel, pytest.mark.tsan]

H, W = 32, 48


def flat(depth: float, rgb) -> tuple[np.ndarray, np.ndarray]:
    return (np.ascontiguousarray(np.broadcast_to(np.float32(rgb), (H, W, 3))),
            np.full((H, W), depth, np.float32))


def cam(tx: float = 0.0) -> Camera:
    pose = np.eye(4)
    pose[0, 3] = -tx  # camera centre at x = tx
    return Camera.pinhole(W, H, 40.0, 40.0, W / 2, H / 2, pose)


@pytest.mark.parametrize("order", [0, 1])
def test_depth_tolerance_keeps_the_nearest_surface_in_any_order(order):
    near, far = flat(2.0, (1, 0, 0)), flat(4.0, (0, 0, 1))
    views = [near, far] if order == 0 else [far, near]
    plain = _core.DibrAccumulator(cam().to_core())
    tol = _core.DibrAccumulator(cam().to_core(), depth_tolerance=0.05)
    for c, d in views:
        plain.add_view(c, d, cam().to_core())
        tol.add_view(c, d, cam().to_core())
    mixed, _, _, hole = plain.result()
    kept, depth, _, hole_t = tol.result()
    inner = (slice(1, -1), slice(1, -1))  # the border half-pixel ring is not covered by the mesh
    # RVS blending mixes the views: weight ratio (4 / 2)^5 = 32 for the near one.
    assert np.allclose(mixed[inner], [32 / 33, 0, 1 / 33], atol=1e-5)
    assert np.array_equal(kept[inner], np.broadcast_to(np.float32([1, 0, 0]), kept[inner].shape))
    assert np.allclose(depth[inner], 2.0, rtol=1e-5) and not hole_t[inner].any()


def test_depth_tolerance_blends_within_the_tolerance():
    a, b = flat(2.0, (1, 0, 0)), flat(2.02, (0, 1, 0))  # 1 % apart: the same surface
    acc = _core.DibrAccumulator(cam().to_core(), depth_tolerance=0.05)
    for c, d in (a, b):
        acc.add_view(c, d, cam().to_core())
    col = acc.result()[0][5, 5]
    assert col[0] > 0.4 and col[1] > 0.4


def step_view():
    """Left half at depth 1, right half at depth 4: a discontinuity that a sideways move opens."""
    c = np.zeros((H, W, 3), np.float32)
    c[:, : W // 2] = (1, 0, 0)
    c[:, W // 2:] = (0, 0, 1)
    d = np.full((H, W), 4.0, np.float32)
    d[:, : W // 2] = 1.0
    return c, d


def test_stretched_only_pixels_become_holes():
    c, d = step_view()
    src, dst = cam(0.0), cam(0.15)  # moving right uncovers background to the right of the step
    plain = _core.DibrAccumulator(dst.to_core())
    holes = _core.DibrAccumulator(dst.to_core(), stretched_quality=0.1, stretched_holes=True)
    for acc in (plain, holes):
        acc.add_view(c, d, src.to_core())
    _, _, conf_p, hole_p = plain.result()
    col_h, _, conf_h, hole_h = holes.result()
    # Without the rule the bridge across the step is drawn (confidence = its q < 0.1) ...
    bridge = ~hole_p & (conf_p < 0.1)
    assert bridge.sum() >= H
    # ... with it, exactly those pixels are holes, black, and everything else is unchanged.
    assert np.array_equal(hole_h, hole_p | bridge)
    assert np.all(col_h[hole_h] == 0) and np.all(conf_h[~hole_h] >= 0.1)


def test_real_surface_replaces_a_stretched_fragment():
    c, d = step_view()
    # View 1 bridges the gap; view 2 (the target camera itself) sees the real background there.
    dst = cam(0.15)
    acc = _core.DibrAccumulator(dst.to_core(), stretched_quality=0.1)
    acc.add_view(c, d, cam(0.0).to_core())
    truth_c, truth_d = flat(4.0, (0, 1, 0))
    acc.add_view(truth_c, truth_d, dst.to_core())
    col, _, conf, hole = acc.result()
    alone = _core.DibrAccumulator(dst.to_core())
    alone.add_view(c, d, cam(0.0).to_core())
    bridge = (~alone.result()[3]) & (alone.result()[2] < 0.1)
    assert bridge.any()
    assert np.array_equal(col[bridge], np.broadcast_to(np.float32([0, 1, 0]), col[bridge].shape))


@pytest.mark.parametrize("kwargs, msg", [
    (dict(stretched_quality=1.5), "stretched_quality"), (dict(stretched_quality=-0.1), "stretched_quality"),
    (dict(depth_tolerance=1.0), "depth_tolerance"), (dict(depth_tolerance=float("nan")), "depth_tolerance"),
    (dict(stretched_holes=True), "stretched_holes")])
def test_bad_visibility_options(kwargs, msg):
    with pytest.raises(BadValueError, match=msg):
        _core.DibrAccumulator(cam().to_core(), **kwargs)


@pytest.mark.parametrize("params, msg", [
    ({"stretched_holes": "maybe"}, "stretched_holes"), ({"depth_tolerance": 1.0}, "depth_tolerance"),
    ({"stretched_quality": -1}, "stretched_quality")])
def test_dibr_method_checks_visibility_params(params, msg):
    from ibrtools.dibr.method import DibrParams
    with pytest.raises(BadValueError, match=msg):
        DibrParams.from_dict(params)
    assert DibrParams.from_dict({"stretched_holes": "false"}).stretched_holes is False


# ---- Fresh sums (BlendBuffers::fresh): no clearing pass; the first view after construction or
# reset() writes every pixel's sums. Tolerances: none (the same bits as adding to cleared sums).

ACC_OPTIONS = [dict(), dict(stretched_quality=0.1, stretched_holes=True), dict(depth_tolerance=0.05)]


def noisy_view(seed: int, depth: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    d = (depth + rng.random((H, W)) * np.where(rng.random((H, W)) < 0.2, 3.0, 0.05)).astype(np.float32)
    d[rng.random((H, W)) < 0.05] = 0.0  # unknown: pixels no triangle covers
    return rng.random((H, W, 3), dtype=np.float32), d


@pytest.mark.parametrize("kwargs", ACC_OPTIONS)
def test_reset_forgets_every_view_bit_for_bit(kwargs, isa):
    """A reused accumulator (reset, then views) equals a new one with the same views, and the
    sums of the views before reset() leave no trace (the fresh view writes every pixel)."""
    views = [noisy_view(s) for s in range(3)]
    used = _core.DibrAccumulator(cam(0.05).to_core(), **kwargs)
    for c, d in views:
        used.add_view(c, d, cam().to_core())
    assert used.num_views == 3
    used.reset()
    assert used.num_views == 0
    for c, d in views[1:]:
        used.add_view(c, d, cam(0.1).to_core())
    new = _core.DibrAccumulator(cam(0.05).to_core(), **kwargs)
    for c, d in views[1:]:
        new.add_view(c, d, cam(0.1).to_core())
    for a, b in zip(used.result(), new.result()):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("kwargs", ACC_OPTIONS)
def test_result_without_views_is_all_holes(kwargs, isa):
    acc = _core.DibrAccumulator(cam().to_core(), **kwargs)
    for _ in range(2):
        col, depth, conf, hole = acc.result()
        assert hole.all() and not col.any() and not depth.any() and not conf.any()
        c, d = noisy_view(1)
        acc.add_view(c, d, cam().to_core())
        assert not acc.result()[3].all()
        acc.reset()


def test_rejected_first_view_keeps_the_sums_fresh(isa):
    """A view rejected after the kernel ran (bad depth, non-finite colour) writes nothing: the
    next good view is still the first one."""
    c, d = noisy_view(2)
    bad_d = d.copy()
    bad_d[4, 5] = -1.0
    bad_c = c.copy()
    bad_c[1, 2, 0] = np.nan
    bad_c[7, 8, 2] = np.inf
    bad_c[9, 9, 1] = -np.inf
    acc = _core.DibrAccumulator(cam().to_core())
    with pytest.raises(BadValueError, match="depth: 1 values are NaN or negative"):
        acc.add_view(c, bad_d, cam().to_core())
    with pytest.raises(BadValueError, match="color: 3 values are NaN or infinite"):
        acc.add_view(bad_c, d, cam().to_core())
    assert acc.num_views == 0 and acc.result()[3].all()
    acc.add_view(c, d, cam().to_core())
    ref = _core.DibrAccumulator(cam().to_core())
    ref.add_view(c, d, cam().to_core())
    for a, b in zip(acc.result(), ref.result()):
        np.testing.assert_array_equal(a, b)
    # ... and a rejected later view leaves the sums of the good ones unchanged
    with pytest.raises(BadValueError, match="color: 3 values"):
        acc.add_view(bad_c, d, cam().to_core())
    assert acc.num_views == 1
    for a, b in zip(acc.result(), ref.result()):
        np.testing.assert_array_equal(a, b)


def test_add_view_colour_check_counts_every_row(isa):
    """The colour check runs in the kernel's row tasks (all rows, any width, the last values of
    a row past the eight-wide steps); the count is exact. forward_warp checks before the kernel."""
    c, d = noisy_view(3)
    acc = _core.DibrAccumulator(cam().to_core())
    for y, x, ch in [(0, 0, 0), (H - 1, W - 1, 2), (H // 2, W - 1, 1), (5, 0, 0), (6, 7, 1)]:
        bad = c.copy()
        bad[y, x, ch] = np.nan
        with pytest.raises(BadValueError, match="color: 1 values are NaN or infinite"):
            acc.add_view(bad, d, cam().to_core())
        with pytest.raises(BadValueError, match="color: 1 values are NaN or infinite"):
            _core.forward_warp(bad, d, cam().to_core(), cam().to_core())
    odd = np.full((7, 5, 3), np.inf, np.float32)  # 105 values: 13 steps of 8 and one left over
    small = Camera.pinhole(5, 7, 10.0, 10.0, 2.5, 3.5, np.eye(4))
    with pytest.raises(BadValueError, match="color: 105 values are NaN or infinite"):
        _core.DibrAccumulator(small.to_core()).add_view(odd, np.ones((7, 5), np.float32), small.to_core())
    # colour errors come before depth errors, as in forward_warp
    with pytest.raises(BadValueError, match="color: 105 values"):
        _core.DibrAccumulator(small.to_core()).add_view(odd, np.full((7, 5), np.nan, np.float32), small.to_core())


# ---- Reused memory (cpp/bindings/dibr.cpp, AccumulatorStorage): a destroyed accumulator leaves
# its sums and scratch as the one spare; a new accumulator of the same target size takes them
# (any bits: the sums start fresh). Tolerances: none (bit for bit).

@pytest.mark.parametrize("kwargs", ACC_OPTIONS)
def test_new_accumulator_on_a_freed_ones_memory_is_bit_identical(kwargs, isa):
    import gc
    views = [noisy_view(s) for s in range(4, 7)]
    ref = _core.DibrAccumulator(cam(0.05).to_core(), **kwargs)
    for c, d in views:
        ref.add_view(c, d, cam().to_core())
    expected = ref.result()
    for dirty_kwargs in ACC_OPTIONS:
        # A freed accumulator with other views and options (its sums and max_q hold their values)
        dirty = _core.DibrAccumulator(cam(-0.1).to_core(), **dirty_kwargs)
        for c, d in (noisy_view(9, 1.0), noisy_view(10, 5.0)):
            dirty.add_view(c, d, cam(0.2).to_core())
        dirty.result()
        del dirty
        gc.collect()
        new = _core.DibrAccumulator(cam(0.05).to_core(), **kwargs)  # takes the spare
        for c, d in views:
            new.add_view(c, d, cam().to_core())
        for a, b in zip(new.result(), expected):
            np.testing.assert_array_equal(a, b)
        del new
    # A live accumulator's memory is its own: another one's views do not reach it.
    other = _core.DibrAccumulator(cam(0.05).to_core(), **kwargs)
    other.add_view(*noisy_view(11, 3.0), cam().to_core())
    for a, b in zip(ref.result(), expected):
        np.testing.assert_array_equal(a, b)
    # Another target size: the spare is not taken (freed); results as a new accumulator's.
    del other
    small = Camera.pinhole(W // 2, H // 2, 20.0, 20.0, W / 4, H / 4, np.eye(4))
    s1 = _core.DibrAccumulator(small.to_core(), **kwargs)
    s1.add_view(*views[0], cam().to_core())
    r1 = s1.result()
    del s1
    s2 = _core.DibrAccumulator(small.to_core(), **kwargs)
    s2.add_view(*views[0], cam().to_core())
    for a, b in zip(s2.result(), r1):
        np.testing.assert_array_equal(a, b)
    assert not r1[3].all()
