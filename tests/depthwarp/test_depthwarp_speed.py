"""The speed paths of the depth warp (docs/depthwarp.md, "Measured (kernels)"): the motion pass that builds
level 1 of the min-max motion mipmaps while its rows are in cache (``_core.dw_motion_mips``), and the
in-place dilation. Both must give exactly what the separate, plain forms give: every comparison
here is bit for bit (``assert_array_equal``), no tolerance."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import _core
from ibrtools.camera import Camera
from ibrtools.depthwarp.core import DepthWarpParams, warp_depth
from ibrtools.errors import BadValueError, DtypeError, ShapeError

pytestmark = [pytest.mark.asan, pytest.mark.tsan]


@pytest.fixture
def restore_threads():
    yield
    _core.set_num_threads(0)


def _cam(w: int, h: int, centre=(0.0, 0.0, 0.0), yaw: float = 0.0) -> Camera:
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])
    pose = np.eye(4)
    pose[:3, :3] = rot
    pose[:3, 3] = -rot @ np.asarray(centre, np.float64)
    f = 0.9 * max(w, h)
    return Camera.pinhole(w, h, f, f, w / 2, h / 2, pose)


def _layers(rng, n: int, h: int, w: int) -> np.ndarray:
    d = (2 + 8 * rng.random((n, h, w))).astype(np.float32)
    d[rng.random((n, h, w)) < 0.15] = 0  # empty pixels: excluded from the bounds
    return np.sort(d, axis=0)  # deeper layers farther (0 = empty sorts first: fine for these tests)


def _assert_same_mips(a, b) -> None:
    assert a.num_layers == b.num_layers
    assert list(a.axes) == list(b.axes)
    for j in range(a.num_layers):
        np.testing.assert_array_equal(a.rotation(j), b.rotation(j))
        assert a.num_levels(j) == b.num_levels(j)
        for lv in range(1, a.num_levels(j) + 1):
            np.testing.assert_array_equal(a.level(j, lv), b.level(j, lv))


@pytest.mark.parametrize("h, w", [(1, 1), (1, 7), (5, 1), (23, 37), (72, 96)])
@pytest.mark.parametrize("oriented", [False, True])
@pytest.mark.parametrize("objects", [False, True])
def test_fused_motion_mips_equal_the_separate_calls(h, w, oriented, objects):
    rng = np.random.default_rng(h * 1000 + w)
    lay = _layers(rng, 2, h, w)
    src, dst = _cam(w, h), _cam(w, h, centre=(0.3, -0.1, 0.2), yaw=0.05)
    ids = mot = None
    if objects:
        ids = rng.integers(-1, 2, size=lay.shape).astype(np.int32)
        mot = np.stack([np.eye(4), np.eye(4)])
        mot[1, :3, 3] = (0.2, 0.0, -0.1)
    sc, dc = src.to_core(), dst.to_core()
    packed = _core.dw_motion(lay, sc, dc, ids, mot)
    mips = _core.dw_build_mips(packed, oriented, 16)
    fused, fmips, motion_ms, mipmap_ms = _core.dw_motion_mips(lay, sc, dc, ids, mot, oriented, 16)
    np.testing.assert_array_equal(fused, packed)
    _assert_same_mips(fmips, mips)
    assert motion_ms >= 0 and mipmap_ms >= 0


@pytest.mark.parametrize("w", [1, 3, 4, 5, 8, 13, 67])
def test_sse2_motion_rows_equal_the_scalar_loop(w):
    # Static scenes run 4 pixels at a time (SSE2) plus a scalar tail; the scalar loop alone must
    # give the same bits: widths around the 4-pixel groups, empty pixels, points behind the target
    # camera (z_dst <= 0), huge depths (overflowing float32 in the camera) and a motion past the
    # 1e7 px cut-off.
    h = 6
    rng = np.random.default_rng(w)
    d = (0.5 + 20 * rng.random((2, h, w))).astype(np.float32)
    d[rng.random((2, h, w)) < 0.2] = 0
    d[0, 0, :] = 3.0e38
    d[1, 1, :] = 1e-30
    src = _cam(w, h)
    for dst in (_cam(w, h, centre=(0.4, -0.2, 0.3), yaw=0.2), _cam(w, h, centre=(0, 0, 8.0)),
                _cam(w, h, yaw=1.5), src):
        sc, dc = src.to_core(), dst.to_core()
        fast = _core.dw_motion(d, sc, dc)
        scalar = _core.dw_motion(d, sc, dc, simd=False)
        np.testing.assert_array_equal(fast.view(np.uint32), scalar.view(np.uint32))  # bits, incl. signed zeros


def test_fused_motion_mips_refill_the_given_buffers():
    rng = np.random.default_rng(3)
    src, dst = _cam(40, 30), _cam(40, 30, centre=(0.2, 0, 0))
    sc, dc = src.to_core(), dst.to_core()
    a, b = _layers(rng, 3, 30, 40), _layers(rng, 3, 30, 40)
    out, mips, _, _ = _core.dw_motion_mips(a, sc, dc)
    out2, mips2, _, _ = _core.dw_motion_mips(b, sc, dc, out=out, reuse=mips)
    assert out2 is out and mips2 is mips  # filled in place, returned
    fresh, fresh_mips, _, _ = _core.dw_motion_mips(b, sc, dc)
    np.testing.assert_array_equal(out, fresh)
    _assert_same_mips(mips, fresh_mips)


def test_fused_motion_mips_bad_inputs():
    src = _cam(16, 12)
    sc = src.to_core()
    lay = np.ones((1, 12, 16), np.float32)
    with pytest.raises(BadValueError, match="pca_grid"):
        _core.dw_motion_mips(lay, sc, sc, None, None, True, 1)
    with pytest.raises(DtypeError, match="reuse"):
        _core.dw_motion_mips(lay, sc, sc, reuse="mips")
    with pytest.raises(ShapeError, match="out"):
        _core.dw_motion_mips(lay, sc, sc, out=np.zeros((1, 12, 16, 3), np.float32))
    with pytest.raises(BadValueError, match="shares memory"):
        buf = np.zeros((1, 12, 16, 4), np.float32)
        _core.dw_motion_mips(buf.reshape(-1)[:12 * 16].reshape(1, 12, 16), sc, sc, out=buf)
    with pytest.raises(ShapeError, match="layers"):
        _core.dw_motion_mips(np.ones((1, 11, 16), np.float32), sc, sc)
    with pytest.raises(BadValueError, match="finite"):
        _core.dw_motion_mips(np.full((1, 12, 16), np.nan, np.float32), sc, sc)
    with pytest.raises(DtypeError):
        _core.dw_motion_mips(lay.astype(np.float64), sc, sc)


def _reference_dilate(depth: np.ndarray, layer: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """docs/depthwarp.md "dilate", written independently in numpy: a hole with >= k converged
    8-neighbours takes the smallest depth of its converged edge neighbours, else of its diagonal
    ones (ties: the first in the order left, right, up, down / up-left, up-right, down-left,
    down-right - the kernel keeps the first strictly smaller one)."""
    h, w = depth.shape
    offs = [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, -1), (-1, 1), (1, 1)]  # (dx, dy)
    pd = np.pad(depth, 1)
    pl = np.pad(layer, 1, constant_values=-1)
    nd = np.stack([pd[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dx, dy in offs])
    nl = np.stack([pl[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dx, dy in offs])
    ok = nl >= 0
    count = ok.sum(axis=0)
    edge = np.where(ok[:4], nd[:4], np.inf)
    diag = np.where(ok[4:], nd[4:], np.inf)
    ie, idg = edge.argmin(axis=0), diag.argmin(axis=0)
    has_edge = ok[:4].any(axis=0)
    rows, cols = np.indices((h, w))
    pick = np.where(has_edge, ie, 4 + idg)
    fill = (layer < 0) & (count >= k)
    d, lo = depth.copy(), layer.copy()
    d[fill] = nd[pick, rows, cols][fill]
    lo[fill] = nl[pick, rows, cols][fill]
    return d, lo


@pytest.mark.parametrize("k", [1, 3, 5, 8])
def test_in_place_dilation_matches_an_independent_reference(k, restore_threads):
    # Zero motion: the warp returns its input (per layer), so the holes are the pixels empty in
    # every layer: isolated ones, 1-2 px cracks, a wide hole, the image border.
    rng = np.random.default_rng(k)
    h, w = 70, 101  # not a multiple of the 8-pixel hole scan or of the tiles
    lay = _layers(rng, 2, h, w)
    lay[:, rng.random((h, w)) < 0.08] = 0
    lay[:, 20:22, :] = 0
    lay[:, 40:50, 30:45] = 0
    lay[:, :, 0] = 0
    cam = _cam(w, h)
    for threads in (1, 2):
        _core.set_num_threads(threads)
        plain = warp_depth(lay, cam, cam, DepthWarpParams(dilate=False, dilate_min_neighbors=k))
        dil = warp_depth(lay, cam, cam, DepthWarpParams(dilate=True, dilate_min_neighbors=k))
        ref_d, ref_l = _reference_dilate(plain.depth, plain.layer, k)
        np.testing.assert_array_equal(dil.layer, ref_l)
        np.testing.assert_array_equal(dil.depth, np.where(ref_l >= 0, ref_d, 0).astype(np.float32))
        assert dil.stats["dilated_pixels"] == int(((plain.layer < 0) & (ref_l >= 0)).sum())
        assert dil.stats["hole_fraction"] == float((ref_l < 0).mean())


def test_stage_times_are_reported():
    rng = np.random.default_rng(5)
    lay = _layers(rng, 2, 30, 40)
    src, dst = _cam(40, 30), _cam(40, 30, centre=(0.1, 0, 0))
    for oriented in (False, True):
        r = warp_depth(lay, src, dst, DepthWarpParams(oriented=oriented))
        assert set(r.times_ms) == {"motion", "mipmap", "warp", "dilate"}
        assert all(v >= 0 for v in r.times_ms.values())
