"""Bad input of the fused foveation kernel binding _core.mip_foveate_level (cpp/bindings/mip.cpp).
Its results are pinned by tests/test_foveate.py (bit-identical to the unfused path)."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import BadValueError, DtypeError, ShapeError, _core


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
