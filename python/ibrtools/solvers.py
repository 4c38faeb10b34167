"""General solvers of the engine (docs/solvers.md): grid max-flow/min-cut and Poisson blending.

* :func:`grid_maxflow` — minimum s-t cut of a 4-connected pixel grid by the Boykov-Kolmogorov
  algorithm (``cpp/kernels/solvers/maxflow.{h,cpp}``): binary labelling energies with per-pixel terminal
  capacities and symmetric edge capacities, e.g. graph-cut segmentation or the view-dependent
  mask of the hybrid harmonisation. int64 capacities give the exact optimum; float64 also works.
* :func:`poisson_blend` — Pérez et al. 2003 seamless cloning: inside ``mask`` the image whose
  Laplacian equals ``source``'s, with ``boundary``'s values on the mask's outer border, solved by
  multigrid-preconditioned conjugate gradients (``cpp/kernels/solvers/poisson.{h,cpp}``) to a stated
  relative residual.

Both check their arguments in C++ (``cpp/bindings/solvers.cpp``) and release the GIL.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ibrtools.errors import BadValueError, DtypeError, ShapeError


def _core():
    from ibrtools import _core  # noqa: PLC0415 (import where used: the package imports without the build)

    return _core


def grid_maxflow(source_cap: np.ndarray, sink_cap: np.ndarray, right: np.ndarray,
                 down: np.ndarray) -> tuple[float | int, np.ndarray]:
    """Minimum cut of a 4-connected H x W grid graph.

    ``source_cap``, ``sink_cap`` (H, W) >= 0: capacities of the arcs source -> pixel and
    pixel -> sink. ``right`` (H, W) >= 0: symmetric capacity of the edge (y, x) - (y, x + 1)
    (last column ignored); ``down`` (H, W): edge (y, x) - (y + 1, x) (last row ignored).
    All four float64, or all four int64 (then the result is exact).

    Returns ``(flow, sink_side)``: the maximum flow value (= the capacity of the minimum cut =
    the minimum of ``sum(source_cap[L]) + sum(sink_cap[~L]) + sum of the edge capacities across
    label changes`` over bool labellings L) and the (H, W) bool labelling, True where the pixel
    is on the sink side (PyMaxflow's ``get_grid_segments`` convention; pixels connected to
    neither terminal go to the source side). Raises ShapeError / DtypeError / BadValueError
    (negative, NaN or infinite capacity).
    """
    arrays = {"source_cap": source_cap, "sink_cap": sink_cap, "right": right, "down": down}
    for name, a in arrays.items():
        if not isinstance(a, np.ndarray):
            raise DtypeError(f"{name}: expected a numpy float64 or int64 array of shape (H, W), got {type(a).__name__}")
    dtype = source_cap.dtype
    if dtype not in (np.float64, np.int64):
        raise DtypeError(f"source_cap: expected float64 or int64, got {dtype}")
    for name, a in arrays.items():
        if a.dtype != dtype:
            raise DtypeError(f"{name}: expected {dtype} like source_cap, got {a.dtype}")
    flow, sink_side = _core().grid_maxflow(source_cap, sink_cap, right, down)
    return flow, sink_side


def poisson_blend(boundary: np.ndarray, source: np.ndarray, mask: np.ndarray, *, tol: float = 1e-6,
                  max_iter: int = 200) -> tuple[np.ndarray, dict[str, Any]]:
    """Pérez et al. 2003 seamless cloning (eq. 7, guidance v_pq = source_p - source_q).

    ``boundary``, ``source``: float32 (H, W) or (H, W, C) of one shape; ``mask``: bool (H, W),
    True = unknown. Inside the mask the result's discrete Laplacian (4 neighbours inside the
    image; Neumann at the image border) equals ``source``'s, and the mask's outer border takes
    ``boundary``'s values; outside the mask the result *is* ``boundary`` (copied). An empty mask
    returns a copy of ``boundary``. The mask may not cover the whole image (no boundary: the
    solution would be defined only up to a constant).

    Returns ``(out, info)`` with info = {"iterations", "relative_residual" (largest over the
    channels of ||b - A x|| / ||b||, computed from the returned solution), "converged" (every
    channel reached ``tol``), "unknowns"}.
    """
    for name, a in (("boundary", boundary), ("source", source)):
        if not isinstance(a, np.ndarray):
            raise DtypeError(f"{name}: expected a float32 numpy array of shape (H, W) or (H, W, C), got {type(a).__name__}")
        if a.ndim not in (2, 3):
            raise ShapeError(f"{name}: expected shape (H, W) or (H, W, C), got {a.shape}")
    if not isinstance(mask, np.ndarray):
        raise DtypeError(f"mask: expected a bool numpy array of shape (H, W), got {type(mask).__name__}")
    if mask.dtype != np.bool_:
        raise DtypeError(f"mask: expected bool, got {mask.dtype}")
    if not (isinstance(max_iter, (int, np.integer)) and max_iter >= 1):
        raise BadValueError(f"max_iter: expected an integer >= 1, got {max_iter!r}")
    out, info = _core().poisson_blend(boundary, source, mask, float(tol), int(max_iter))
    return out, dict(info)


def poisson_system(boundary, source, mask):
    """The linear system poisson_blend solves for one channel (Pérez et al. eq. 7), assembled
    independently with scipy in float64: (A csr (n, n), b (n,)) over the n mask pixels in row-major
    order. A reference for checks (scipy spsolve) and for peer solvers (pyamg); needs scipy."""
    import scipy.sparse as sp

    H, W = mask.shape
    idx = -np.ones((H, W), np.int64)
    m = int(mask.sum())
    idx[mask] = np.arange(m)
    ys, xs = np.nonzero(mask)
    b, diag = np.zeros(m), np.zeros(m)
    rows, cols, vals = [np.arange(m)], [np.arange(m)], []
    s, f = source.astype(np.float64), boundary.astype(np.float64)
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        qy, qx = ys + dy, xs + dx
        ok = (qy >= 0) & (qy < H) & (qx >= 0) & (qx < W)
        i, qy, qx = np.nonzero(ok)[0], qy[ok], qx[ok]
        diag[i] += 1
        b[i] += s[ys[i], xs[i]] - s[qy, qx]
        inside = mask[qy, qx]
        b[i[~inside]] += f[qy[~inside], qx[~inside]]
        rows.append(i[inside])
        cols.append(idx[qy[inside], qx[inside]])
        vals.append(-np.ones(int(inside.sum())))
    A = sp.csr_matrix((np.concatenate([diag] + vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m, m))
    return A, b
