"""Poisson blending (ibrtools.solvers.poisson_blend, cpp/kernels/solvers/poisson.{h,cpp}): exact on a
quadratic, scipy's sparse direct solve as the reference, masks at the image border, empty and
one-pixel masks, thread-count independence, bad input, the GIL."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as sla

from gil import runs_python_during
from ibrtools import _core
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.solvers import poisson_blend, poisson_system

pytestmark = [pytest.mark.asan, pytest.mark.kernel, pytest.mark.tsan]


@pytest.fixture
def restore_threads():
    yield
    _core.set_num_threads(0)


def test_exact_on_a_quadratic():
    # source q1 and boundary q2 = q1 + (x^2 - y^2) + linear + const have the same Laplacian (the
    # 5-point Laplacian of a quadratic is exact, and x^2 - y^2 and linear terms are discrete-
    # harmonic), so the solution inside is q2. Mask away from the image border (no Neumann side).
    H, W = 48, 64
    y, x = np.mgrid[0:H, 0:W] / 32.0
    q1 = 0.3 * x ** 2 + 0.2 * y ** 2 + 0.1 * x * y
    q2 = q1 + 0.25 * (x ** 2 - y ** 2) + 0.1 * x - 0.2 * y + 0.5
    mask = np.zeros((H, W), bool)
    mask[5:40, 7:55] = True
    mask[20:30, 20:30] = False  # a hole: the domain is an annulus
    out, info = poisson_blend(q2.astype(np.float32), q1.astype(np.float32), mask, tol=1e-10)
    assert info["converged"] and info["relative_residual"] <= 1e-10
    # float32 inputs and output: the rounding of q1, q2 (|q| < 3, eps 2.4e-7 relative) is all that
    # is left, amplified mildly by the solve -> 5e-6 absolute.
    np.testing.assert_allclose(out[mask], q2[mask], atol=5e-6)
    assert np.array_equal(out[~mask], q2.astype(np.float32)[~mask])


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("shape", [(9, 13), (37, 29), (64, 80)])
def test_matches_scipy_direct_solve(seed, shape):
    rng = np.random.default_rng(seed)
    boundary = rng.random(shape).astype(np.float32)
    source = rng.random(shape).astype(np.float32)
    mask = rng.random(shape) < 0.6  # scattered pixels and blobs, touching the border
    mask[0, 0] = False
    out, info = poisson_blend(boundary, source, mask, tol=1e-11)
    A, b = poisson_system(boundary, source, mask)
    x = sla.spsolve(A, b)
    assert info["converged"], info
    # Residual 1e-11 relative => error ~1e-9 even with a condition number ~1e2; the float32
    # output rounds values in [0, 1.5] to 1e-7: 1e-6 is the task's agreement target.
    np.testing.assert_allclose(out[mask], x, atol=1e-6)
    assert np.array_equal(out[~mask], boundary[~mask])


def test_mask_touching_every_border_and_identity():
    rng = np.random.default_rng(4)
    H, W = 30, 40
    boundary = rng.random((H, W, 3)).astype(np.float32)
    mask = np.ones((H, W), bool)
    mask[10:12, 15:17] = False  # the only Dirichlet pixels; the rest of the border is Neumann
    # Same image as boundary and source: the solution is that image.
    out, info = poisson_blend(boundary, boundary, mask, tol=1e-10)
    np.testing.assert_allclose(out, boundary, atol=2e-6)
    # A constant offset between source and boundary is removed entirely (pure Neumann outside).
    out, info = poisson_blend(boundary, boundary + np.float32(0.5), mask, tol=1e-10)
    np.testing.assert_allclose(out, boundary, atol=2e-6)
    for c in range(3):
        A, b = poisson_system(boundary[..., c], boundary[..., c] + np.float32(0.5), mask)
        np.testing.assert_allclose(out[..., c][mask], sla.spsolve(A, b), atol=1e-6)


def test_empty_mask_is_a_copy():
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    out, info = poisson_blend(img, img * 2, np.zeros((3, 4), bool))
    assert np.array_equal(out, img) and not np.shares_memory(out, img)
    assert info["iterations"] == 0 and info["converged"] and info["unknowns"] == 0


def test_one_pixel_mask_by_hand():
    boundary = np.arange(20, dtype=np.float32).reshape(4, 5)
    source = np.zeros((4, 5), np.float32)
    source[1, 2] = 8.0
    mask = np.zeros((4, 5), bool)
    mask[1, 2] = True
    out, info = poisson_blend(boundary, source, mask)
    # 4 f = sum of the 4 neighbours' boundary values + sum_q (s_p - s_q) = (2+12+6+8) + 32.
    assert out[1, 2] == pytest.approx((2 + 12 + 6 + 8 + 32) / 4, abs=1e-5)
    # At the image corner: 2 neighbours (Neumann).
    mask = np.zeros((4, 5), bool)
    mask[0, 0] = True
    out, _ = poisson_blend(boundary, np.zeros_like(boundary), mask)
    assert out[0, 0] == pytest.approx((1 + 5) / 2, abs=1e-6)


def test_channels_are_independent():
    rng = np.random.default_rng(7)
    boundary = rng.random((33, 47, 3)).astype(np.float32)
    source = rng.random((33, 47, 3)).astype(np.float32)
    mask = np.zeros((33, 47), bool)
    mask[3:30, 4:40] = True
    out, _ = poisson_blend(boundary, source, mask, tol=1e-10)
    for c in range(3):
        one, _ = poisson_blend(np.ascontiguousarray(boundary[..., c]), np.ascontiguousarray(source[..., c]), mask,
                               tol=1e-10)
        np.testing.assert_allclose(out[..., c], one, atol=1e-6)


def test_identical_for_any_thread_count(restore_threads):
    rng = np.random.default_rng(8)
    H, W = 300, 260  # enough rows for several parallel tasks per level
    boundary = rng.random((H, W)).astype(np.float32)
    source = rng.random((H, W)).astype(np.float32)
    mask = np.zeros((H, W), bool)
    mask[10:290, 5:250] = True
    _core.set_num_threads(1)
    a, ia = poisson_blend(boundary, source, mask)
    _core.set_num_threads(2)
    b, ib = poisson_blend(boundary, source, mask)
    assert np.array_equal(a, b) and ia == ib


def test_bad_inputs():
    img = np.zeros((6, 7), np.float32)
    mask = np.zeros((6, 7), bool)
    mask[2, 2] = True
    with pytest.raises(DtypeError, match="boundary"):
        poisson_blend(img.astype(np.float64), img, mask)
    with pytest.raises(DtypeError, match="source"):
        poisson_blend(img, [[0.0]], mask)
    with pytest.raises(DtypeError, match="mask"):
        poisson_blend(img, img, mask.astype(np.uint8))
    with pytest.raises(ShapeError, match="source"):
        poisson_blend(img, np.zeros((6, 8), np.float32), mask)
    with pytest.raises(ShapeError, match="source"):
        poisson_blend(img, np.zeros((6, 7, 3), np.float32), mask)
    with pytest.raises(ShapeError, match="mask"):
        poisson_blend(img, img, np.zeros((7, 6), bool))
    with pytest.raises(ShapeError, match="boundary"):
        poisson_blend(np.zeros(5, np.float32), img, mask)
    with pytest.raises(BadValueError, match="whole image"):
        poisson_blend(img, img, np.ones((6, 7), bool))
    bad = img.copy()
    bad[0, 0] = np.nan
    with pytest.raises(BadValueError, match="NaN"):
        poisson_blend(bad, img, mask)
    with pytest.raises(BadValueError, match="tol"):
        poisson_blend(img, img, mask, tol=0.0)
    with pytest.raises(BadValueError, match="max_iter"):
        poisson_blend(img, img, mask, max_iter=0)


def test_gil_released(restore_threads):
    rng = np.random.default_rng(0)
    H = W = 700
    boundary = rng.random((H, W)).astype(np.float32)
    mask = np.zeros((H, W), bool)
    mask[1:-1, 1:-1] = True
    _core.set_num_threads(1)
    assert runs_python_during(lambda: _core.poisson_blend(boundary, boundary * 0.5, mask), min_span=0.0)
