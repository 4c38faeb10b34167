"""Visibility across views in the streaming blend (cpp/kernels/blend.h): stretched fragments
and the depth tolerance. Exact answers: constant colours, so any mixing shows."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import BadValueError, Camera, _core

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
    from ibrtools.render.dibr import check_params
    with pytest.raises(BadValueError, match=msg):
        check_params(params)
    assert check_params({"stretched_holes": "false"})["stretched_holes"] is False
