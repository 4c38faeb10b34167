"""One view per face of the global mesh for the texture bake (Waechter et al. 2014, "Let
There Be Color!", without their seam levelling): a labelling with a data term and a Potts
smoothness term on the face adjacency, minimised by alpha-expansion (Boykov et al. 2001) with
PyMaxflow's max-flow on the general face graph (the project's own max-flow,
``solvers.grid_maxflow``, is for pixel grids only).

Energy: sum_f D[f, l_f] + weight * sum_{(f, g) adjacent} [l_f != l_g].

:func:`face_data_cost`: D[f, v] = 1 - a_v(f) / max_u a_u(f), a_v(f) = the face's projected area
in view v's pixels when its centroid is visible there (in front, inside the image, within
``depth_tol`` of the view's depth, facing the camera), else the face cannot take label v
(cost ``UNSEEN_COST``). Large, frontal, close projections cost least: the views a texel would
be sharpest and least misregistered in; the Potts term makes the choice piecewise constant, so
neighbouring texels do not mix differently misregistered views.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ibrtools.camera import Camera
from ibrtools.checks import check_float, check_int
from ibrtools.errors import BadValueError, NotBuiltError, ShapeError
from ibrtools.mesh import Mesh

UNSEEN_COST = 1e3


def face_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) int64 pairs of faces sharing an edge (f < g, each pair once, sorted). An edge of
    more than two faces links them in a chain (each to the next by face index)."""
    f = np.asarray(faces, np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ShapeError(f"faces: expected shape (M, 3), got {f.shape}")
    m = len(f)
    if m == 0:
        return np.zeros((0, 2), np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e.sort(axis=1)
    owner = np.tile(np.arange(m, dtype=np.int64), 3)
    key = e[:, 0] * (int(f.max()) + 1) + e[:, 1]
    order = np.lexsort((owner, key))
    key, owner = key[order], owner[order]
    same = key[1:] == key[:-1]
    p = np.stack([owner[:-1][same], owner[1:][same]], 1)
    p = p[p[:, 0] != p[:, 1]]
    p.sort(axis=1)
    return np.unique(p, axis=0).reshape(-1, 2)


def face_data_cost(mesh: Mesh, cameras: Mapping[str, Camera], depths: Mapping[str, np.ndarray],
                   depth_tol: float = 0.02) -> np.ndarray:
    """(F, V) float32 data cost of every face for every view (module docstring), views in
    ``cameras`` order."""
    names = list(cameras)
    if not names:
        raise BadValueError("face labels: no views")
    tol = check_float(depth_tol, "depth_tol")
    if not tol > 0:
        raise BadValueError("depth_tol: expected > 0")
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    tri = v[f]
    cen = tri.mean(1)
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.zeros((len(f), len(names)))
    for j, n in enumerate(names):
        cam = cameras[n]
        if cam.model != "pinhole":
            raise BadValueError(f"face labels: view {n!r} is {cam.model}; only pinhole views")
        dep = np.asarray(depths[n], np.float32)
        if dep.shape != (cam.height, cam.width):
            raise ShapeError(f"view {n!r}: expected depth ({cam.height}, {cam.width}), got {dep.shape}")
        xy, z = cam.project(tri)  # (F, 3, 2), (F, 3); NaN where a corner is not in front
        front = (z > 1e-9).all(1)
        px, py = xy[..., 0], xy[..., 1]
        with np.errstate(invalid="ignore"):
            a = 0.5 * np.abs((px[:, 1] - px[:, 0]) * (py[:, 2] - py[:, 0]) - (px[:, 2] - px[:, 0]) * (py[:, 1] - py[:, 0]))
        # The centroid: inside the image, in front, facing the camera, within depth_tol of the view.
        cxy, cz = cam.project(cen)
        u, w = cxy[:, 0], cxy[:, 1]
        with np.errstate(invalid="ignore"):
            inside = front & (cz > 1e-9) & (u >= 0) & (u < cam.width) & (w >= 0) & (w < cam.height)
        iu = np.where(inside, np.nan_to_num(u), 0).astype(np.int64)
        iw = np.where(inside, np.nan_to_num(w), 0).astype(np.int64)
        dz = np.where(inside, dep[iw, iu], 0.0).astype(np.float64)
        centre = cam.centre
        facing = np.einsum("fc,fc->f", fn, centre[None] - cen) > 0
        ok = inside & facing & (dz > 0) & (np.abs(np.where(inside, cz, 0.0) - dz) <= tol * dz)
        area[:, j] = np.where(ok, a, 0.0)
    best = area.max(1, keepdims=True)
    cost = np.where(area > 0, 1.0 - area / np.where(best > 0, best, 1.0), UNSEEN_COST)
    return cost.astype(np.float32)


def potts_energy(cost: np.ndarray, edges: np.ndarray, labels: np.ndarray, weight: float) -> float:
    """The labelling energy of the module docstring (float64)."""
    c = np.asarray(cost, np.float64)
    lab = np.asarray(labels, np.int64)
    e = np.asarray(edges, np.int64).reshape(-1, 2)
    return float(c[np.arange(len(lab)), lab].sum() + weight * (lab[e[:, 0]] != lab[e[:, 1]]).sum())


def potts_labels(cost: np.ndarray, edges: np.ndarray, weight: float, sweeps: int = 2) -> np.ndarray:
    """Labels (F,) int32 minimising the Potts energy by alpha-expansion from the data term's
    argmin: ``sweeps`` passes over the labels (each expansion is one s-t min-cut; the energy never
    increases; stops early when a pass changes nothing). Labels no face can take cheaply
    (all costs >= UNSEEN_COST) are skipped."""
    try:
        import maxflow
    except ImportError as e:  # an optional dependency (the test and bench extras)
        raise NotBuiltError("face labels need PyMaxflow (pip install PyMaxflow)") from e

    c = np.asarray(cost, np.float64)
    if c.ndim != 2 or c.shape[1] < 1:
        raise ShapeError(f"cost: expected shape (F, L) with L >= 1, got {c.shape}")
    if not np.isfinite(c).all():
        raise BadValueError("cost: expected finite values")
    e = np.asarray(edges, np.int64)
    if e.ndim != 2 or e.shape[1] != 2:
        raise ShapeError(f"edges: expected shape (E, 2), got {e.shape}")
    if len(e) and (e.min() < 0 or e.max() >= len(c)):
        raise BadValueError(f"edges: face index outside 0..{len(c) - 1}")
    lam = check_float(weight, "weight")
    if not lam >= 0:
        raise BadValueError(f"weight: expected >= 0, got {weight!r}")
    sweeps = check_int(sweeps, "sweeps", 1)
    n, nl = c.shape
    lab = np.argmin(c, 1).astype(np.int64)
    if n == 0 or nl == 1 or lam == 0 or len(e) == 0:
        return lab.astype(np.int32)
    a_, b_ = e[:, 0], e[:, 1]
    rows = np.arange(n)
    for _ in range(sweeps):
        changed = False
        for alpha in range(nl):
            if not (c[:, alpha] < UNSEEN_COST).any():
                continue
            is_a = lab == alpha
            # Binary choice per face: keep its label (source side, x = 0) or take alpha (x = 1).
            # Data: keep -> c[f, lab_f], alpha -> c[f, alpha] (faces already alpha: both alpha).
            d0 = c[rows, lab]
            d1 = c[:, alpha]
            # Pairwise Potts term, as E(x_f, x_g): E00 = lam [l_f != l_g], E01 = lam [l_f != a],
            # E10 = lam [a != l_g], E11 = 0 — submodular (E00 + E11 <= E01 + E10, triangle rule).
            la, lb = lab[a_], lab[b_]
            e00 = lam * (la != lb)
            e01 = lam * (la != alpha)
            e10 = lam * (lb != alpha)
            # Standard reduction: E = E00 + (E10 - E00) x_f + (E11 - E10) x_g + (E01 + E10 - E00 - E11) x_g (1 - x_f)...
            # written with unary terms on f and g and one edge capacity f -> g of
            # E01 + E10 - E00 (>= 0) for the (x_f = 0, x_g = 1) cut.
            u1 = d1.copy()
            u0 = d0.copy()
            np.add.at(u1, a_, e10 - e00)        # x_f = 1 costs E10 - E00 (given x_g = 0)
            np.add.at(u1, b_, -e10)             # x_g = 1 adds E11 - E10 = -E10
            cap = e01 + e10 - e00
            # Normalise unaries to non-negative t-link capacities.
            lo = np.minimum(u0, u1)
            u0, u1 = u0 - lo, u1 - lo
            # Faces already alpha cannot leave alpha (both choices are alpha): x = 1 forced.
            big = 1e9
            u0 = np.where(is_a, big, u0)
            g = maxflow.Graph[float](n, len(e))
            ids = g.add_nodes(n)
            # x = 1 (alpha) = sink side: a node on the sink side cuts its source edge, so the
            # source capacity is the cost of x = 1 and the sink capacity the cost of x = 0.
            g.add_grid_tedges(ids, u1, u0)
            # Edge f -> g cut when f is source side (x_f = 0) and g sink side (x_g = 1).
            g.add_edges(ids[a_], ids[b_], cap, np.zeros_like(cap))
            g.maxflow()
            x = g.get_grid_segments(ids)  # True: sink side = alpha
            new = np.where(x, alpha, lab)
            if (new != lab).any():
                before = potts_energy(c, e, lab, lam)
                after = potts_energy(c, e, new, lam)
                if after < before - 1e-9 * max(1.0, abs(before)):
                    lab = new
                    changed = True
        if not changed:
            break
    return lab.astype(np.int32)
