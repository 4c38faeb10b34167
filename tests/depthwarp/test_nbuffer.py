"""Conservative max-depth queries (ibrtools.depthwarp.core.MaxDepthQuery: Y-map = max-mipmap levels
then N-buffers; cpp/kernels/depthwarp/nbuffer.h) against a brute-force numpy max over random boxes."""
from __future__ import annotations

import numpy as np
import pytest

from ibrtools import _core
from ibrtools.depthwarp.core import MaxDepthQuery
from ibrtools.errors import BadValueError, DtypeError, ShapeError

pytestmark = [pytest.mark.asan, pytest.mark.kernel, pytest.mark.tsan]


def random_boxes(rng, k, h, w, outside=True):
    pad = 8 if outside else 0
    x0 = rng.integers(-pad, w + pad, k)
    y0 = rng.integers(-pad, h + pad, k)
    x1 = x0 + rng.integers(0, w // 2 + 2, k)
    y1 = y0 + rng.integers(0, h // 2 + 2, k)
    return np.stack([x0, y0, x1, y1], 1).astype(np.int32)


def brute(depth, boxes):
    h, w = depth.shape
    out = []
    for x0, y0, x1, y1 in boxes:
        x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
        out.append(np.inf if x0 >= x1 or y0 >= y1 else depth[y0:y1, x0:x1].max())
    return np.array(out, np.float32)


@pytest.mark.parametrize("shape", [(61, 97), (64, 64), (1, 1), (5, 130), (33, 17)])
@pytest.mark.parametrize("mip_levels", [0, 1, 2])
def test_conservative_and_exact_when_aligned(shape, mip_levels):
    rng = np.random.default_rng(shape[0] * 7 + mip_levels)
    h, w = shape
    depth = rng.random(shape).astype(np.float32) * 10
    depth[rng.random(shape) < 0.05] = np.inf  # holes set to far by the caller
    q = MaxDepthQuery(depth, mip_levels=mip_levels)
    boxes = random_boxes(rng, 400, h, w)
    got = q.max_depth(boxes)
    want = brute(depth, boxes)
    assert got.dtype == np.float32 and got.shape == (400,)
    assert (got >= want).all()  # conservative (both are float32 maxima of stored values: exact compare)
    # Boxes aligned to the 2^mip_levels grid and inside the image: the Y-map is exact.
    f = 1 << mip_levels
    g = random_boxes(rng, 400, max(1, h // f), max(1, w // f), outside=False) * f
    g[:, 2] = np.minimum(g[:, 2], (w // f) * f)
    g[:, 3] = np.minimum(g[:, 3], (h // f) * f)
    np.testing.assert_array_equal(q.max_depth(g), brute(depth, g))
    if mip_levels == 0:  # pure N-buffers are exact for every box
        np.testing.assert_array_equal(got, want)


def test_empty_boxes_give_inf_and_threads_agree():
    rng = np.random.default_rng(1)
    depth = rng.random((50, 70)).astype(np.float32)
    q = MaxDepthQuery(depth)
    assert q.num_nbuffer_levels >= 1
    empty = np.array([[5, 5, 5, 9], [10, 10, 3, 20], [-10, 0, 0, 5], [70, 0, 90, 10], [0, 50, 10, 60]], np.int32)
    assert np.isinf(q.max_depth(empty)).all()
    assert q.max_depth(np.zeros((0, 4), np.int32)).shape == (0,)
    boxes = random_boxes(rng, 20000, 50, 70)
    try:
        _core.set_num_threads(1)
        a = MaxDepthQuery(depth).max_depth(boxes)
        _core.set_num_threads(2)
        b = MaxDepthQuery(depth).max_depth(boxes)
    finally:
        _core.set_num_threads(0)
    np.testing.assert_array_equal(a, b)


def test_bad_inputs():
    d = np.ones((8, 8), np.float32)
    with pytest.raises(DtypeError, match="depth"):
        MaxDepthQuery(d.astype(np.float64))
    with pytest.raises(DtypeError, match="depth"):
        MaxDepthQuery([[1.0]])
    with pytest.raises(ShapeError, match="depth"):
        MaxDepthQuery(np.ones((8, 8, 1), np.float32))
    with pytest.raises(ShapeError, match="depth"):
        MaxDepthQuery(np.ones((0, 8), np.float32))
    bad = d.copy()
    bad[1, 1] = np.nan
    with pytest.raises(BadValueError, match="NaN"):
        MaxDepthQuery(bad)
    with pytest.raises(BadValueError, match="mip_levels"):
        MaxDepthQuery(d, mip_levels=-1)
    with pytest.raises(BadValueError, match="mip_levels"):
        MaxDepthQuery(d, mip_levels=9)
    q = MaxDepthQuery(d)
    with pytest.raises(DtypeError, match="boxes"):
        q.max_depth(np.zeros((3, 4), np.int64))
    with pytest.raises(ShapeError, match="boxes"):
        q.max_depth(np.zeros((3, 5), np.int32))
