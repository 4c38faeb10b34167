"""Variance mesh (Prakash et al. 2021, sec. 4.1): per vertex of the global mesh,
the per-channel standard deviation of the colours of the views that see it. docs/harmonise.md.

Visibility: a vertex is seen by a view when it projects inside the image, in front of the
camera, and its depth agrees with the mesh's depth rendered by Embree for that view
(:class:`ibrtools.raycast.reference.ReferenceRenderer`) within ``depth_tol`` (relative) -- the
depth test is the ray cast: the first hit along the pixel's ray is the vertex's own surface.
Colours are sampled bilinearly at the projection (pixel centres at +0.5).

Exposure and white balance are *removed before the deviation is taken*: each view's colours are
divided by its global per-channel gain (the median over its visible vertices of view colour /
vertex mean, re-estimated with the means until the gains settle). Otherwise a 20 % exposure difference
would make every vertex "view-dependent" and leave nothing for the diffuse harmonisation to
correct; what remains is what a global gain cannot explain: specular highlights, occlusion
errors, noise. (The paper does not say; this is our reading of what the variance must measure.)

Per-view work is vectorised numpy over vertices, the loop over views; the gain estimation's
two inner loops (per-vertex sums, per-view median ratios) are kernels (cpp/kernels/hybrid/vertexstats.h).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ibrtools.errors import BadValueError, DtypeError
from ibrtools.mesh import Mesh
from ibrtools.scene import Scene
from ibrtools.hybrid.gainmodel import gain_halves

DEPTH_TOL = 0.01  # |z_vertex - z_rendered| <= 1 % of z: a vertex on the rendered surface
GAIN_ITERATIONS = 30  # at most; stops when no gain moves by more than 1e-4 (log)


@dataclass
class VertexSamples:
    """The colour samples of one view: vertex indices seen, their colours (float32 (k, 3)),
    and where they project (x, y in pixels, pixel centres at +0.5)."""

    name: str
    index: np.ndarray
    color: np.ndarray
    x: np.ndarray
    y: np.ndarray


def check_inputs(scene: Scene, mesh: Mesh) -> None:
    if not isinstance(scene, Scene):
        raise DtypeError(f"scene: expected an ibrtools.Scene, got {type(scene).__name__}")
    if not isinstance(mesh, Mesh):
        raise DtypeError(f"mesh: expected an ibrtools.Mesh, got {type(mesh).__name__}")
    if not scene.views:
        raise BadValueError("scene: has no input views")
    for v in scene.views:
        if not v.has_color:
            raise BadValueError(f"view {v.name!r}: has no colour image")
    for lo in range(0, len(mesh.faces), 65536):  # usually decided by the first block
        fv = mesh.vertices[mesh.faces[lo:lo + 65536]].astype(np.float64)
        if np.any(np.linalg.norm(np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0]), axis=1) > 0):
            break
    else:
        raise BadValueError("mesh: degenerate (every triangle has zero area)")


def bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup at continuous pixel coordinates (pixel centres at +0.5), clamped."""
    h, w = img.shape[:2]
    fx = np.clip(x - 0.5, 0, w - 1)
    fy = np.clip(y - 0.5, 0, h - 1)
    x0 = np.minimum(fx.astype(np.int64), w - 2) if w > 1 else np.zeros(len(fx), np.int64)
    y0 = np.minimum(fy.astype(np.int64), h - 2) if h > 1 else np.zeros(len(fy), np.int64)
    ax = (fx - x0) if w > 1 else np.zeros(len(fx))
    ay = (fy - y0) if h > 1 else np.zeros(len(fy))
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    if img.ndim == 3:
        ax, ay = ax[:, None], ay[:, None]
    top = img[y0, x0] * (1 - ax) + img[y0, x1] * ax
    bot = img[y1, x0] * (1 - ax) + img[y1, x1] * ax
    return top * (1 - ay) + bot * ay


def visible_samples(scene: Scene, mesh: Mesh, renderer=None, depth_tol: float = DEPTH_TOL,
                    images: dict[str, np.ndarray] | None = None, depths: dict[str, np.ndarray] | None = None):
    """Yields one :class:`VertexSamples` per view (``images`` overrides the views' colours;
    ``depths``: the mesh's depth per view when the caller has rendered it already)."""
    from ibrtools.raycast.reference import ReferenceRenderer

    if renderer is None and depths is None:
        renderer = ReferenceRenderer(mesh)
    verts = mesh.vertices.astype(np.float64)
    for view in scene.views:
        cam = view.camera
        if depths is not None:
            depth = depths[view.name]
        else:
            depth = renderer.render(cam, outputs=("depth",), lights=[])["depth"]
        xy, z = cam.project(verts)
        x, y = xy[:, 0], xy[:, 1]
        ok = np.isfinite(z) & (z > 0) & (x >= 0) & (x < cam.width) & (y >= 0) & (y < cam.height)
        idx = np.nonzero(ok)[0]
        col = np.minimum((x[idx]).astype(np.int64), cam.width - 1)
        row = np.minimum((y[idx]).astype(np.int64), cam.height - 1)
        # The vertex is on the surface its pixel's ray hits first (else it is occluded).
        zr = depth[row, col]
        good = (zr > 0) & (np.abs(zr - z[idx]) <= depth_tol * z[idx])
        idx = idx[good]
        img = view.color if images is None else images[view.name]
        color = bilinear(img, x[idx], y[idx]).astype(np.float32)
        yield VertexSamples(view.name, idx, color, x[idx], y[idx])


def vertex_statistics(scene: Scene, mesh: Mesh, *, depth_tol: float = DEPTH_TOL, compensate_gains: bool = True,
                      renderer=None, samples: list[VertexSamples] | None = None) -> dict:
    """Per-vertex mean and standard deviation of the views' colours (after each view's global
    per-channel gain is divided out when ``compensate_gains``), the number of views that see
    each vertex and the per-view gains. Returns {"mean" (N, 3) f32, "std" (N, 3) f32,
    "count" (N,) i32, "gains": {view: (3,) f64}, "half_gains": {view: (4, 3) f64} (the gain on
    the view's left / right / top / bottom image half, for gainmodel.exposure_gains; {} without
    gain compensation), "samples": [VertexSamples]}."""
    from ibrtools import _core

    check_inputs(scene, mesh)
    if samples is None:
        samples = list(visible_samples(scene, mesh, renderer, depth_tol))
    n = len(mesh.vertices)
    names = [s.name for s in samples]
    gains = np.ones((len(samples), 3))
    half_gains: dict[str, np.ndarray] = {}
    count = np.zeros(n)
    for s in samples:
        count += np.bincount(s.index, minlength=n)

    # Every view's samples in one array, in view order, stored channel by channel (3, S); the
    # kernel accumulates each vertex's samples in that order (numpy bincount's bits).
    if samples:
        all_index = np.concatenate([s.index for s in samples]).astype(np.int64, copy=False)
        all_color = np.ascontiguousarray(np.concatenate([s.color for s in samples]).astype(np.float64).T)
    else:
        all_index, all_color = np.zeros(0, np.int64), np.zeros((3, 0))
    bounds = np.concatenate([[0], np.cumsum([len(s.index) for s in samples])]).astype(np.int64)
    cnt = np.maximum(count, 1)[:, None]

    def means(with_var=False):
        s1, s2 = _core.vertex_colour_sums(all_index, all_color, bounds, gains, n, squares=with_var)
        mean = s1 / cnt
        return mean, (np.maximum(s2 / cnt - mean ** 2, 0.0) if with_var else None)

    mean, _ = means()
    if compensate_gains and len(samples) > 1:
        # The samples of vertices another view sees too, with colours > 1e-3 (fixed), in view
        # order (rows [sh_bounds[k], sh_bounds[k + 1]) are view k's).
        sh = (count[all_index] >= 2) & (all_color > 1e-3).all(0)
        sh_index = all_index[sh]
        sh_color = np.ascontiguousarray(all_color[:, sh].T)
        sh_bounds = np.concatenate([[0], np.cumsum([sh[bounds[k]:bounds[k + 1]].sum() for k in range(len(samples))])
                                    ]).astype(np.int64)
        # Alternate gains (robust: medians of colour / gain / mean per view, over the vertices with
        # a mean > 1e-3 in every channel, where at least 16 are) and means until the gains settle
        # (each vertex is seen by a subset of the views, so the means mix gains: convergence is
        # geometric, not one step).
        for _ in range(GAIN_ITERATIONS):
            before = gains.copy()
            med, used = _core.gain_median_ratios(sh_index, sh_color, sh_bounds, gains, mean)
            upd = used >= 16
            gains[upd] = gains[upd] * med[upd]
            # Gains are relative: fix their geometric mean at 1 per channel.
            gains = gains / np.exp(np.mean(np.log(gains), axis=0))
            mean, _ = means()
            if float(np.abs(np.log(gains / before)).max()) < 1e-4:
                break
        # The same median ratio on each half of the view's image (at the converged means): an
        # exposure scales the whole image, so the halves of an exposure gain agree.
        for k, s in enumerate(samples):
            a, b = sh_bounds[k], sh_bounds[k + 1]
            own = sh[bounds[k]:bounds[k + 1]]
            idx, c, x, y = sh_index[a:b], sh_color[a:b], s.x[own], s.y[own]
            cam = scene.view(s.name).camera
            m = mean[idx]
            ok = (m > 1e-3).all(1)
            half_gains[s.name] = gain_halves(c[ok] / m[ok], x[ok], y[ok], cam.width, cam.height, gains[k])
    mean, var = means(with_var=True)
    std = np.where(count[:, None] >= 2, np.sqrt(var), 0.0)
    mean = np.where(count[:, None] >= 1, mean, 0.0)
    return {"mean": mean.astype(np.float32), "std": std.astype(np.float32), "count": count.astype(np.int32),
            "gains": {name: gains[k].copy() for k, name in enumerate(names)}, "half_gains": half_gains,
            "samples": samples}


def variance_mesh(scene: Scene, mesh: Mesh, *, depth_tol: float = DEPTH_TOL) -> np.ndarray:
    """(N, 3) float32 per-vertex, per-channel standard deviation of the (gain-compensated)
    colours of the views that see the vertex; 0 where fewer than 2 views see it."""
    return vertex_statistics(scene, mesh, depth_tol=depth_tol)["std"]
