"""Bad input of the fused foveation kernel binding _core.mip_foveate_level (cpp/bindings/metamers.cpp).
Its results are pinned by tests/metamers/test_foveate.py (bit-identical to the unfused path)."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import BadValueError, DtypeError, ShapeError, _core

pytestmark = [pytest.mark.asan, pytest.mark.kernel]


def args(h=16, w=12, c=3, k=2):
    rng = np.random.default_rng(0)
    bands = [rng.random((h, w, c), dtype=np.float32) for _ in range(k)]
    noise = [rng.random((h, w, c), dtype=np.float32) for _ in range(k)]
    level = np.full((h, w), 1.5, np.float32)
    return bands, level, noise


def test_runs_and_writes_in_place():
    bands, level, noise = args()
    before = [b.copy() for b in bands]
    _core.mip_foveate_level(bands, level, noise, 2)
    assert all(np.all(np.isfinite(b)) for b in bands)
    assert any(not np.array_equal(a, b) for a, b in zip(before, bands))


@pytest.mark.parametrize("mutate, err, msg", [
    (lambda b, l, n: ([], l, n, 2), ShapeError, "bands: expected at least one array"),
    (lambda b, l, n: ("x", l, n, 2), DtypeError, "bands: expected a list"),
    (lambda b, l, n: ([b[0].astype(np.float64)], l, n[:1], 2), DtypeError, r"bands\[0\]: expected float32"),
    (lambda b, l, n: (b, l, n[:1], 2), ShapeError, "noise: expected one array per band"),
    (lambda b, l, n: (b, l[:, :5], n, 2), ShapeError, "level: expected float32"),
    (lambda b, l, n: (b, l, n, 99), BadValueError, "levels: expected 0.."),
    (lambda b, l, n: (b, np.where(l > 0, np.nan, l).astype(np.float32), n, 2), BadValueError, "NaN"),
    (lambda b, l, n: ([b[0], b[0]], l, n, 2), BadValueError, "shares memory"),
    (lambda b, l, n: ([b[0]], l, [b[0]], 2), BadValueError, "shares memory with noise"),
])
def test_bad_input(mutate, err, msg):
    bands, level, noise = args()
    with pytest.raises(err, match=msg):
        _core.mip_foveate_level(*mutate(bands, level, noise))


def test_read_only_band_is_refused():
    bands, level, noise = args()
    bands[0].setflags(write=False)
    with pytest.raises(BadValueError, match="writeable"):
        _core.mip_foveate_level(bands, level, noise, 2)


def _reference_change(bands, level, noise, n):
    """mip_foveate_level's equations (cpp/kernels/metamers/mip.h) in float32 numpy, every operation in the
    kernel's order (numpy float32 element ops are IEEE, no contraction on x86-64 without -march):
    the result must match bit for bit."""
    f = np.float32
    h, w, c = bands[0].shape
    k = len(bands)
    kc = k * c
    stack = np.empty((h, w, 2 * kc), np.float32)
    _core.metameric_stack_moments(bands, stack)
    chain = [stack] + list(_core.mip_build(stack, n))
    lam = np.minimum(level, f(n))
    l0 = np.minimum(np.floor(lam).astype(np.int64), n - 1)
    t = (lam - l0.astype(np.float32)).astype(np.float32)
    ys, xs = np.indices((h, w))

    def bilinear(lv, w_):  # weight w_ * bilinear read of chain level lv (>= 1) at every pixel
        def axis(p, size):
            q = 2 * p + 1 - (1 << lv)
            i = q >> (lv + 1)
            fr = (q & ((2 << lv) - 1)).astype(np.float32) * f(1.0 / (2 << lv))
            return np.clip(i, 0, size - 1), np.clip(i + 1, 0, size - 1), fr
        img = chain[lv]
        x0, x1, fx = axis(xs, img.shape[1])
        y0, y1, fy = axis(ys, img.shape[0])
        one = f(1)
        w00, w01 = w_ * (one - fx) * (one - fy), w_ * fx * (one - fy)
        w10, w11 = w_ * (one - fx) * fy, w_ * fx * fy
        return (((w00[..., None] * img[y0, x0] + w01[..., None] * img[y0, x1]) + w10[..., None] * img[y1, x0])
                + w11[..., None] * img[y1, x1])

    m = np.zeros((h, w, 2 * kc), np.float32)
    for l in range(n):
        sel = l0 == l
        wa = np.where(t > 0, f(1) - t, f(1)).astype(np.float32)
        if l == 0:
            a = wa[..., None] * stack
        else:
            a = bilinear(l, wa)
        b = bilinear(l + 1, t)
        a = np.where((t > 0)[..., None], a + b, a)
        m[sel] = a[sel]
    mean, sq = m[..., :kc], m[..., kc:]
    d = sq - mean * mean
    with np.errstate(invalid="ignore"):
        sigma = np.where(d > 0, np.sqrt(d), f(0))
    out = []
    for i in range(k):
        nv = mean[..., i * c:(i + 1) * c] + sigma[..., i * c:(i + 1) * c] * noise[i]
        out.append(np.where((level > 0)[..., None], nv - bands[i], f(0)))
    return out


@pytest.mark.parametrize("h, w, c, k", [(37, 150, 3, 3), (20, 67, 3, 2), (9, 70, 3, 5), (11, 13, 1, 3),
                                        (10, 65, 3, 4)])
def test_matches_reference_bit_for_bit(h, w, c, k):
    # Every branch: level <= 0 (no change), fractional in (0, 1) (the stack's own level 0), integer
    # levels (t == 0), above the chain (clamped); widths past the kernel's 64-sample chunks; RGB with
    # 2-5 bands (the fixed-size paths) and one channel (the generic path).
    rng = np.random.default_rng(h * w + k)
    bands = [(rng.random((h, w, c), dtype=np.float32) - 0.5) for _ in range(k)]
    noise = [rng.standard_normal((h, w, c)).astype(np.float32) for _ in range(k)]
    n = 3
    level = rng.uniform(-1, n + 1.5, (h, w)).astype(np.float32)
    level[::5, ::3] = np.floor(level[::5, ::3])  # exact integers: t == 0
    level[1::7] = 0.0
    ref = _reference_change(bands, level, noise, n)
    _core.mip_foveate_level(bands, level, noise, n)
    for got, want in zip(bands, ref):
        assert np.array_equal(got, want)
