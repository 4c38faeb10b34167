"""A UV texture atlas for the global mesh (TM as a textured mesh, as the paper's TM is;
docs/texture.md "Atlas").

* :func:`layout` — parameterisation and packing of our own: the faces are binned by their
  longest edge in texels (bins a factor 1.25 wide, largest first), ordered along a Morton curve
  of their centroids within a bin (neighbouring faces get neighbouring cells) and paired; each
  pair gets a square cell of N x N texels (N = longest edge of the
  pair / texel + 4, so every edge gets at least its length in texels), face A in the lower-left
  corner with legs N - 3, face B in the upper-right corner with legs N - 4. Texel (i, j) of the
  cell belongs to A when (i + 0.5) + (j + 0.5) <= N, else to B. A bilinear read at (x, y) touches
  texel centres within 1 of x and of y, so sums of centres within 2 of x + y; A's diagonal lies
  at x + y = N - 1 and B's at N + 2, so a bilinear lookup anywhere inside a face reads only
  texels assigned to that face (tests/hybrid/test_atlas.py checks it). Cells are shelf-packed in that
  order (rows as tall as their tallest cell; a loop over the rows). ``face_scale`` gives faces
  their own texel size (:func:`face_footprint_scale`). One chart per
  face: no seams to cut, no distortion beyond mapping each triangle to a right isosceles one.
  (open3d's UVAtlas, ``compute_uvatlas``, was not used: it takes minutes on 10^5 faces and
  offers nothing the per-face charts need here.)
* :func:`bake` — per texel, the world point of its face at the texel centre's barycentrics
  (clamped to the face: texels outside it take the face's nearest point, which is the charts'
  dilation) and the interpolated vertex normal; colour = the ULR-weighted blend of the views
  that see the point, the same weights as the per-vertex texture
  (:func:`ibrtools.hybrid.globalmesh.point_colors`); texels no view sees get the per-vertex colour.
* :func:`texel_size` — the views' median pixel footprint on the surface (depth / focal length).

Coordinates: ``uv`` (M, 3, 2) float32 in atlas pixels (x right, y down, pixel centres at
+0.5), as the sampling kernel (``_core.sample_atlas``) reads them; :func:`obj_uvs` converts to the
OBJ convention of :class:`ibrtools.mesh.Mesh` (normalised, v up).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ibrtools.camera import PINHOLE, Camera
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.mesh import Mesh
from ibrtools.hybrid.globalmesh import (ATLAS_MAX_TEXELS, ATLAS_TEXELS_LIMIT, GlobalMeshOptions, point_colors, smooth_normals,
                         vertex_normals)
from ibrtools.imageio import srgb8

MIN_CELL = 5  # B's legs of N - 4 texels: >= 1 texel
CHUNK = 1 << 19  # texels per point_colors call (bounds the (views, texels) penalty arrays)


@dataclass
class AtlasLayout:
    uv: np.ndarray          # (M, 3, 2) float32, atlas pixels
    face_of_texel: np.ndarray  # (H, W) int32, -1 = unused
    texel: float            # world units per texel


def _check_mesh(mesh: Mesh) -> None:
    if not isinstance(mesh, Mesh):
        raise DtypeError(f"mesh: expected an ibrtools.Mesh, got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise BadValueError("texture atlas: the mesh has no faces")


def texel_size(cameras: Mapping[str, Camera], depths: Mapping[str, np.ndarray]) -> float:
    """Median over the views of (median valid depth) x (angle per pixel): the size of an input
    pixel on the surface, in world units."""
    sizes = []
    for n, cam in cameras.items():
        d = np.asarray(depths[n])
        ok = d[np.isfinite(d) & (d > 0)]
        if ok.size == 0:
            continue
        per_px = 1.0 / cam.fx if cam.model == PINHOLE else (cam.lon_range[1] - cam.lon_range[0]) / cam.width
        sizes.append(float(np.median(ok)) * per_px)
    if not sizes:
        raise BadValueError("texture atlas: no view has a valid depth pixel (cannot choose the texel size)")
    return float(np.median(sizes))


def layout(mesh: Mesh, texel: float, max_texels: int = ATLAS_MAX_TEXELS, max_cell: int = 256,
           face_scale: np.ndarray | None = None) -> AtlasLayout:
    """Per-face charts packed in cells of face pairs (module docstring). ``texel``: world units per
    texel; grown (by factors of 1.25) until the atlas holds at most ``max_texels``. ``face_scale``
    (M,) > 0: face f gets texels of ``texel * face_scale[f]`` (:func:`face_footprint_scale`: finer
    where the views see the surface finely); None = 1 everywhere."""
    _check_mesh(mesh)
    if not (isinstance(texel, (int, float)) and math.isfinite(texel) and texel > 0):
        raise BadValueError(f"texture atlas: texel size must be a finite number > 0, got {texel!r}")
    if not MIN_CELL * MIN_CELL <= int(max_texels) <= ATLAS_TEXELS_LIMIT:
        raise BadValueError(f"texture atlas: max_texels must be in [{MIN_CELL * MIN_CELL}, {ATLAS_TEXELS_LIMIT}], "
                            f"got {max_texels}")
    v = mesh.vertices.astype(np.float64)
    f = mesh.faces
    m = len(f)
    e = np.stack([v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 1]], v[f[:, 0]] - v[f[:, 2]]], 1)
    longest = np.linalg.norm(e, axis=-1).max(1)
    if face_scale is not None:
        fs = np.asarray(face_scale, np.float64)
        if fs.shape != (m,):
            raise ShapeError(f"face_scale: expected shape ({m},), got {fs.shape}")
        if not (np.all(np.isfinite(fs)) and np.all(fs > 0)):
            raise BadValueError("face_scale: expected finite values > 0")
        longest = longest / fs  # in units of the face's own texel
    # Order: faces binned by length in texels (bins a factor 1.25 wide), largest bin first; within
    # a bin by the Morton code of the centroid, so that neighbours on the surface (and on the
    # screen) get neighbouring cells and the TM read walks the atlas instead of jumping at every
    # face (cache misses: docs/texture.md "Atlas").
    length_bin = np.floor(np.log(np.maximum(longest, 1e-30)) / math.log(1.25))
    order = np.lexsort((_morton(v[f].mean(1)), -length_bin))
    n_pairs = (m + 1) // 2
    pairs = np.full(2 * n_pairs, -1, np.int64)
    pairs[:m] = order
    pairs = pairs.reshape(n_pairs, 2)
    pair_len = np.maximum(longest[pairs[:, 0]], np.where(pairs[:, 1] >= 0, longest[pairs[:, 1]], 0.0))
    # The smallest cell a pair can get: MIN_CELL + 1 when it has a positive length (the ceil is
    # >= 1 for any finite texel), MIN_CELL for a degenerate pair. Growing the texel stops there:
    # growing on would only end when the texel overflows to infinity.
    floor = np.where(pair_len > 0, MIN_CELL + 1, MIN_CELL)
    while True:
        cell = np.clip(np.ceil(pair_len / texel).astype(np.int64) + MIN_CELL, floor, max_cell)
        total = int((cell * cell).sum())
        if total <= max_texels or (cell <= floor).all():
            break
        texel *= 1.25
    if total > max_texels:
        raise BadValueError(f"texture atlas: {m} faces need at least {total} texels, more than max_texels "
                            f"{max_texels}")
    width = int(max(int(cell.max()), math.ceil(math.sqrt(total))))
    sizes = np.unique(cell)[::-1]
    # Shelf packing: the cells in that order (sizes non-increasing up to the 1.25 bin width) fill
    # rows ("shelves") left to right; a shelf is as tall as its tallest cell. One iteration per
    # shelf (about sqrt(pairs) of them), not per face.
    origin = np.zeros((n_pairs, 2), np.int64)
    csum = np.concatenate([[0], np.cumsum(cell)])
    start, y0 = 0, 0
    while start < n_pairs:
        end = int(np.searchsorted(csum, csum[start] + width, side="right")) - 1  # cells start..end-1 fit
        end = max(end, start + 1)
        origin[start:end, 0] = csum[start:end] - csum[start]
        origin[start:end, 1] = y0
        y0 += int(cell[start:end].max())
        start = end
    height = y0
    nf = cell.astype(np.float64)[:, None]
    ox, oy = origin[:, 0:1].astype(np.float64), origin[:, 1:2].astype(np.float64)
    # A: (1, 1), (N - 2, 1), (1, N - 2) (diagonal x + y = N - 1); B: (N - 1, N - 1), (3, N - 1),
    # (N - 1, 3) (diagonal x + y = N + 2).
    ua = np.stack([np.concatenate([ox + 1, oy + 1], 1), np.concatenate([ox + nf - 2, oy + 1], 1),
                   np.concatenate([ox + 1, oy + nf - 2], 1)], 1)
    ub = np.stack([np.concatenate([ox + nf - 1, oy + nf - 1], 1), np.concatenate([ox + 3, oy + nf - 1], 1),
                   np.concatenate([ox + nf - 1, oy + 3], 1)], 1)
    uv = np.zeros((m, 3, 2), np.float32)
    uv[pairs[:, 0]] = ua
    has_b = pairs[:, 1] >= 0
    uv[pairs[has_b, 1]] = ub[has_b]
    # Texel ownership: centre (i + 0.5, j + 0.5) in the cell; i + j + 1 <= N -> A, else B.
    fot = np.full((height, width), -1, np.int32)
    for n in sizes:
        idx = np.flatnonzero(cell == n)
        jj, ii = np.mgrid[0:n, 0:n]
        is_a = (ii + jj + 1) <= n
        owner = np.where(is_a[None], pairs[idx, 0][:, None, None], pairs[idx, 1][:, None, None])
        ys = origin[idx, 1][:, None, None] + jj[None]
        xs = origin[idx, 0][:, None, None] + ii[None]
        fot[ys, xs] = owner
    return AtlasLayout(uv, fot, float(texel))


def face_footprint_scale(mesh: Mesh, cameras: Mapping[str, Camera], texel: float,
                         limits: tuple[float, float] = (0.5, 8.0)) -> np.ndarray:
    """(M,) per-face texel scale: the finest input-pixel footprint on the face (over the views
    whose image holds the face's centroid in front of the camera: depth x angle per pixel; no
    occlusion test) divided by ``texel``, clipped to ``limits``; faces no view holds get the upper
    limit. Surface the views see from far away needs no texel per input-pixel-at-median-depth."""
    _check_mesh(mesh)
    c = mesh.vertices[mesh.faces].astype(np.float64).mean(1)
    best = np.full(len(c), np.inf)
    for cam in cameras.values():
        xy, z = cam.project(c)
        with np.errstate(invalid="ignore"):
            ok = (np.isfinite(z) & (z > 0) & (xy[:, 0] >= 0) & (xy[:, 0] < cam.width)
                  & (xy[:, 1] >= 0) & (xy[:, 1] < cam.height))
        per_px = 1.0 / cam.fx if cam.model == PINHOLE else (cam.lon_range[1] - cam.lon_range[0]) / cam.width
        best[ok] = np.minimum(best[ok], z[ok] * per_px)
    scale = np.where(np.isfinite(best), best / texel, limits[1])
    return np.clip(scale, limits[0], limits[1])


def _morton(points: np.ndarray) -> np.ndarray:
    """Morton (Z-order) codes of 3-D points quantised to 1024 steps per axis of their bounds."""
    p = np.asarray(points, np.float64)
    lo = p.min(0)
    span = max(float((p.max(0) - lo).max()), 1e-12)
    q = np.clip(((p - lo) / span * 1023.0).astype(np.int64), 0, 1023)

    def spread(x: np.ndarray) -> np.ndarray:  # 10 bits -> every third bit of 30
        x = (x | (x << 16)) & 0x030000FF
        x = (x | (x << 8)) & 0x0300F00F
        x = (x | (x << 4)) & 0x030C30C3
        return (x | (x << 2)) & 0x09249249

    return spread(q[:, 0]) | (spread(q[:, 1]) << 1) | (spread(q[:, 2]) << 2)


def texel_points(mesh: Mesh, lay: AtlasLayout, normals: np.ndarray, rows: slice | None = None
                 ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """((ys, xs, face), bary (T, 3), points (T, 3), unit normals (T, 3)) of the used texels (of the
    atlas rows ``rows``, default all; row-major): the barycentrics of the texel centre in its face's
    chart, clamped to the face (negative weights set to 0, renormalised), and the surface point and
    normal (of the per-vertex ``normals`` (N, 3)) they give, in float64 (``_core.texel_points``)."""
    from ibrtools import _core

    lo, hi, _ = (slice(None) if rows is None else rows).indices(lay.face_of_texel.shape[0])
    ys, xs, face, bary, pts, nrm = _core.texel_points(
        np.ascontiguousarray(lay.face_of_texel[lo:hi], np.int32), lo, np.ascontiguousarray(lay.uv, np.float32),
        np.ascontiguousarray(mesh.vertices, np.float32), np.ascontiguousarray(mesh.faces, np.int32),
        np.ascontiguousarray(normals, np.float32))
    return (ys, xs, face), bary, pts, nrm


def bake(mesh: Mesh, lay: AtlasLayout, cameras: Mapping[str, Camera], colors: Mapping[str, np.ndarray],
         depths: Mapping[str, np.ndarray], vertex_color: np.ndarray,
         options: GlobalMeshOptions | None = None) -> tuple[np.ndarray, float]:
    """The atlas image (H, W, 3) float32 and the fraction of used texels no view sees (those get
    ``vertex_color`` interpolated; unused texels 0)."""
    _check_mesh(mesh)
    vc = np.asarray(vertex_color, np.float32)
    if vc.shape != (len(mesh.vertices), 3):
        raise ShapeError(f"vertex_color: expected shape ({len(mesh.vertices)}, 3), got {vc.shape}")
    h, w = lay.face_of_texel.shape
    if h == 0 or w == 0:
        raise BadValueError("texture atlas: the layout has size 0")
    opts = options or GlobalMeshOptions()
    vn = vertex_normals(mesh.vertices, mesh.faces)
    if opts.bake_normal_rounds:
        vn = smooth_normals(vn, mesh.faces, opts.bake_normal_rounds)
    labels = None
    if opts.bake_label_weight > 0:
        from ibrtools.hybrid.texlabel import UNSEEN_COST, face_data_cost, face_edges, potts_labels

        names = list(cameras)
        cost = face_data_cost(mesh, cameras, depths, opts.depth_tol)
        lab = potts_labels(cost, face_edges(mesh.faces), opts.bake_label_weight)
        # -1: no view sees the face's centroid (the per-texel blend decides there).
        labels = np.where(cost[np.arange(len(lab)), lab] < UNSEEN_COST, lab, -1)
        one = GlobalMeshOptions(**{**opts.to_dict(), "k_views": 1})
    img = np.zeros((h, w, 3), np.float32)
    unseen = used = 0
    # Bands of about CHUNK texels (whole atlas rows): the per-texel temporaries (~200 bytes a
    # texel with point_colors' (views, texels) arrays) stay bounded whatever the atlas size.
    band = max(1, CHUNK // w)
    for lo in range(0, h, band):
        (ys, xs, face), b, pts, nrm = texel_points(mesh, lay, vn, slice(lo, min(h, lo + band)))
        if len(face) == 0:
            continue
        if labels is None:
            col, seen = point_colors(pts, nrm, cameras, colors, depths, options)
        else:
            col = np.zeros((len(face), 3), np.float32)
            seen = np.zeros(len(face), np.int32)
            tl = labels[face]
            for j in np.unique(tl[tl >= 0]):
                sel = np.flatnonzero(tl == j)
                n = names[j]
                c1, s1 = point_colors(pts[sel], nrm[sel], {n: cameras[n]}, {n: colors[n]}, {n: depths[n]}, one)
                col[sel], seen[sel] = c1, s1
            rest = np.flatnonzero(seen == 0)
            if len(rest):
                col[rest], seen[rest] = point_colors(pts[rest], nrm[rest], cameras, colors, depths, options)
        miss = seen == 0
        if miss.any():
            col[miss] = np.einsum("tk,tkc->tc", b[miss], vc[mesh.faces[face[miss]]]).astype(np.float32)
        unseen += int(miss.sum())
        used += len(face)
        img[ys, xs] = col
    return img, unseen / max(1, used)


def to_srgb8(img: np.ndarray) -> np.ndarray:
    """Linear RGB (H, W, 3) float -> (H, W, 4) uint8 sRGB RGBA (alpha 255; values clipped to [0, 1]),
    the storage ``_core.sample_atlas`` reads fastest (cpp/kernels/hybrid/atlas8.h)."""
    a = np.asarray(img)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ShapeError(f"atlas: expected shape (H, W, 3), got {a.shape}")
    if a.dtype.kind != "f":
        raise DtypeError(f"atlas: expected a float array, got {a.dtype}")
    out = np.full(a.shape[:2] + (4,), 255, np.uint8)
    for lo in range(0, a.shape[0], 512):  # bounded float64 temporaries
        sl = np.clip(np.nan_to_num(a[lo:lo + 512].astype(np.float32)), 0.0, 1.0)
        out[lo:lo + 512, :, :3] = srgb8(sl)
    return out


def obj_uvs(uv: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Atlas-pixel UVs -> OBJ convention (u = x / W, v = 1 - y / H), for :class:`ibrtools.mesh.Mesh`."""
    h, w = size
    out = np.empty_like(uv, dtype=np.float32)
    out[..., 0] = uv[..., 0] / w
    out[..., 1] = 1.0 - uv[..., 1] / h
    return out
