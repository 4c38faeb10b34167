"""Per-view meshes (PVM) and their tiles in a two-level voxel grid (Prakash et al. 2021, sec. 5.1,
Fig. 2b; per-view meshes after Hedman et al. 2016, sec. 4). docs/preprocess.md.

* :func:`view_mesh` — one view's depth map as a world-space triangle mesh of the surface it sees:
  a triangle per half pixel quad between pixel centres, edges cut at depth discontinuities
  (relative jump > ``max_rel_jump``), blocks of up to ``max_block`` quads merged into two
  triangles where the surface is planar (pinhole: 1/z affine in the pixel coordinates within
  a tolerance: ``plane_tol``, raised to ``noise_tol`` times the view's relative depth noise as
  :func:`depth_noise` estimates it). C++: ``_core.pvm_triangulate`` (cpp/kernels/hybrid/pvm.h).
  With the global mesh's depth in the view (``mesh_depth``), depth within ``snap`` of it takes the
  mesh's depth first (:func:`snap_depth`): the fused surface, averaged over every view, where the
  view's own depth cannot be told from it; the view's depth where it departs (geometry the global
  mesh lacks or rounds off).
* :func:`build_tiles` — every view's PVM sliced into the fine cells of a grid of
  ``coarse``^3 cells over the PVMs' bounds, each split ``sub`` times per axis; a tile is the part
  of one view's PVM in one fine cell (``clip`` "large": triangles whole, in the cell of their
  centroid, or, reaching beyond the coarse cells next to it, in every cell they have area in;
  "all": every triangle crossing a cell face clipped into pieces, the paper's slicing), stored
  compactly (:class:`PvmTiles`): one vertex array and one face array sorted by tile, offsets,
  per-tile AABB, view and fine cell, and per coarse cell the range of its tiles (the lookup
  level). C++: ``_core.pvm_slice``.

Arrays: vertices float32 world units, faces int32 counter-clockwise seen from the view's camera.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Mapping

import numpy as np

from ibrtools.camera import PINHOLE, Camera
from ibrtools.checks import check_float, check_int
from ibrtools.errors import BadValueError, DtypeError, FormatError, MissingFileError, ShapeError
from ibrtools.outputs import mkstemp_beside

TILES_FORMAT = 1
# PvmOptions.clip: "large" keeps triangles whole: in the fine cell of the centroid when the triangle lies
# within the coarse cells next to the centroid's (the renderer's visibility margin), else in every fine
# cell it has area in; "all" clips every triangle crossing a fine cell's face into pieces (the paper's
# slicing).
CLIP_MODES = ("large", "all")


@dataclass(frozen=True)
class PvmOptions:
    """Parameters of the PVM stage (hashed into its cache key)."""

    max_rel_jump: float = 0.03  # an edge is cut where neighbour depths differ by > 3 %
    plane_tol: float = 1e-3      # merged block: 1/z within 0.1 % of the corners' bilinear ...
    noise_tol: float = 4.0       # ... or within noise_tol x the view's estimated relative depth noise
    max_block: int = 16          # largest merged block, in pixel quads
    coarse: int = 32             # coarse cells per axis (paper: 32^3)
    sub: int = 4                 # fine cells per coarse cell per axis (paper: 4)
    mesh_snap: float = 2.0       # depth within mesh_snap voxels of the global mesh's takes the mesh's (0 = off)
    clip: str = "large"          # "large": triangles whole (CLIP_MODES); "all": clipped to the fine cells

    def __post_init__(self) -> None:
        jump = check_float(self.max_rel_jump, "max_rel_jump")
        if not jump > 0:
            raise BadValueError(f"max_rel_jump: expected > 0, got {jump}")
        tol = check_float(self.plane_tol, "plane_tol", 0.0)
        ntol = check_float(self.noise_tol, "noise_tol", 0.0)
        mb = check_int(self.max_block, "max_block", 1)
        if mb & (mb - 1) or mb > 256:
            raise BadValueError(f"max_block: expected a power of two <= 256, got {mb}")
        # coarse: the tiling holds an int64 offset per coarse cell, coarse^3 of them (134 MB at 256)
        snap = check_float(self.mesh_snap, "mesh_snap", 0.0)
        coarse = check_int(self.coarse, "coarse", 1, 256)
        sub = check_int(self.sub, "sub", 1)
        for k, v in (("max_rel_jump", jump), ("noise_tol", ntol), ("mesh_snap", snap)):
            if v > 1e6:  # only finite in float32 matters (params.py FINITE_MAX)
                raise BadValueError(f"{k}: expected a number <= 1e+06, got {v}")
        if self.clip not in CLIP_MODES:
            raise BadValueError(f"clip: expected one of {', '.join(CLIP_MODES)}, got {self.clip!r}")
        if coarse * sub > 4096:
            raise BadValueError(f"coarse * sub: expected <= 4096, got {coarse} * {sub}")
        for k, v in (("max_rel_jump", jump), ("plane_tol", tol), ("noise_tol", ntol), ("max_block", mb), ("coarse", coarse),
                     ("sub", sub), ("mesh_snap", snap)):
            object.__setattr__(self, k, v)

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


# The merge tolerance never exceeds this (a view with wildly inconsistent depth keeps its quads).
MAX_PLANE_TOL = 0.1


def depth_noise(depth: np.ndarray) -> float:
    """Relative noise of a pinhole depth map, estimated robustly (i.i.d. per-pixel noise assumed).

    On a plane 1/z is affine in the pixel coordinates, so the second difference
    r = f(x) - (f(x - 1) + f(x + 1)) / 2 of f = 1/z vanishes; multiplicative noise of standard
    deviation s on z gives f relative noise s, and r / f a standard deviation s * sqrt(1.5). The
    estimate is 1.4826 * median(|r / f|) / sqrt(1.5) (the MAD) over the horizontal and vertical
    triples of valid depth: the triples across discontinuities and silhouettes are outliers the
    median ignores (a few % of them move it by a few % of s), curved surfaces contribute their
    (sub-pixel small) curvature. 0 with fewer than 64 triples.
    Measured: 0.0101-0.0102 on the views of synth:objects with depth_noise 0.01, 0 without noise."""
    if not isinstance(depth, np.ndarray) or depth.dtype.kind != "f":
        raise DtypeError(f"depth: expected a float numpy array, got {getattr(depth, 'dtype', type(depth).__name__)}")
    if depth.ndim != 2:
        raise ShapeError(f"depth: expected shape (H, W), got {depth.shape}")
    d = depth.astype(np.float32, copy=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(np.isfinite(d) & (d > 0), np.float32(1.0) / d, np.float32(np.nan))
        parts = []
        for a, b, c in ((f[:, :-2], f[:, 1:-1], f[:, 2:]), (f[:-2], f[1:-1], f[2:])):
            r = np.abs(b - 0.5 * (a + c)) / b
            parts.append(r[np.isfinite(r)])  # NaN: a missing depth in the triple
    r = np.concatenate([p.ravel() for p in parts])
    if r.size < 64:
        return 0.0
    return float(1.4826 * np.median(r) / np.sqrt(1.5))


def plane_tolerance(camera: Camera, depth: np.ndarray, options: PvmOptions | None = None) -> float:
    """The merge tolerance of one view: max(plane_tol, noise_tol x depth_noise), at most
    MAX_PLANE_TOL. Noisy depth defeats a fixed 0.1 % (docs/pvm_render.md "Speed"): every pixel quad
    became two triangles. A tolerance matched to the noise merges the blocks the noise alone keeps
    apart; their corners carry the same noise as before, the other vertices are dropped."""
    options = options or PvmOptions()
    if camera.model != PINHOLE or options.noise_tol <= 0:
        return float(options.plane_tol)
    tol = options.noise_tol * depth_noise(depth)
    return float(min(MAX_PLANE_TOL, max(options.plane_tol, tol)))


def snap_depth(depth: np.ndarray, mesh_depth: np.ndarray, snap: float) -> np.ndarray:
    """``depth`` with every pixel within ``snap`` (world units, along the depth's measure: z or ray
    distance) of ``mesh_depth`` set to ``mesh_depth``; pixels where either has no surface (0, NaN,
    inf) keep ``depth``. float32 (H, W)."""
    ok = np.isfinite(depth) & (depth > 0) & np.isfinite(mesh_depth) & (mesh_depth > 0)
    with np.errstate(invalid="ignore"):
        near = ok & (np.abs(depth - mesh_depth) <= snap)
    return np.ascontiguousarray(np.where(near, mesh_depth, depth).astype(np.float32))


def _check_depth(camera: Camera, depth: np.ndarray, name: str) -> np.ndarray:
    if not isinstance(depth, np.ndarray) or depth.dtype != np.float32:
        raise DtypeError(f"{name}: expected a float32 numpy array, got "
                         f"{getattr(depth, 'dtype', type(depth).__name__)}")
    hw = (camera.height, camera.width)
    if depth.shape != hw:
        raise ShapeError(f"{name}: expected shape (H, W) = {hw} to match the camera, got {depth.shape}")
    return np.ascontiguousarray(depth)


def view_mesh(camera: Camera, depth: np.ndarray, options: PvmOptions | None = None, *,
              mesh_depth: np.ndarray | None = None, snap: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """World-space mesh (vertices float32 (N, 3), faces int32 (M, 3)) of the surface one view sees.

    ``depth``: float32 (H, W) as in scene.py (z for pinhole, ray distance for equirect; 0 or inf =
    no surface). Only the pixel centres used by a triangle become vertices. ``mesh_depth`` (the
    global mesh's depth in this view, same measure) and ``snap`` > 0 (world units): the depth is
    :func:`snap_depth`-ed first; the merge tolerance is still the one of ``depth`` itself (its noise
    is what the merging must not split on)."""
    from ibrtools import _core

    options = options or PvmOptions()
    if not isinstance(camera, Camera):
        raise DtypeError(f"camera: expected an ibrtools.Camera, got {type(camera).__name__}")
    depth = _check_depth(camera, depth, "depth")
    snap = check_float(snap, "snap", 0.0)
    tol = plane_tolerance(camera, depth, options)
    if mesh_depth is not None and snap > 0:
        depth = snap_depth(depth, _check_depth(camera, mesh_depth, "mesh_depth"), snap)
    field_ = None
    if camera.model == PINHOLE:
        with np.errstate(divide="ignore"):
            field_ = np.where(depth > 0, np.float32(1.0) / depth, np.float32(0.0)).astype(np.float32)
    faces = _core.pvm_triangulate(depth, field_, options.max_rel_jump, tol, options.max_block)
    if len(faces) == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
    used = np.zeros(depth.size, bool)
    used[faces.ravel()] = True
    ids = np.flatnonzero(used)
    remap = np.full(depth.size, -1, np.int32)
    remap[ids] = np.arange(len(ids), dtype=np.int32)
    ys, xs = np.divmod(ids, camera.width)
    rays = camera.rays_in_cam(xs + 0.5, ys + 0.5)
    d = depth.ravel()[ids].astype(np.float64)
    if camera.model == PINHOLE:
        p_cam = rays * d[:, None]  # rays_in_cam has z = 1 for pinhole
    else:
        p_cam = rays / np.linalg.norm(rays, axis=-1, keepdims=True) * d[:, None]
    wfc = camera.world_from_cam
    verts = (p_cam @ wfc[:3, :3].T + wfc[:3, 3]).astype(np.float32)
    return np.ascontiguousarray(verts), np.ascontiguousarray(remap[faces])


@dataclass(eq=False)
class PvmTiles:
    """Per-view meshes and their tiles (docs/FORMAT.md, "cache/pvm").

    pvm_vertices (N, 3) f32, pvm_faces (M, 3) i32 (indices into pvm_vertices), pvm_face_view (M,)
    i32: every view's PVM, concatenated in view order. Tiles t = 0..T-1, sorted by (coarse cell,
    fine cell, view): faces[face_offsets[t]:face_offsets[t+1]] index vertices (global indices, all
    inside vertices[vertex_offsets[t]:vertex_offsets[t+1]]); face_source (F,) the PVM face each
    tile face was cut from; tile_view (T,) i32, tile_cell (T, 3) i32 fine cell (x, y, z),
    tile_bounds (T, 2, 3) f32 AABB; coarse_offsets (coarse^3 + 1,) i64: tiles of coarse cell
    c = (cz * coarse + cy) * coarse + cx are coarse_offsets[c]:coarse_offsets[c+1]. Fine cell
    (i, j, k) spans origin + (i, j, k) * cell .. + cell (the outermost cells extend to infinity).
    """

    views: list[str]
    origin: np.ndarray
    cell: np.ndarray
    coarse: int
    sub: int
    pvm_vertices: np.ndarray
    pvm_faces: np.ndarray
    pvm_face_view: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    face_source: np.ndarray
    face_offsets: np.ndarray
    vertex_offsets: np.ndarray
    tile_view: np.ndarray
    tile_cell: np.ndarray
    tile_bounds: np.ndarray
    coarse_offsets: np.ndarray
    stats: dict = field(default_factory=dict)

    @property
    def num_tiles(self) -> int:
        return len(self.tile_view)

    def tile(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """(vertices, faces) of tile ``t`` with faces indexing the returned vertices."""
        t = check_int(t, "tile", 0)
        if t >= self.num_tiles:
            raise BadValueError(f"tile: expected < {self.num_tiles}, got {t}")
        v0, v1 = self.vertex_offsets[t], self.vertex_offsets[t + 1]
        f = self.faces[self.face_offsets[t]:self.face_offsets[t + 1]] - v0
        return self.vertices[v0:v1], f

    def cell_bounds(self, t: int) -> np.ndarray:
        """(2, 3) world bounds of tile ``t``'s fine cell (float64, infinite on the grid's outer faces)."""
        c = self.tile_cell[t].astype(np.float64)
        lo = self.origin + c * self.cell
        hi = lo + self.cell
        n = self.coarse * self.sub
        lo = np.where(self.tile_cell[t] == 0, -np.inf, lo)
        hi = np.where(self.tile_cell[t] == n - 1, np.inf, hi)
        return np.stack([lo, hi])

    def coarse_tiles(self, cx: int, cy: int, cz: int) -> range:
        c = (cz * self.coarse + cy) * self.coarse + cx
        return range(int(self.coarse_offsets[c]), int(self.coarse_offsets[c + 1]))

    def save(self, path: str | os.PathLike) -> Path:
        """Write as one uncompressed .npz, atomically (temporary name, then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {f.name: getattr(self, f.name) for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray)}
        meta = np.array([TILES_FORMAT, self.coarse, self.sub], np.int64)
        tmp = mkstemp_beside(path)
        try:
            np.savez(tmp, meta=meta, views=np.array(self.views, dtype=str), **arrays)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "PvmTiles":
        path = Path(path)
        if not path.is_file():
            raise MissingFileError(f"{path}: no such file")
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = z["meta"]
                if int(meta[0]) != TILES_FORMAT:
                    raise FormatError(f"{path}: PVM tiles format {int(meta[0])} (this ibrtools reads {TILES_FORMAT})")
                kw = {f.name: z[f.name] for f in fields(cls) if f.name in z.files and f.name not in ("views",)}
                return cls(views=[str(v) for v in z["views"]], coarse=int(meta[1]), sub=int(meta[2]), **kw)
        except (OSError, ValueError, KeyError) as e:
            raise FormatError(f"{path}: not a readable PVM tiles file ({e})") from None


def grid_bounds(vertices: np.ndarray, coarse: int, sub: int) -> tuple[np.ndarray, np.ndarray]:
    """Origin and fine cell size of the grid over ``vertices``' bounds: cubic cells, the largest
    extent (padded by 1e-4 of it on each side) split into ``coarse * sub`` cells, the grid centred on
    the bounds (so it reaches beyond them along the shorter axes).

    Why cubes: with a cell per axis of that axis's extent / 128, a flat scene (objects on a ground
    plane: 24.7 m x 1.7 m x 24.7 m) got 1.3 cm tall cells against 19 cm wide ones, and per-view
    meshes of noisy depth (vertices jittered along the rays by ~1 % of the depth) crossed several
    of those thin slabs per triangle: slicing multiplied the 2.9 M PVM triangles by 6.5 (18.8 M
    tile triangles) and the per-view depth pass drew 2.6 M triangles per 1280x720 frame. Cubic
    19 cm cells: 8.8 M tile triangles, 1.4 M drawn (docs/pvm_render.md, "Speed")."""
    if len(vertices) == 0:
        raise BadValueError("PVM bounds: empty (no view has a valid depth pixel forming a triangle)")
    lo = vertices.min(0).astype(np.float64)
    hi = vertices.max(0).astype(np.float64)
    big = float((hi - lo).max())
    if not big > 0:
        raise BadValueError(f"PVM bounds: empty (all vertices at one point {lo.tolist()})")
    side = big * (1 + 2e-4)
    n = coarse * sub
    centre = (lo + hi) / 2
    return centre - side / 2, np.full(3, side / n)


def build_tiles(cameras: Mapping[str, Camera], depths: Mapping[str, np.ndarray],
                options: PvmOptions | None = None, *,
                view_meshes: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
                mesh_depths: Mapping[str, np.ndarray] | None = None, snap: float = 0.0) -> PvmTiles:
    """Every view's PVM, sliced into tiles. ``cameras`` and ``depths`` keyed by view name (same
    names, in the order of ``cameras``). ``view_meshes``: every view's :func:`view_mesh` already
    made (by Dask workers, ibrtools.pipeline.stages); ``depths`` is then not read. ``mesh_depths`` (the
    global mesh's depth of some views) and ``snap``: :func:`view_mesh`'s, per view that has one."""
    from ibrtools import _core

    options = options or PvmOptions()
    names = list(cameras)
    if not names:
        raise BadValueError("build_tiles: no views")
    missing = [n for n in names if (n not in depths or depths[n] is None) and n not in (view_meshes or {})]
    if missing:
        raise BadValueError(f"build_tiles: views without depth {missing[:5]} (give depth maps or a mesh to "
                            "render them from)")
    verts, faces, fview, base = [], [], [], 0
    per_view = {}
    for i, n in enumerate(names):
        v, f = (view_meshes[n] if view_meshes is not None else
                view_mesh(cameras[n], depths[n], options, mesh_depth=(mesh_depths or {}).get(n), snap=snap))
        verts.append(v)
        faces.append(f + base)
        fview.append(np.full(len(f), i, np.int32))
        base += len(v)
        per_view[n] = int(len(f))
    pv = np.ascontiguousarray(np.concatenate(verts), np.float32)
    pf = np.ascontiguousarray(np.concatenate(faces), np.int32)
    pfv = np.ascontiguousarray(np.concatenate(fview), np.int32)
    if len(pf) == 0:
        raise BadValueError("PVM bounds: empty (no view has a valid depth pixel forming a triangle)")
    origin, cell = grid_bounds(pv, options.coarse, options.sub)
    r = _core.pvm_slice(pv, pf, pfv, len(names), origin.tolist(), cell.tolist(), options.coarse, options.sub,
                        clip_all=options.clip == "all")
    keys = r["keys"]
    n_views = len(names)
    tile_view = (keys % n_views).astype(np.int32)
    vox = keys // n_views
    sub3 = options.sub ** 3
    coarse_id, local = vox // sub3, vox % sub3
    c = options.coarse
    cx, cy, cz = coarse_id % c, (coarse_id // c) % c, coarse_id // (c * c)
    s = options.sub
    lx, ly, lz = local % s, (local // s) % s, local // (s * s)
    tile_cell = np.stack([cx * s + lx, cy * s + ly, cz * s + lz], -1).astype(np.int32)
    coarse_offsets = np.searchsorted(coarse_id, np.arange(c ** 3 + 1), side="left").astype(np.int64)
    return PvmTiles(views=names, origin=origin, cell=cell, coarse=options.coarse, sub=options.sub,
                    pvm_vertices=pv, pvm_faces=pf, pvm_face_view=pfv,
                    vertices=r["vertices"], faces=r["faces"], face_source=r["face_source"],
                    face_offsets=r["face_offsets"], vertex_offsets=r["vertex_offsets"],
                    tile_view=tile_view, tile_cell=np.ascontiguousarray(tile_cell),
                    tile_bounds=r["bounds"], coarse_offsets=coarse_offsets,
                    stats={"pvm_faces": int(len(pf)), "pvm_faces_per_view": per_view,
                           "tiles": int(len(keys)), "tile_faces": int(len(r["faces"]))})
