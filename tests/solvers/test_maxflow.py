"""Grid max-flow/min-cut (ibrtools.solvers.grid_maxflow, cpp/kernels/solvers/maxflow.{h,cpp}):
hand-checked graphs, random grids against PyMaxflow (an independent Boykov-Kolmogorov
implementation), the cut's energy recomputed from the labels, bad input, the GIL."""
from __future__ import annotations

import numpy as np
import pytest

from gil import runs_python_during
from ibrtools import _core
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.solvers import grid_maxflow

pytestmark = [pytest.mark.asan, pytest.mark.kernel, pytest.mark.tsan]

maxflow = pytest.importorskip("maxflow", reason="PyMaxflow (test extra) is the reference")

RIGHT = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0]])
DOWN = np.array([[0, 0, 0], [0, 0, 0], [0, 1, 0]])


def energy(s, t, r, d, sink_side):
    """The labelling energy the cut measures, recomputed from the labels alone."""
    L = sink_side
    return ((s * L).sum() + (t * ~L).sum() + (r[:, :-1] * (L[:, :-1] != L[:, 1:])).sum()
            + (d[:-1] * (L[:-1] != L[1:])).sum())


def pymaxflow(s, t, r, d, kind=int):
    g = maxflow.Graph[kind]()
    ids = g.add_grid_nodes(s.shape)
    g.add_grid_edges(ids, weights=r, structure=RIGHT, symmetric=True)
    g.add_grid_edges(ids, weights=d, structure=DOWN, symmetric=True)
    g.add_grid_tedges(ids, s, t)
    return g.maxflow(), g.get_grid_segments(ids)


def i64(a):
    return np.asarray(a, dtype=np.int64)


def test_single_pixel():
    # source 3, sink 5: 3 units flow straight through; the source arc saturates, so the pixel
    # is on the sink side (cutting s->p costs 3 < 5).
    flow, side = grid_maxflow(i64([[3]]), i64([[5]]), i64([[0]]), i64([[0]]))
    assert flow == 3 and side.tolist() == [[True]]
    flow, side = grid_maxflow(i64([[5]]), i64([[3]]), i64([[0]]), i64([[0]]))
    assert flow == 3 and side.tolist() == [[False]]


def test_two_pixels_by_hand():
    # s -5-> a -3- b -4-> t: the path s,a,b,t carries min(5, 3, 4) = 3; cut = the edge a-b.
    s, t = i64([[5, 0]]), i64([[0, 4]])
    flow, side = grid_maxflow(s, t, i64([[3, 99]]), i64([[0, 0]]))  # right[:, -1] is ignored
    assert flow == 3 and side.tolist() == [[False, True]]
    # A strong edge: both pixels on the source side, the cut is b's sink arc (4).
    flow, side = grid_maxflow(s, t, i64([[10, 0]]), i64([[0, 0]]))
    assert flow == 4 and side.tolist() == [[False, False]]


def test_two_by_two_by_hand():
    # Source feeds the top row (6 each), the sink drains the bottom row (5 each); vertical edges 2,
    # the horizontal edges 1. Max-flow: each column carries 2 down -> 4; the min cut is the two
    # vertical edges (top on the source side, bottom on the sink side).
    s = i64([[6, 6], [0, 0]])
    t = i64([[0, 0], [5, 5]])
    r = i64([[1, 0], [1, 0]])
    d = i64([[2, 2], [0, 0]])
    flow, side = grid_maxflow(s, t, r, d)
    assert flow == 4
    assert side.tolist() == [[False, False], [True, True]]


def test_free_nodes_go_to_source_side():
    flow, side = grid_maxflow(*(np.zeros((3, 4), np.int64),) * 4)
    assert flow == 0 and not side.any()


@pytest.mark.parametrize("shape", [(1, 7), (9, 1), (13, 17), (64, 48)])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_int_grids_match_pymaxflow_exactly(shape, seed):
    rng = np.random.default_rng(seed)
    s, t = rng.integers(0, 30, shape), rng.integers(0, 30, shape)
    r, d = rng.integers(0, 12, shape), rng.integers(0, 12, shape)
    flow, side = grid_maxflow(i64(s), i64(t), i64(r), i64(d))
    ref_flow, ref_side = pymaxflow(s, t, r, d)
    # Integers: the maximum flow is unique and exact; the cut's energy equals it exactly.
    assert flow == ref_flow
    assert energy(s, t, r, d, side) == flow
    assert energy(s, t, r, d, ref_side) == flow


def test_vision_like_grid_matches_pymaxflow():
    # Noisy binary segmentation with a Potts prior (large uniform edge weights, long augmenting
    # paths, many orphans) -- the case BK is built for.
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:120, 0:160]
    img = ((np.sin(xx / 9.0) * np.cos(yy / 7.0)) > 0.1) + rng.normal(0, 0.8, yy.shape)
    s = np.round(100 * img ** 2).astype(np.int64)
    t = np.round(100 * (img - 1) ** 2).astype(np.int64)
    r = np.full(yy.shape, 60, np.int64)
    flow, side = grid_maxflow(s, t, r, r.copy())
    ref_flow, _ = pymaxflow(s, t, r, r)
    assert flow == ref_flow == energy(s, t, r, r, side)


def test_float_grid_matches_pymaxflow():
    rng = np.random.default_rng(3)
    shape = (40, 30)
    s, t, r, d = (rng.random(shape) * k for k in (3.0, 3.0, 1.0, 1.0))
    flow, side = grid_maxflow(s, t, r, d)
    ref_flow, _ = pymaxflow(s, t, r, d, float)
    # float64 sums of ~1e3 terms of size ~1: agreement to 1e-9 relative is rounding, not method.
    assert flow == pytest.approx(ref_flow, rel=1e-9)
    assert energy(s, t, r, d, side) == pytest.approx(flow, rel=1e-9)


def test_empty_grid():
    z = np.zeros((0, 5), np.int64)
    flow, side = grid_maxflow(z, z, z, z)
    assert flow == 0 and side.shape == (0, 5)


def test_bad_inputs():
    a = np.ones((4, 5), np.int64)
    with pytest.raises(DtypeError, match="source_cap"):
        grid_maxflow(a.astype(np.int32), a, a, a)
    with pytest.raises(DtypeError, match="right"):
        grid_maxflow(a, a, a.astype(np.float64), a)
    with pytest.raises(DtypeError, match="down"):
        grid_maxflow(a, a, a, [[1]])
    with pytest.raises(ShapeError, match="sink_cap"):
        grid_maxflow(a, np.ones((4, 6), np.int64), a, a)
    with pytest.raises(ShapeError, match="source_cap"):
        grid_maxflow(np.ones((4, 5, 1), np.int64), a, a, a)
    with pytest.raises(ShapeError, match="C-contiguous"):
        grid_maxflow(a, a, np.ones((5, 4), np.int64).T, a)
    neg = a.copy()
    neg[2, 3] = -1
    with pytest.raises(BadValueError, match="sink_cap.*>= 0"):
        grid_maxflow(a, neg, a, a)
    f = np.ones((4, 5))
    nan = f.copy()
    nan[0, 0] = np.nan
    with pytest.raises(BadValueError, match="down"):
        grid_maxflow(f, f, f, nan)
    inf = f.copy()
    inf[1, 1] = np.inf
    with pytest.raises(BadValueError, match="source_cap"):
        grid_maxflow(inf, f, f, f)


def test_gil_released():
    rng = np.random.default_rng(0)
    shape = (700, 700)
    s = np.round(100 * rng.random(shape)).astype(np.int64)
    t = np.round(100 * rng.random(shape)).astype(np.int64)
    r = np.full(shape, 30, np.int64)
    assert runs_python_during(lambda: _core.grid_maxflow(s, t, r, r), min_span=0.0)
