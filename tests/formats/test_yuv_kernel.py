"""The Y'CbCr <-> linear RGB kernels (_core.yuv_to_linear_rgb and _core.linear_rgb_to_yuv,
cpp/ibr/colour.h) against the numpy definitions below (the MPEG importer's and the YUV writer's
conversions as first written): the same float32 values and the same codes, bit for bit, for 8 to
16-bit samples (5 for reading), odd and one-pixel sizes, limited and full range, both matrices,
4:2:0 and 4:0:0 (reading), NaN and out-of-range colour (writing); and their fronts."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import _core
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.formats import yuv
from ibrtools.imageio import linear_to_srgb, srgb_to_linear

pytestmark = [pytest.mark.asan, pytest.mark.kernel]


def upsample2(c: np.ndarray, h: int, w: int) -> np.ndarray:
    """2x upsampling of a chroma plane with the centred linear filter (3/4, 1/4), rows then columns."""
    def axis(a: np.ndarray, ax: int, n: int) -> np.ndarray:
        prev = np.concatenate([np.take(a, [0], axis=ax), np.take(a, np.arange(a.shape[ax] - 1), axis=ax)], ax)
        nxt = np.concatenate([np.take(a, np.arange(1, a.shape[ax]), axis=ax), np.take(a, [-1], axis=ax)], ax)
        even, odd = 0.75 * a + 0.25 * prev, 0.75 * a + 0.25 * nxt
        out = np.stack([even, odd], axis=ax + 1)
        shape = list(a.shape)
        shape[ax] *= 2
        return np.take(out.reshape(shape), np.arange(n), axis=ax)

    return axis(axis(c.astype(np.float32), 0, h), 1, w)


def reference(planes, bits, matrix="bt709", full_range=False):
    y = planes[0].astype(np.float32)
    h, w = y.shape
    scale = float(1 << (bits - 8)) if bits >= 8 else 1.0 / (1 << (8 - bits))
    vmax = float((1 << bits) - 1)
    cb = cr = np.zeros_like(y) if len(planes) == 1 else None
    if len(planes) > 1:
        cb, cr = (upsample2(p, h, w) for p in planes[1:3])
    if full_range:
        yn = y / vmax
        mid = float(1 << (bits - 1))
        cbn, crn = (cb - mid) / vmax, (cr - mid) / vmax
    else:
        yn = (y - 16 * scale) / (219 * scale)
        cbn, crn = (cb - 128 * scale) / (224 * scale), (cr - 128 * scale) / (224 * scale)
    if len(planes) == 1:
        cbn = crn = np.zeros_like(y)
    kr, kb = yuv.MATRICES[matrix]
    kg = 1 - kr - kb
    r = yn + 2 * (1 - kr) * crn
    b = yn + 2 * (1 - kb) * cbn
    g = (yn - kr * r - kb * b) / kg
    return np.ascontiguousarray(srgb_to_linear(np.clip(np.stack([r, g, b], -1), 0, 1)))


def reference_to_yuv(rgb, bits, matrix="bt709", full_range=False):
    e = linear_to_srgb(rgb).astype(np.float64)  # clipped to [0, 1], NaN -> 0
    kr, kb = yuv.MATRICES[matrix]
    y = kr * e[..., 0] + (1 - kr - kb) * e[..., 1] + kb * e[..., 2]
    cb, cr = (e[..., 2] - y) / (2 * (1 - kb)), (e[..., 0] - y) / (2 * (1 - kr))
    h, w = y.shape

    def half(c):
        c = np.pad(c, ((0, h % 2), (0, w % 2)), mode="edge")
        return 0.25 * (c[0::2, 0::2] + c[1::2, 0::2] + c[0::2, 1::2] + c[1::2, 1::2])

    cb, cr = half(cb), half(cr)
    vmax = float((1 << bits) - 1)
    scale = float(1 << (bits - 8))
    if full_range:
        mid = float(1 << (bits - 1))
        planes = [y * vmax, mid + cb * vmax, mid + cr * vmax]
    else:
        planes = [16 * scale + 219 * scale * y, 128 * scale + 224 * scale * cb, 128 * scale + 224 * scale * cr]
    dtype = np.uint8 if bits <= 8 else np.dtype("<u2")
    return [np.clip(np.rint(p), 0, vmax).astype(dtype) for p in planes]


@pytest.mark.parametrize("bits", [8, 10, 12, 16])
@pytest.mark.parametrize("size", [(37, 54), (7, 9), (1, 1), (2, 3), (5, 1)])
def test_writer_kernel_is_the_reference_bit_for_bit(bits, size):
    rng = np.random.default_rng(bits * 7 + size[1])
    rgb = rng.random(size + (3,), dtype=np.float32) * 1.2 - 0.1  # below 0 and above 1 too
    rgb[0, 0, 0] = np.nan
    for full in (False, True):
        for matrix in yuv.MATRICES:
            got, want = yuv.rgb_to_yuv(rgb, bits, matrix, full), reference_to_yuv(rgb, bits, matrix, full)
            for g, w in zip(got, want):
                assert g.dtype == w.dtype
                np.testing.assert_array_equal(g, w)


def test_reference_upsampling_is_centred():
    np.testing.assert_allclose(upsample2(np.array([[0.0, 4.0]]), 2, 4)[0], [0.0, 1.0, 3.0, 4.0])


@pytest.mark.parametrize("bits", [8, 10, 16, 5])
@pytest.mark.parametrize("size", [(37, 54), (7, 9), (1, 1), (2, 3)])
def test_kernel_is_the_reference_bit_for_bit(bits, size):
    rng = np.random.default_rng(bits * 100 + size[0])
    h, w = size
    dtype = np.uint8 if bits <= 8 else np.uint16
    hi = 1 << bits
    planes = [rng.integers(0, hi, (h, w)).astype(dtype)] + [
        rng.integers(0, hi, ((h + 1) // 2, (w + 1) // 2)).astype(dtype) for _ in range(2)]
    for full in (False, True):
        for matrix in yuv.MATRICES:
            np.testing.assert_array_equal(yuv.yuv_to_rgb(planes, bits, matrix, full), reference(planes, bits, matrix, full))
            np.testing.assert_array_equal(yuv.yuv_to_rgb(planes[:1], bits, matrix, full),
                                          reference(planes[:1], bits, matrix, full))


def test_kernel_front_names_bad_arguments():
    y = np.zeros((4, 6), np.uint16)
    c = np.zeros((2, 3), np.uint16)
    kr, kb = yuv.MATRICES["bt709"]
    with pytest.raises(BadValueError, match="bits: expected 1..16, got 17"):
        _core.yuv_to_linear_rgb(y, c, c, 17, kr, kb)
    with pytest.raises(BadValueError, match="kr, kb"):
        _core.yuv_to_linear_rgb(y, c, c, 10, 0.6, 0.5)
    with pytest.raises(ShapeError, match=r"cb: expected uint16 array of shape"):
        _core.yuv_to_linear_rgb(y, np.zeros((3, 3), np.uint16), c, 10, kr, kb)
    with pytest.raises(DtypeError, match=r"y: expected uint8"):
        _core.yuv_to_linear_rgb(y.astype(np.float32), None, None, 8, kr, kb)
    with pytest.raises(DtypeError, match=r"cb: expected uint16"):
        _core.yuv_to_linear_rgb(y, c.astype(np.uint8), c, 10, kr, kb)
    with pytest.raises(BadValueError, match=r"yuv planes: expected samples in 0..65535, got -1..-1"):
        yuv.yuv_to_rgb([np.full((2, 2), -1, np.int32)], 8)
    rgb = np.zeros((4, 6, 3), np.float32)
    with pytest.raises(BadValueError, match="bits: expected 8..16, got 7"):
        _core.linear_rgb_to_yuv(rgb, 7, kr, kb)
    with pytest.raises(ShapeError, match=r"rgb: expected float32 array of shape \(H, W, 3\)"):
        _core.linear_rgb_to_yuv(rgb[..., :2].copy(), 10, kr, kb)
    with pytest.raises(ShapeError, match="rgb: expected at least 1 x 1 pixels"):
        _core.linear_rgb_to_yuv(np.zeros((0, 6, 3), np.float32), 10, kr, kb)
