"""The background lookup kernel (cpp/kernels/inpaint/background.h) against an independent numpy
implementation of the same rule, on pinhole and equirectangular inputs with sky, surfaces,
unknown depth, pixels too near a surface, directions behind or outside an input; and its front."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import _core
from ibrtools.camera import Camera, look_at
from ibrtools.errors import BadValueError, DtypeError, ShapeError

pytestmark = [pytest.mark.asan, pytest.mark.kernel]


RAY_SAMPLES, RAY_TOLERANCE = 64, 0.01  # BackgroundRay in cpp/kernels/inpaint/background.h


def ray_is_free(target: Camera, inputs, direction: np.ndarray, near: float, far: float) -> bool:
    """The ray test in numpy: every sample of the target's ray that some input sees (inside its
    image, known depth) is seen past by one of them."""
    t = near * np.exp(np.log(far / near) / (RAY_SAMPLES - 1) * np.arange(RAY_SAMPLES))
    points = target.centre + t[:, None] * direction
    seen = np.zeros(RAY_SAMPLES, bool)
    free = np.zeros(RAY_SAMPLES, bool)
    for cam, depth, _, _ in inputs:
        xy, d = cam.project(points)
        w, h = cam.width, cam.height
        with np.errstate(invalid="ignore"):
            inside = np.isfinite(xy).all(-1) & (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
        for k in np.nonzero(inside)[0]:
            at = float(depth[min(int(xy[k, 1]), h - 1), min(int(xy[k, 0]), w - 1)])
            if at > 0:
                seen[k] = True
                free[k] |= at > d[k] * (1.0 + RAY_TOLERANCE)
    return bool(np.all(free | ~seen))


def reference(target: Camera, inputs, hole: np.ndarray, near: float = 0.0, far: float = 0.0):
    """(state, rgb) per hole pixel in np.nonzero order: each input in turn, with numpy, for the
    directions no earlier input decided; a background found then passes the ray test when
    0 < near < far."""
    ys, xs = np.nonzero(hole)
    dirs = target.rays_in_cam(xs + 0.5, ys + 0.5) @ target.cam_from_world[:3, :3]
    state = np.zeros(len(ys), np.uint8)
    rgb = np.zeros((len(ys), 3), np.float32)
    for cam, depth, clear, color in inputs:
        todo = np.nonzero(state == 0)[0]
        rot = np.eye(4)
        rot[:3, :3] = cam.cam_from_world[:3, :3]
        xy, _ = cam.with_pose(rot).project(dirs[todo])
        w, h = cam.width, cam.height
        with np.errstate(invalid="ignore"):
            inside = np.isfinite(xy).all(-1) & (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
        for k in np.nonzero(inside)[0]:
            x, y = xy[k]
            ix, iy = min(int(x), w - 1), min(int(y), h - 1)
            at = depth[iy, ix]
            if not at > 0:
                continue
            j = todo[k]
            if not (np.isposinf(at) and clear[iy, ix]):
                state[j] = 1
                continue
            gx, gy = x - 0.5, y - 0.5
            x0, y0 = int(np.floor(gx)), int(np.floor(gy))
            fx, fy = gx - x0, gy - y0
            acc, wsum = np.zeros(3), 0.0
            for dx, dy, wt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy),
                               (1, 1, fx * fy)):
                cx, cy = np.clip(x0 + dx, 0, w - 1), np.clip(y0 + dy, 0, h - 1)
                if np.isposinf(depth[cy, cx]):
                    acc += wt * color[cy, cx].astype(np.float64)
                    wsum += wt
            state[j] = 2
            rgb[j] = (acc / max(wsum, 1e-12)).astype(np.float32)
    if 0 < near < far:
        for j in np.nonzero(state == 2)[0]:
            if not ray_is_free(target, inputs, dirs[j], near, far):
                state[j], rgb[j] = 0, 0
    return state, rgb


def _input(cam: Camera, rng: np.random.Generator):
    h, w = cam.height, cam.width
    depth = rng.uniform(1, 5, (h, w)).astype(np.float32)
    sky = rng.random((h, w)) < 0.6
    depth[sky] = np.inf
    depth[rng.random((h, w)) < 0.1] = 0  # unknown
    clear = rng.random((h, w)) < 0.8
    color = rng.random((h, w, 3)).astype(np.float32)
    return cam, depth, clear, color


def test_lookup_matches_the_reference():
    rng = np.random.default_rng(7)
    target = Camera.pinhole(41, 29, 30, 31, 20.3, 14.1, look_at((0.2, 0, 0), (0.5, 0.1, 5), up=(0, -1, 0)))
    cams = [Camera.pinhole(23, 17, 14, 15, 11.5, 8.5, look_at((0, 0, 0), (0, 0, 5), up=(0, -1, 0))),
            Camera.pinhole(19, 21, 12, 12, 9.0, 10.0, look_at((1, 0, 0), (2, 0.5, 5), up=(0, -1, 0))),
            Camera.pinhole(15, 15, 10, 10, 7.5, 7.5, look_at((0, 0, 0), (0, 0, -5), up=(0, -1, 0))),  # behind
            Camera.equirect(32, 16, cam_from_world=look_at((0, 0, 0), (0, 0, 5), up=(0, -1, 0)))]
    inputs = [_input(c, rng) for c in cams]
    hole = rng.random((29, 41)) < 0.7
    color = rng.random((29, 41, 3)).astype(np.float32)
    before = color.copy()
    state = _core.background_lookup(target.to_core(), [(c.to_core(), d, m, col) for c, d, m, col in inputs],
                                    hole, color)
    want_state, want_rgb = reference(target, inputs, hole)
    ys, xs = np.nonzero(hole)
    assert {0, 1, 2} <= set(np.unique(want_state))  # every outcome is exercised
    np.testing.assert_array_equal(state[ys, xs], want_state)
    assert (state[~hole] == 0).all()
    bg = want_state == 2
    np.testing.assert_allclose(color[ys[bg], xs[bg]], want_rgb[bg], rtol=0, atol=1e-6)
    # everything else untouched
    untouched = np.ones(hole.shape, bool)
    untouched[ys[bg], xs[bg]] = False
    np.testing.assert_array_equal(color[untouched], before[untouched])
    # no inputs: nothing decided
    assert (_core.background_lookup(target.to_core(), [], hole, color.copy()) == 0).all()
    # The ray test: the same, less the background directions whose ray passes behind a surface.
    ray_color = before.copy()
    ray_state = _core.background_lookup(target.to_core(), [(c.to_core(), d, m, col) for c, d, m, col in inputs],
                                        hole, ray_color, near=0.5, far=20.0)
    want_ray, _ = reference(target, inputs, hole, 0.5, 20.0)
    np.testing.assert_array_equal(ray_state[ys, xs], want_ray)
    assert 0 < np.count_nonzero(want_ray == 2) < np.count_nonzero(want_state == 2)
    np.testing.assert_array_equal(ray_color[ray_state == 2], color[ray_state == 2])  # the same colours
    np.testing.assert_array_equal(ray_color[ray_state != 2], before[ray_state != 2])


def test_a_surface_no_input_sees_is_not_background():
    """Input A at the origin sees a box (depth 2, x/z in [-0.1, 0.1]) against the sky. From a
    target 1 unit to the right, the ray to (0, 0, 4) passes behind the box as A sees it: its
    direction is sky in A, but what the target sees there is unknown (it stays a hole). The ray
    to (0, 0, 1) passes in front of the box: free, the sky."""
    a = Camera.pinhole(64, 9, 16, 16, 32, 4.5, np.eye(4))
    depth = np.full((9, 64), np.inf, np.float32)
    box = np.abs((np.arange(64) + 0.5 - 32) / 16) <= 0.1
    depth[:, box] = 2.0
    clear = ~np.repeat(np.convolve(box, np.ones(3), "same")[None] > 0, 9, 0)
    color = np.ones((9, 64, 3), np.float32)
    pose = np.eye(4)
    pose[0, 3] = -1.0  # centre (1, 0, 0)
    target = Camera.pinhole(64, 9, 16, 16, 32, 4.5, pose)
    hidden, free = (int(32 + 16 * -1 / 4 - 0.5), 4), (int(32 + 16 * -1 / 1 - 0.5), 4)  # (x, y): dirs (-1, 0, 4), (-1, 0, 1)
    hole = np.zeros((9, 64), bool)
    for x, y in (hidden, free):
        hole[y, x] = True
    inputs = [(a.to_core(), depth, clear, color)]
    without = _core.background_lookup(target.to_core(), inputs, hole, np.zeros((9, 64, 3), np.float32))
    assert without[hidden[1], hidden[0]] == 2 and without[free[1], free[0]] == 2  # the direction alone: sky
    out = np.zeros((9, 64, 3), np.float32)
    state = _core.background_lookup(target.to_core(), inputs, hole, out, near=0.5, far=8.0)
    assert state[hidden[1], hidden[0]] == 0 and (out[hidden[1], hidden[0]] == 0).all()
    assert state[free[1], free[0]] == 2 and (out[free[1], free[0]] == 1).all()


def test_lookup_front_names_bad_arguments():
    rng = np.random.default_rng(1)
    target = Camera.pinhole(8, 6, 5, 5, 4, 3, np.eye(4))
    cam, depth, clear, color = _input(Camera.pinhole(7, 5, 5, 5, 3.5, 2.5, np.eye(4)), rng)
    hole = np.ones((6, 8), bool)
    out = np.zeros((6, 8, 3), np.float32)
    with pytest.raises(ShapeError, match=r"inputs\[0\].depth: expected float32 array of shape \(h, w\) = \(5, 7\)"):
        _core.background_lookup(target.to_core(), [(cam.to_core(), depth[:4], clear, color)], hole, out)
    with pytest.raises(DtypeError, match=r"inputs\[0\].clear: expected bool"):
        _core.background_lookup(target.to_core(), [(cam.to_core(), depth, clear.astype(np.float32), color)],
                                hole, out)
    with pytest.raises(DtypeError, match=r"inputs\[0\]: expected a tuple \(camera, depth, clear, color\)"):
        _core.background_lookup(target.to_core(), [(cam.to_core(), depth)], hole, out)
    with pytest.raises(ShapeError, match=r"color: expected float32 array of shape \(H, W, 3\) = \(6, 8, 3\)"):
        _core.background_lookup(target.to_core(), [], hole, out[:, :, :2].copy())
    with pytest.raises(ShapeError, match=r"hole: expected"):
        _core.background_lookup(target.to_core(), [], hole[:5], out)
    for near, far in ((-1.0, 2.0), (1.0, float("inf")), (float("nan"), 1.0)):
        with pytest.raises(BadValueError, match=r"near, far: expected finite depths >= 0"):
            _core.background_lookup(target.to_core(), [], hole, out, near=near, far=far)


def test_hole_sides_match_nearest_covered():
    # The kernel's per-pixel summary against ibrtools.inpaint.pushpull.nearest_covered, the numpy
    # search of the four nearest covered pixels, reduced the same way.
    from ibrtools.inpaint.pushpull import nearest_covered

    rng = np.random.default_rng(5)
    for shape in ((37, 150), (1, 9), (9, 1), (64, 65)):
        hole = rng.random(shape) < 0.6
        hole[:, :1] = True  # runs touching the borders
        bg = ~hole & (rng.random(shape) < 0.4)
        known = np.where(~hole & ~bg, rng.uniform(0.5, 9, shape), 0).astype(np.float32)
        ys, xs = np.nonzero(hole)
        found_sides = list(nearest_covered(hole))  # left, right, up, down
        want = np.zeros(len(ys), np.float32)
        for ny, nx, found in found_sides:
            want = np.maximum(want, np.where(found, known[np.where(found, ny, 0), np.where(found, nx, 0)], 0))
        for ratio in (0.0, 1.5, 4.0):  # 0: no occluders
            sides, around = _core.hole_sides(hole, bg, known, ratio)
            code = np.zeros(len(ys), np.int64)
            for k, (ny, nx, found) in enumerate(found_sides):
                ny, nx = np.where(found, ny, 0), np.where(found, nx, 0)
                d = known[ny, nx].astype(np.float64)
                occluder = (ratio > 0) & found & ~bg[ny, nx] & (d > 0) & (d * ratio < want)
                c = np.select([~found, bg[ny, nx], occluder],
                              [_core.SIDE_NONE, _core.SIDE_BACKGROUND, _core.SIDE_OCCLUDER], _core.SIDE_SURFACE)
                code |= c << (2 * k)
            np.testing.assert_array_equal(sides[ys, xs], code)
            np.testing.assert_array_equal(around[ys, xs], want)
            assert (sides[~hole] == 0).all() and (around[~hole] == 0).all()
    all_hole = np.ones((4, 5), bool)
    sides, around = _core.hole_sides(all_hole, np.zeros((4, 5), bool), np.zeros((4, 5), np.float32), 1.5)
    assert (sides == 0).all() and (around == 0).all()
    with pytest.raises(ShapeError, match=r"background: expected bool array of shape \(H, W\) = \(4, 5\)"):
        _core.hole_sides(all_hole, np.zeros((4, 4), bool), np.zeros((4, 5), np.float32), 0.0)
    with pytest.raises(DtypeError, match=r"known_depth: expected float32"):
        _core.hole_sides(all_hole, all_hole, np.zeros((4, 5)), 0.0)
    for ratio in (0.5, 1.0, -2.0, float("inf"), float("nan")):
        with pytest.raises(BadValueError, match=r"occluder_ratio: expected 0 \(no occluders\) or a finite ratio > 1"):
            _core.hole_sides(all_hole, all_hole, np.zeros((4, 5), np.float32), ratio)


def test_clean_color_matches_numpy():
    # NaN and +-inf -> 0 and hole pixels -> +0, other values (negative, above 1, -0.0) kept: as
    # numpy's nan_to_num then where(hole, 0, colour), bit for bit.
    rng = np.random.default_rng(9)
    col = rng.normal(0, 2, (13, 17, 3)).astype(np.float32)
    col[::3, ::5] = np.nan
    col[1, 2, 0], col[2, 3, 1], col[4, 4, 2] = np.inf, -np.inf, -0.0
    hole = rng.random((13, 17)) < 0.3
    for h in (hole, None):
        want = np.nan_to_num(col, nan=0.0, posinf=0.0, neginf=0.0)
        if h is not None:
            want = np.where(h[..., None], np.float32(0.0), want)
        got = _core.clean_color(col, h)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(np.signbit(got), np.signbit(want))
    with pytest.raises(ShapeError, match=r"hole: expected bool array of shape \(H, W\) = \(13, 17\)"):
        _core.clean_color(col, hole[:5])
