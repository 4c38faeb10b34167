"""The per-sample C++ passes of metameric inpainting (cpp/kernels/inpaint/metameric.h): the stacked
[X, X^2] push-pull input, the push-pull of the moments computed on the fly
(cpp/kernels/inpaint/pushpull.h PushPullMomentsKernel) and the mean + sigma * noise composite, against the numpy expressions
python/ibrtools/metameric.py used before them (exact: same float32 operations, same order)."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import _core
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.inpaint.metameric import _sample_positions

pytestmark = [pytest.mark.asan, pytest.mark.kernel]


def _bands(k=3, h=13, w=11, c=3, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.standard_normal((h, w, c)).astype(np.float32) for _ in range(k)]


def test_stack_moments_matches_numpy():
    bands = _bands()
    out = np.full((13, 11, 18), np.nan, np.float32)
    _core.metameric_stack_moments(bands, out)
    ref = np.concatenate(bands + [b * b for b in bands], axis=2)
    np.testing.assert_array_equal(out, ref)


@pytest.mark.parametrize("k,depth_aware", [(2, False), (3, True), (5, True), (1, False)])
def test_pushpull_moments_matches_pushpull_of_the_stack(k, depth_aware):
    # The fused kernel computes level 0's rows of [X, X^2] on the fly; in the mask it must equal
    # push-pull of the stored stack bit for bit (same operations, same order; k = 1 runs the
    # generic channel count, 2, 3 and 5 the compiled-in ones), and never write outside it.
    rng = np.random.default_rng(k)
    h, w = 37, 29
    bands = _bands(k, h, w, seed=k)
    mask = np.zeros((h, w), bool)
    mask[5:20, 3:12] = True
    mask[30:, 20:] = True
    depth = (5 + rng.random((h, w))).astype(np.float32) if depth_aware else None
    if depth_aware:
        depth[10:14, :] = 1.0  # a foreground strip the depth test rejects next to the mask
    stack = np.empty((h, w, 2 * k * 3), np.float32)
    _core.metameric_stack_moments(bands, stack)
    args = (0.04, 0.5) if depth_aware else (0.0, 0.0)
    ref, _ = _core.pushpull(stack, mask, depth, *args)
    out = np.full((h, w, 2 * k * 3), -3.0, np.float32)
    _core.metameric_pushpull_moments(bands, mask.view(np.uint8), depth, *args, out)
    np.testing.assert_array_equal(out[mask], ref[mask])
    assert np.all(out[~mask] == -3.0)


def test_pushpull_moments_bad_input():
    bands = _bands(2)
    out = np.zeros((13, 11, 12), np.float32)
    mask = np.zeros((13, 11), np.uint8)
    mask[2:5, 2:5] = 1
    with pytest.raises(ShapeError, match="out: expected float32 array of shape"):
        _core.metameric_pushpull_moments(bands, mask, None, 0.0, 0.0, np.zeros((13, 11, 6), np.float32))
    with pytest.raises(ShapeError, match="mask"):
        _core.metameric_pushpull_moments(bands, mask[:5].copy(), None, 0.0, 0.0, out)
    with pytest.raises(ShapeError, match="depth"):
        _core.metameric_pushpull_moments(bands, mask, np.ones((13, 10), np.float32), 0.04, 0.5, out)
    with pytest.raises(BadValueError, match="gamma"):
        _core.metameric_pushpull_moments(bands, mask, None, 0.0, -1.0, out)
    with pytest.raises(BadValueError, match="every sample is masked"):
        _core.metameric_pushpull_moments(bands, np.ones_like(mask), None, 0.0, 0.0, out)
    nan = [b.copy() for b in bands]
    nan[1][0, 0, 0] = np.nan
    with pytest.raises(BadValueError, match=r"bands\[1\]: contains 1 NaN"):
        _core.metameric_pushpull_moments(nan, mask, None, 0.0, 0.0, out)
    nan[1][3, 3, 0] = np.nan  # inside the mask: never read, no error for it
    nan[1][0, 0, 0] = 0.0
    _core.metameric_pushpull_moments(nan, mask, None, 0.0, 0.0, out)
    with pytest.raises(BadValueError, match="out: .*shares memory"):
        buf = np.zeros(13 * 11 * 12, np.float32)
        _core.metameric_pushpull_moments([buf[:13 * 11 * 3].reshape(13, 11, 3)] * 2, mask, None, 0.0, 0.0,
                                         buf.reshape(13, 11, 12))


def _reference(moments, mask, noise, bands, flow, scale):
    k, c = len(bands), bands[0].shape[2]
    idx = np.flatnonzero(mask)
    m = moments.reshape(-1, 2 * k * c)[idx]
    mean, sq = m[:, :k * c], m[:, k * c:]
    sigma = np.sqrt(np.maximum(sq - mean * mean, np.float32(0)))
    ys, xs = np.divmod(idx, mask.shape[1])
    yy, xx = _sample_positions(ys, xs, scale, mask.shape, flow)
    synth = mean + sigma * np.concatenate([n[yy, xx] for n in noise], axis=1)
    out = [b.copy() for b in bands]
    for i, b in enumerate(out):
        b.reshape(-1, c)[idx] = synth[:, i * c:(i + 1) * c]
    return out


@pytest.mark.parametrize("flow_dtype,scale", [(None, 1), (np.float32, 1), (np.float32, 4), (np.float64, 2)])
def test_composite_matches_numpy(flow_dtype, scale):
    rng = np.random.default_rng(3)
    h, w, c, k = 13, 11, 3, 3
    bands, noise = _bands(k, h, w, c, 1), _bands(k, h, w, c, 2)
    mean = rng.standard_normal((h, w, k * c)).astype(np.float32)
    # E[X^2] around mean^2, below it for some samples (sigma clamps to 0 there, never NaN).
    sq = (mean * mean + rng.uniform(-0.1, 1.0, mean.shape)).astype(np.float32)
    moments = np.ascontiguousarray(np.concatenate([mean, sq], axis=2))
    mask = rng.random((h, w)) < 0.4
    flow = None
    if flow_dtype is not None:
        # Half-integer offsets included: rint rounds half to even in both.
        flow = (rng.integers(-60, 60, ((h - 1) * scale + 3, (w - 1) * scale + 2, 2)) * 0.5).astype(flow_dtype)
    ref = _reference(moments, mask, noise, bands, flow, scale)
    _core.metameric_composite(moments, mask.astype(np.uint8), noise, bands, flow, scale)
    for b, r in zip(bands, ref):
        np.testing.assert_array_equal(b, r)
        assert np.isfinite(b).all()


def test_bad_input():
    bands, noise = _bands(2), _bands(2, seed=5)
    mom = np.zeros((13, 11, 12), np.float32)
    mask = np.ones((13, 11), bool)
    with pytest.raises(ShapeError, match="bands: expected at least one array"):
        _core.metameric_stack_moments([], mom)
    with pytest.raises(DtypeError, match="bands: expected a list"):
        _core.metameric_stack_moments(bands[0], mom)
    with pytest.raises(ShapeError, match=r"bands\[1\]"):
        _core.metameric_stack_moments([bands[0], bands[1][:, :5].copy()], mom)
    with pytest.raises(DtypeError, match=r"bands\[0\]: expected float32"):
        _core.metameric_stack_moments([bands[0].astype(np.float64)], mom)
    with pytest.raises(ShapeError, match="out: expected float32 array of shape"):
        _core.metameric_stack_moments(bands, np.zeros((13, 11, 6), np.float32))
    buf = np.zeros(13 * 11 * 6, np.float32)
    with pytest.raises(BadValueError, match="out: .*shares memory"):
        _core.metameric_stack_moments([buf[:13 * 11 * 3].reshape(13, 11, 3)], buf.reshape(13, 11, 6))
    ro = bands[0].copy()
    ro.setflags(write=False)
    with pytest.raises(BadValueError, match="writeable"):
        _core.metameric_composite(mom, mask, noise, [ro, bands[1]])
    with pytest.raises(ShapeError, match="noise: expected one array per band"):
        _core.metameric_composite(mom, mask, noise[:1], bands)
    with pytest.raises(ShapeError, match="moments"):
        _core.metameric_composite(mom[:, :, :6].copy(), mask, noise, bands)
    with pytest.raises(ShapeError, match="mask"):
        _core.metameric_composite(mom, mask[:5], noise, bands)
    with pytest.raises(BadValueError, match="scale"):
        _core.metameric_composite(mom, mask, noise, bands, None, 0)
    with pytest.raises(ShapeError, match="flow: expected the full-resolution flow"):
        _core.metameric_composite(mom, mask, noise, bands, np.zeros((13, 11, 2), np.float32), 2)
    with pytest.raises(BadValueError, match="flow: contains 1 NaN"):
        f = np.zeros((13, 11, 2), np.float32)
        f[3, 4, 1] = np.nan
        _core.metameric_composite(mom, mask, noise, bands, f, 1)
    with pytest.raises(DtypeError, match="flow"):
        _core.metameric_composite(mom, mask, noise, bands, np.zeros((13, 11, 2), np.int32), 1)
    with pytest.raises(BadValueError, match=r"bands\[0\]: shares memory"):
        _core.metameric_composite(mom, mask, [bands[0], noise[1]], bands)
    with pytest.raises(BadValueError, match=r"shares memory with bands"):
        _core.metameric_composite(mom, mask, noise, [bands[0], bands[0]])


@pytest.mark.parametrize("flow_dtype,scale", [(None, 1), (np.float32, 2)])
def test_composite_delta_is_sigma_noise_in_the_mask_zero_elsewhere(flow_dtype, scale):
    # delta=True writes the band's change sigma * noise (no mean) in the mask and 0 outside:
    # the mean + sigma * noise composite minus the mean, computed the same way (exact).
    rng = np.random.default_rng(4)
    h, w, c, k = 13, 11, 3, 2
    bands, noise = _bands(k, h, w, c, 6), _bands(k, h, w, c, 7)
    mean = rng.standard_normal((h, w, k * c)).astype(np.float32)
    sq = (mean * mean + rng.uniform(-0.1, 1.0, mean.shape)).astype(np.float32)
    moments = np.ascontiguousarray(np.concatenate([mean, sq], axis=2))
    zero_mean = np.ascontiguousarray(np.concatenate([np.zeros_like(mean), sq - mean * mean], axis=2))
    mask = rng.random((h, w)) < 0.4
    flow = None
    if flow_dtype is not None:
        flow = (rng.integers(-60, 60, ((h - 1) * scale + 1, (w - 1) * scale + 1, 2)) * 0.5).astype(flow_dtype)
    ref = _reference(zero_mean, mask, noise, [np.zeros_like(b) for b in bands], flow, scale)
    _core.metameric_composite(moments, mask, noise, bands, flow, scale, delta=True)
    for b, r in zip(bands, ref):
        # sigma from E[X^2] - mean^2 in float32 (kernel) vs the pre-subtracted value (here): the
        # same float32 subtraction, so equal; outside the mask exactly 0.
        np.testing.assert_array_equal(b, r)
        assert np.all(b[~mask] == 0)


def _srgb_encode_f64(v):
    v = v.astype(np.float64)
    a = np.abs(v)
    return np.sign(v) * np.where(a <= 0.0031308, 12.92 * a, 1.055 * a ** (1 / 2.4) - 0.055)


def test_display_encoding_accuracy():
    # The polynomial log2/exp2 sRGB curve (cpp/kernels/inpaint/metameric.h SrgbEncode / SrgbDecode)
    # against float64 numpy: the whole [0, 1] range on a fine grid, negatives (odd extension) and
    # HDR values up to 1e6. Tolerance 1e-5 relative (measured 3e-6 for the encoding, 8e-6 for the
    # round trip: float32 has 6e-8; the polynomial's own error is ~1e-7, the rest is the float32
    # log2 / exp2 argument rounding, amplified by the exponent 2.4).
    v = np.concatenate([np.linspace(0, 1, 200001), np.geomspace(1e-6, 1e6, 20001),
                        -np.linspace(0, 2, 2001)]).astype(np.float32)
    x = np.ascontiguousarray(v.reshape(1, -1, 1))
    e = _core.metameric_encode(x)
    ref = _srgb_encode_f64(v)
    assert e.shape == x.shape and e.dtype == np.float32
    assert np.max(np.abs(e[0, :, 0] - ref) / np.maximum(np.abs(ref), 1e-12)) < 1e-5
    hole = np.ones(x.shape[:2], bool)
    back = _core.metameric_fill_holes(x, hole, e, np.zeros_like(e), True)[0, :, 0]
    pos = v >= 0
    assert np.max(np.abs(back[pos] - v[pos]) / np.maximum(v[pos], 1e-12)) < 1e-5
    assert np.all(back[~pos] == 0)  # negative light clamped
    special = _core.metameric_encode(np.array([[[np.nan, np.inf, -np.inf]]], np.float32))[0, 0]
    assert np.isnan(special[0]) and special[1] == np.inf and special[2] == -np.inf


def test_fill_holes():
    rng = np.random.default_rng(5)
    img, base, change = (rng.random((9, 7, 3)).astype(np.float32) for _ in range(3))
    hole = rng.random((9, 7)) < 0.3
    out = _core.metameric_fill_holes(img, hole, base, change, False)
    np.testing.assert_array_equal(out[~hole], img[~hole])
    np.testing.assert_array_equal(out[hole], (base + change)[hole])
    out2 = _core.metameric_fill_holes(img, hole.view(np.uint8), base, change, True)
    np.testing.assert_array_equal(out2[~hole], img[~hole])
    # out= the change's or the image's own memory: the same values as a new array.
    for decode in (False, True):
        fresh = _core.metameric_fill_holes(img, hole, base, change, decode)
        ch2, im2 = change.copy(), img.copy()
        assert _core.metameric_fill_holes(img, hole, base, ch2, decode, ch2) is ch2
        assert _core.metameric_fill_holes(im2, hole, base, change, decode, im2) is im2
        np.testing.assert_array_equal(ch2, fresh)
        np.testing.assert_array_equal(im2, fresh)
    with pytest.raises(BadValueError, match="out: shares memory"):
        _core.metameric_fill_holes(img, hole, base, change, True, base)
    buf = np.zeros(2 * change.size, np.float32)
    shifted_change = buf[:change.size].reshape(change.shape)
    shifted_change[...] = change
    with pytest.raises(BadValueError, match="out: shares memory"):  # overlaps change, not the same array
        _core.metameric_fill_holes(img, hole, base, shifted_change, True, buf[3:3 + change.size].reshape(change.shape))
    ref = _srgb_encode_f64(img)  # decode(encode(v)) = v: check the decode through a known pair
    dec = _core.metameric_fill_holes(img, hole, ref.astype(np.float32), np.zeros_like(img), True)
    np.testing.assert_allclose(dec[hole], img[hole], rtol=1e-5, atol=1e-7)


def test_display_kernels_bad_input():
    img = np.zeros((5, 4, 3), np.float32)
    hole = np.zeros((5, 4), bool)
    with pytest.raises(DtypeError, match="image"):
        _core.metameric_encode(img.astype(np.float64))
    with pytest.raises(ShapeError, match="image"):
        _core.metameric_encode(img[..., 0])
    with pytest.raises(ShapeError, match="hole"):
        _core.metameric_fill_holes(img, hole[:3], img, img, True)
    with pytest.raises(ShapeError, match="base"):
        _core.metameric_fill_holes(img, hole, img[:, :, :1].copy(), img, True)
    with pytest.raises(ShapeError, match="change"):
        _core.metameric_fill_holes(img, hole, img, img[:4].copy(), True)
    with pytest.raises(DtypeError, match="hole"):
        _core.metameric_fill_holes(img, hole.astype(np.float32), img, img, True)


@pytest.mark.parametrize("depth_aware,flow_dtype,scale", [(True, None, 1), (False, np.float32, 2), (True, np.float64, 1)])
def test_pushpull_change_equals_moments_then_delta_composite(depth_aware, flow_dtype, scale):
    # The fused kernel (PushPullMomentsChangeKernel) must give the bands the same values, bit for
    # bit, as metameric_pushpull_moments followed by metameric_composite(delta=True): 3 bands of
    # 3 channels (the unrolled 18-channel path) and 2 bands of 2 channels (the generic one).
    rng = np.random.default_rng(8)
    h, w = 41, 37
    for k, c in ((3, 3), (2, 2)):
        bands = [rng.standard_normal((h, w, c)).astype(np.float32) for _ in range(k)]
        noise = [rng.standard_normal((h, w, c)).astype(np.float32) for _ in range(k)]
        mask = np.zeros((h, w), np.uint8)
        mask[5:20, 3:12] = 1
        mask[30:, 20:] = 1
        depth = (5 + rng.random((h, w))).astype(np.float32) if depth_aware else None
        if depth_aware:
            depth[10:14, :] = 1.0
        flow = None
        if flow_dtype is not None:
            flow = (rng.integers(-40, 40, ((h - 1) * scale + 1, (w - 1) * scale + 1, 2)) * 0.5).astype(flow_dtype)
        args = (0.04, 0.5) if depth_aware else (0.0, 0.0)
        ref = [b.copy() for b in bands]
        mom = np.empty((h, w, 2 * k * c), np.float32)
        _core.metameric_pushpull_moments(ref, mask, depth, *args, mom)
        _core.metameric_composite(mom, mask, noise, ref, flow, scale, delta=True)
        out = [b.copy() for b in bands]
        _core.metameric_pushpull_change(out, mask, depth, *args, noise, flow, scale)
        for a, b in zip(out, ref):
            np.testing.assert_array_equal(a, b)
            assert np.all(a[mask == 0] == 0)


def test_pushpull_change_classic_fallback():
    # The depth-aware moments with the farthest depth in the holes only: push-pull's classic
    # fallback (its own buffer on this path), still equal to the two-step result.
    rng = np.random.default_rng(9)
    hole = np.zeros((48, 48), np.uint8)
    hole[15:30, 15:30] = 1
    depth = np.full((48, 48), 2.0, np.float32)
    depth[hole != 0] = 9.0
    img = rng.random((48, 48, 3)).astype(np.float32)
    # The path under test: the farthest depth (9) is hole only, so every block that holds it drops
    # its valid samples (depth 2) and the 1x1 top has no data (cpp/kernels/inpaint/pushpull.h, "Classic
    # fallback"); the depth-aware fill then differs from the classic one only where depth-aware
    # data reaches through the bilinear push.
    aware, _ = _core.pushpull(img, hole, depth, 0.04, 0.5)
    classic, _ = _core.pushpull(img, hole, None, 0.0, 0.0)
    assert not np.array_equal(aware[hole != 0], classic[hole != 0])
    bands = [rng.standard_normal((48, 48, 3)).astype(np.float32) for _ in range(3)]
    noise = [rng.standard_normal((48, 48, 3)).astype(np.float32) for _ in range(3)]
    ref = [b.copy() for b in bands]
    mom = np.empty((48, 48, 18), np.float32)
    _core.metameric_pushpull_moments(ref, hole, depth, 0.04, 0.5, mom)
    _core.metameric_composite(mom, hole, noise, ref, None, 1, delta=True)
    out = [b.copy() for b in bands]
    _core.metameric_pushpull_change(out, hole, depth, 0.04, 0.5, noise)
    for a, b in zip(out, ref):
        np.testing.assert_array_equal(a, b)


def test_pushpull_change_bad_input():
    bands, noise = _bands(2), _bands(2, seed=5)
    mask = np.zeros((13, 11), np.uint8)
    mask[2:5, 2:5] = 1
    with pytest.raises(ShapeError, match="noise: expected one array per band"):
        _core.metameric_pushpull_change(bands, mask, None, 0.0, 0.0, noise[:1])
    with pytest.raises(ShapeError, match="mask"):
        _core.metameric_pushpull_change(bands, mask[:5].copy(), None, 0.0, 0.0, noise)
    with pytest.raises(ShapeError, match="depth"):
        _core.metameric_pushpull_change(bands, mask, np.ones((3, 3), np.float32), 0.04, 0.5, noise)
    with pytest.raises(BadValueError, match="gamma"):
        _core.metameric_pushpull_change(bands, mask, None, 0.0, -1.0, noise)
    with pytest.raises(BadValueError, match="depth_threshold"):
        _core.metameric_pushpull_change(bands, mask, None, float("nan"), 0.0, noise)
    with pytest.raises(BadValueError, match="scale"):
        _core.metameric_pushpull_change(bands, mask, None, 0.0, 0.0, noise, None, 0)
    with pytest.raises(ShapeError, match="flow"):
        _core.metameric_pushpull_change(bands, mask, None, 0.0, 0.0, noise, np.zeros((13, 11, 2), np.float32), 2)
    with pytest.raises(BadValueError, match=r"bands\[0\]: shares memory"):
        _core.metameric_pushpull_change(bands, mask, None, 0.0, 0.0, [bands[0], noise[1]])
    with pytest.raises(BadValueError, match="every sample is masked"):
        _core.metameric_pushpull_change(bands, np.ones((13, 11), np.uint8), None, 0.0, 0.0, noise)
    bad = [b.copy() for b in bands]
    bad[1][0, 0, 0] = np.nan
    with pytest.raises(BadValueError, match=r"bands\[1\]: contains 1 NaN"):
        _core.metameric_pushpull_change(bad, mask, None, 0.0, 0.0, noise)
    _core.metameric_pushpull_change(bad, mask, None, 0.0, 0.0, noise, None, 1, False)  # check_finite off
    ro = bands[0].copy()
    ro.setflags(write=False)
    with pytest.raises(BadValueError, match="writeable"):
        _core.metameric_pushpull_change([ro, bands[1]], mask, None, 0.0, 0.0, noise)
