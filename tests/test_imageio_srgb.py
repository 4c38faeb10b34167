"""ibrtools.imageio.linear_to_srgb and srgb_to_linear: the C++ encoding and decoding
(_core.linear_to_srgb, _core.srgb_to_linear) against an independent float64 evaluation of the
IEC 61966-2-1 curve, their edges (NaN, infinities, out of range, the linear toe's end, exact 0 and
1), shapes and dtypes, the round trip, and thread-independence."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import _core
from ibrtools.errors import DtypeError, ShapeError
from ibrtools.imageio import linear_to_srgb, quantize, srgb8, srgb_to_linear

pytestmark = [pytest.mark.asan, pytest.mark.tsan]


def srgb64(v) -> np.ndarray:
    """The curve in float64 (numpy), clipped to [0, 1], NaN -> 0."""
    v = np.clip(np.nan_to_num(np.asarray(v, np.float64), nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def linear64(e) -> np.ndarray:
    """The decoding in float64 (numpy), the toe continued below 0 and the power above 1."""
    e = np.asarray(e, np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(e <= 0.04045, e / 12.92, ((e + 0.055) / 1.055) ** 2.4)


def test_matches_the_float64_curve_over_the_unit_interval():
    rng = np.random.default_rng(3)
    x = np.concatenate([np.linspace(0.0, 1.0, 1_000_001, dtype=np.float32),
                        rng.random(500_000, dtype=np.float32),
                        np.geomspace(1e-12, 1.0, 100_000).astype(np.float32)])
    got = linear_to_srgb(x).astype(np.float64)
    want = srgb64(x)
    assert np.abs(got - want).max() <= 2.5e-7  # about 2 float32 ulps near 1
    above = want > 1e-3
    assert (np.abs(got - want)[above] / want[above]).max() <= 1e-6
    # 8-bit codes as the image writers make them: at most a rare tie flips by one code
    codes, codes64 = np.round(got * 255.0), np.round(want * 255.0)
    assert np.abs(codes - codes64).max() <= 1 and (codes != codes64).mean() < 1e-5


def test_monotonic_on_a_dense_sorted_grid():
    x = np.linspace(0.0, 1.0, 2_000_001, dtype=np.float32)
    assert np.all(np.diff(linear_to_srgb(x)) >= 0.0)


def test_edges():
    x = np.array([np.nan, -np.nan, np.inf, -np.inf, -1.0, -0.0, 0.0, 1e-30, 0.0031308, 0.0031309, 0.5,
                  np.nextafter(np.float32(1.0), np.float32(0.0)), 1.0, 1.5, 3e38], np.float32)
    got = linear_to_srgb(x)
    assert got.dtype == np.float32 and np.all(np.isfinite(got))
    np.testing.assert_array_equal(got[:7], [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(got[12:], [1.0, 1.0, 1.0])  # exactly 1 at and above 1
    np.testing.assert_allclose(got[7:12], srgb64(x[7:12]), rtol=1e-6, atol=1e-12)
    # the toe's end: the step from the linear to the power branch as the float64 curve makes it
    step64 = float(np.diff(srgb64(x[8:10]))[0])
    assert abs(float(got[9]) - float(got[8]) - step64) < 3e-7


@pytest.mark.parametrize("shape", [(), (0,), (7,), (5, 3), (0, 3), (4, 6, 3), (3, 4, 5, 2)])
def test_shapes_and_dtypes(shape):
    rng = np.random.default_rng(len(shape))
    x64 = rng.uniform(-0.5, 1.5, shape)
    got = linear_to_srgb(x64)
    assert got.shape == np.shape(x64) and got.dtype == np.float32
    np.testing.assert_allclose(got, srgb64(x64.astype(np.float32)), rtol=1e-6, atol=2.5e-7)


def test_non_contiguous_input_and_lists():
    x = np.random.default_rng(9).random((20, 30, 3), dtype=np.float32)
    view = x[::2, ::3, 1:]
    np.testing.assert_array_equal(linear_to_srgb(view), linear_to_srgb(np.ascontiguousarray(view)))
    np.testing.assert_array_equal(linear_to_srgb([0.25, 0.75]), linear_to_srgb(np.array([0.25, 0.75], np.float32)))


def test_srgb8_is_the_quantised_encoding_bit_for_bit():
    # _core.linear_to_srgb8 (one pass) against numpy's round of linear_to_srgb * 255, on random
    # values in and out of [0, 1], the edges, and a dense band of every 7th float in [2^-11, 1]
    # (every float in [0, 1], 1.07e9 values, was checked once the same way: no difference).
    rng = np.random.default_rng(8)
    x = np.concatenate([rng.random(300_000, dtype=np.float32), rng.normal(0.5, 1, 100_000).astype(np.float32),
                        np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 1.0, 1e-40, 2.0, 0.5 / 255], np.float32),
                        np.arange(0x3A000000, 0x3F800001, 7, dtype=np.uint32).view(np.float32)])
    got = _core.linear_to_srgb8(x)
    assert got.dtype == np.uint8 and got.shape == x.shape
    np.testing.assert_array_equal(got, quantize(linear_to_srgb(x)))
    np.testing.assert_array_equal(srgb8(x[:3000].reshape(-1, 1, 3)), quantize(linear_to_srgb(x[:3000])).reshape(-1, 1, 3))
    assert srgb8(np.float32(0.5)).shape == ()
    with pytest.raises(ShapeError, match="C-contiguous"):
        _core.linear_to_srgb8(np.zeros((4, 6), np.float32)[:, ::2])
    with pytest.raises(DtypeError, match="values: expected a float32 array, got float64"):
        _core.linear_to_srgb8(np.zeros(3))


@pytest.mark.parametrize("fn", [linear_to_srgb, srgb_to_linear, srgb8])
def test_same_bits_on_one_and_two_threads(fn):
    x = np.random.default_rng(4).uniform(-0.1, 1.1, (301, 257, 3)).astype(np.float32)
    try:
        _core.set_num_threads(1)
        one = fn(x)
        _core.set_num_threads(2)
        two = fn(x)
    finally:
        _core.set_num_threads(0)
    np.testing.assert_array_equal(one, two)


def test_core_function_rejects_other_arrays_with_one_line():
    from ibrtools.errors import DtypeError, ShapeError

    with pytest.raises(DtypeError, match="values: expected a float32 array, got float64"):
        _core.linear_to_srgb(np.zeros((2, 3)))
    with pytest.raises(DtypeError, match="values: expected a numpy float32 array, got list"):
        _core.linear_to_srgb([0.5])
    with pytest.raises(ShapeError, match="C-contiguous"):
        _core.linear_to_srgb(np.zeros((4, 6), np.float32)[:, ::2])


def test_decoding_matches_the_float64_curve():
    rng = np.random.default_rng(5)
    e = np.concatenate([np.linspace(0.0, 1.0, 1_000_001, dtype=np.float32), rng.random(500_000, dtype=np.float32),
                        rng.uniform(-2.0, 3.0, 100_000).astype(np.float32)])
    got, want = srgb_to_linear(e).astype(np.float64), linear64(e)
    assert (np.abs(got - want) / np.maximum(np.abs(want), 1e-30)).max() <= 1e-6
    codes = np.arange(256, dtype=np.float32) / 255.0  # what the importers decode
    np.testing.assert_allclose(srgb_to_linear(codes), linear64(codes), rtol=1e-6, atol=0)
    assert srgb_to_linear(np.float32(1.0)) == 1.0 and srgb_to_linear(np.float32(0.0)) == 0.0


def test_decoding_edges_and_round_trip():
    e = np.array([np.nan, np.inf, -np.inf, -1.0, -0.05, 0.04045, 0.0405, 2.0], np.float32)
    got = srgb_to_linear(e)
    assert np.isnan(got[0]) and got[1] == np.inf and got[2] == -np.inf
    np.testing.assert_allclose(got[3:], linear64(e[3:]), rtol=1e-6)
    assert np.all(np.diff(srgb_to_linear(np.linspace(-1.0, 2.0, 1_000_001, dtype=np.float32))) >= 0.0)
    v = np.linspace(0.0, 1.0, 200_001, dtype=np.float32)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(v)), v, rtol=2e-6, atol=1e-9)


@pytest.mark.parametrize("fn", [linear_to_srgb, srgb_to_linear])
@pytest.mark.parametrize("shape", [(), (0,), (4, 6, 3), (3, 4, 5, 2)])
def test_shape_is_kept(fn, shape):
    got = fn(np.full(shape, 0.5))
    assert got.shape == shape and got.dtype == np.float32


def test_core_decoding_rejects_other_arrays_with_one_line():
    from ibrtools.errors import DtypeError

    with pytest.raises(DtypeError, match="values: expected a float32 array, got int64"):
        _core.srgb_to_linear(np.zeros(3, np.int64))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_read_image_decodes_every_code_as_the_curve_does(tmp_path, dtype):
    # read_image looks 8- and 16-bit codes up in a table: the same float32 as srgb_to_linear of
    # code / (2^bits - 1), for every code, and alpha stays linear.
    from ibrtools.imageio import _oiio, read_image

    n = np.iinfo(dtype).max + 1
    side = int(np.sqrt(n))
    codes = np.arange(n, dtype=dtype).reshape(side, side)
    rgba = np.stack([codes, codes[::-1], codes[:, ::-1], codes], -1)
    oiio = _oiio()
    path = str(tmp_path / "codes.png")
    out = oiio.ImageOutput.create(path)
    spec = oiio.ImageSpec(side, side, 4, "uint8" if dtype == np.uint8 else "uint16")
    spec.attribute("oiio:UnassociatedAlpha", 1)
    out.open(path, spec)
    out.write_image(rgba)
    out.close()
    got = read_image(path, alpha=True)
    scaled = rgba.astype(np.float32) / np.float32(n - 1)
    np.testing.assert_array_equal(got[..., :3], srgb_to_linear(scaled[..., :3]))
    np.testing.assert_array_equal(got[..., 3], scaled[..., 3])


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_lookup_codes_is_the_table_gather(dtype):
    # _core.lookup_codes (cpp/ibr/colour.h LookupCodes) against numpy's take, on 1 and 2 threads.
    from ibrtools.errors import DtypeError, ShapeError

    rng = np.random.default_rng(3)
    n = np.iinfo(dtype).max + 1
    table = rng.normal(size=n).astype(np.float32)
    codes = rng.integers(0, n, (301, 257, 3)).astype(dtype)
    codes.flat[:2] = (0, n - 1)
    for threads in (1, 2):
        _core.set_num_threads(threads)
        try:
            got = _core.lookup_codes(codes, table)
        finally:
            _core.set_num_threads(0)
        assert got.dtype == np.float32 and got.shape == codes.shape
        np.testing.assert_array_equal(got, np.take(table, codes))
    assert _core.lookup_codes(codes[:0], table).shape == (0, 257, 3)
    with pytest.raises(DtypeError, match="codes: expected a uint8 or uint16 array, got int32"):
        _core.lookup_codes(codes.astype(np.int32), table)
    with pytest.raises(ShapeError, match="codes: expected a C-contiguous array"):
        _core.lookup_codes(codes[..., :2], table)
    with pytest.raises(ShapeError, match="table"):
        _core.lookup_codes(codes, table[:-1])  # one entry per code
    with pytest.raises(DtypeError, match="table"):
        _core.lookup_codes(codes, table.astype(np.float64))
