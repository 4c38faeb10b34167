"""The global mesh of hybrid IBR (Prakash et al. 2021, sec. 3.1 and Fig. 2).
docs/preprocess.md says what is chosen and why.

* :func:`choose_source` — where the geometry comes from. ``auto``: the scene's
  ``reconstructed`` mesh when it has one (what a real capture gives); else, when every view has
  depth, TSDF fusion of the depth maps (so that a synthetic scene's ground truth never leaks
  into a method under evaluation); else the ``ground_truth`` mesh (the only geometry there is);
  else an error. ``reconstructed`` / ``ground_truth`` / ``fusion`` force one.
* :func:`fuse_depth` — open3d's sparse VoxelBlockGrid over the views' depth maps, marching
  cubes; voxel = the depth points' largest extent / ``resolution`` (default 384), truncation 4 voxels.
  :func:`build_global_mesh` fuses each view's ``fusion_depth``: the depth as the data set stored
  it where the importer filtered it (de-quantised 8-bit codes), so that the views' rounding
  errors, which differ from view to view, average out (docs/preprocess.md "Fusion").
* :func:`densify` — midpoint subdivision of edges longer than ``max_edge`` (per-vertex colour
  needs vertices about as dense as the texture detail it should hold).
* :func:`vertex_colors` — per-vertex colour by ULR-weighted blending (Buehler et al. 2001) of
  the views that see the vertex: visibility by a depth test against each view's depth map,
  penalty = angle between the vertex normal and the direction to the camera + a resolution
  term, k = 4 best views, weights 1 - p / p_(k+1).
* :func:`depth_from_mesh` — a view's depth rendered from the mesh (Embree, ReferenceRenderer).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Mapping

import numpy as np

from ibrtools.camera import PINHOLE, Camera
from ibrtools.checks import check_float, check_int
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.mesh import Mesh
from ibrtools.scene import Scene
from ibrtools.camera import look_at
from ibrtools.hybrid.gainmodel import GAIN_MODES
from ibrtools.memory import available_memory

SOURCES = ("auto", "reconstructed", "ground_truth", "fusion")
# The texture atlas's default texel cap: 2^25 texels = 128 MiB of 8-bit sRGB RGBA (an 8192 x 4096
# atlas), held in memory by the TM render; the bake holds ~20 bytes a texel more while it runs
# (float32 RGB image, int32 face map: ~0.7 GB at the cap). Chosen by memory: a scene's atlas gets
# the texels its layout asks at the views' pixel footprint up to it (docs/texture.md "Atlas").
# The old cap, 2^22 (2048^2), held no atlas for a fused mesh of 10^6 faces (>= 36 texels a face
# pair), which then fell back to per-vertex colour.
ATLAS_MAX_TEXELS = 1 << 25
# Upper limit of atlas_max_texels: 4 GiB of RGBA; atlas sides stay far below 2^24, where float32
# uv (integer texel corners) stop being exact.
ATLAS_TEXELS_LIMIT = 1 << 30


# Upper bounds of the mesh stage's options (docs/preprocess.md "Bounds and memory"). resolution: a voxel of
# 1/4096 of the scene is finer than the depth maps' pixels for every data set we read (lego's 800
# pixels, 4K frames), so a finer one adds no detail, only memory; within it the TSDF's memory is
# estimated (fusion_memory) and checked before the stage runs. trunc_voxels: the band of blocks
# each depth sample activates grows with its cube. max_faces: 160 bytes a face once the mesh is
# loaded with its BVH (pipeline/job.py), 10 GB at 2^26. k_views: the ULR kernels' 64 views a point.
MESH_LIMITS = {"resolution": 4096, "trunc_voxels": 16.0, "max_faces": 1 << 26, "k_views": 64,
               "max_edge_voxels": 1e6, "render_edge_voxels": 1e6, "depth_tol": 1e6, "atlas_texel": 1e6,
               "gain_max_ratio": 1e6, "bake_label_weight": 1e6}
# TSDF fusion's peak bytes per 8^3-voxel block that a depth sample falls in (fusion_memory): the
# block's tsdf and weight (4 KiB), the neighbouring blocks within the truncation band that the
# sample activates too, open3d's hash map and the marching-cubes mesh. Measured on synth:objects
# (6 views of 320x240, peak RSS of fuse_depth with /usr/bin/time -v less the interpreter's):
# resolution 384 / 1000 / 2000 -> 2412 / 12556 / 32691 blocks, 111 / 553 / 1690 MB = 46 / 44 / 52
# KB a block; 64 KiB a block keeps the estimate 1.2-1.5x above them.
FUSION_BLOCK_BYTES = 64 << 10
FUSION_BASE_BYTES = 400 << 20


def _check_max(value, name: str, integer: bool = False):
    """``value`` (already checked for type and minimum) at most MESH_LIMITS[name]."""
    top = MESH_LIMITS[name]
    if value > top:
        raise BadValueError(f"{name}: expected {'an integer' if integer else 'a number'} <= {top:g}, got {value}")
    return value


@dataclass(frozen=True)
class GlobalMeshOptions:
    """Parameters of the mesh and texture stages (hashed into their cache keys)."""

    source: str = "auto"
    resolution: int = 384        # TSDF voxel = largest extent of the depth points / resolution
    trunc_voxels: float = 4.0    # TSDF truncation distance in voxels
    max_edge_voxels: float = 1.0  # densify a given mesh to edges <= this many voxels
    # The render mesh: the same surface densified only to edges <= render_edge_voxels
    # (a given mesh; a fused mesh is used as it is). TM's atlas, the G-buffer of tm / ulr / hybrid
    # and ULR's occlusion depth use it; the dense mesh above carries the per-vertex statistics
    # (variance, harmonisation, view-dependent texture). Midpoint subdivision does not move the
    # surface, so both meshes have the same geometry.
    render_edge_voxels: float = 16.0
    max_faces: int = 4_000_000   # cap on densification
    k_views: int = 4             # ULR: views blended per vertex
    depth_tol: float = 0.02      # visibility: |z_vertex - z_view| <= depth_tol * z_view
    # texture atlas (hybrid/atlas.py): texel = atlas_texel x the input views' median pixel
    # footprint on the surface; at most atlas_max_texels texels (the texel grows to fit). The cap
    # is a memory bound (ATLAS_MAX_TEXELS: 128 MiB of 8-bit RGBA), not a quality knob.
    atlas_texel: float = 1.0
    atlas_max_texels: int = ATLAS_MAX_TEXELS
    # per-face texel size following the finest footprint of the views on the face
    # (atlas.face_footprint_scale, clipped to 0.5-8x); False: one texel size for every face.
    atlas_adaptive: bool = True
    # Which part of the views' estimated gains the texture stage divides out (hybrid/gainmodel.py):
    # "auto" = all of it when it looks like exposure jitter, only the part not explained by a
    # smooth function of the viewing direction when it looks like shading; "exposure" = all of it
    # (texture stage version 5); "none" = nothing.
    gain_model: str = "auto"
    gain_max_ratio: float = 0.5
    # Rounds of 1-ring averaging of the vertex normals the bake ranks views by and tests
    # front-facing with (smooth_normals): a fused surface's normals are voxel-noisy, and a
    # per-texel ranking on them mixes differently misregistered views between neighbouring texels.
    bake_normal_rounds: int = 0
    # The same two for a mesh made by TSDF fusion (texture_options): its normals are voxel-noisy
    # and its surface ~1 voxel off, so each view's sample is misregistered differently; blending
    # more views, ranked on smoothed normals, averages that out (lego validation, docs/texture.md).
    # A given (reconstructed / ground-truth) mesh keeps k_views and bake_normal_rounds (the
    # synth bench scenes lose 0.6 dB of TM with 8 rounds of smoothing across their sharp edges).
    fused_k_views: int = 8
    fused_normal_rounds: int = 8
    # > 0: the atlas takes one view per face (hybrid/texlabel.py: projected-area data term, Potts
    # smoothness of this weight on the face adjacency, alpha-expansion); texels that view does not
    # see, and faces no view sees, keep the per-texel ULR blend. 0: the per-texel blend everywhere.
    bake_label_weight: float = 0.0

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise BadValueError(f"mesh source: expected one of {SOURCES}, got {self.source!r}")
        check_int(self.resolution, "resolution", 8, MESH_LIMITS["resolution"])
        _check_max(check_float(self.trunc_voxels, "trunc_voxels", 1.0), "trunc_voxels")
        for name in ("max_edge_voxels", "render_edge_voxels", "depth_tol", "atlas_texel"):
            if not _check_max(check_float(getattr(self, name), name), name) > 0:
                raise BadValueError(f"{name}: expected > 0")
        check_int(self.max_faces, "max_faces", 1, MESH_LIMITS["max_faces"])
        check_int(self.k_views, "k_views", 1, MESH_LIMITS["k_views"])
        check_int(self.atlas_max_texels, "atlas_max_texels", 16, ATLAS_TEXELS_LIMIT)
        if not isinstance(self.atlas_adaptive, (bool, np.bool_)):
            raise BadValueError(f"atlas_adaptive: expected true or false, got {self.atlas_adaptive!r}")

        if self.gain_model not in GAIN_MODES:
            raise BadValueError(f"gain_model: expected one of {GAIN_MODES}, got {self.gain_model!r}")
        if not _check_max(check_float(self.gain_max_ratio, "gain_max_ratio"), "gain_max_ratio") >= 0:
            raise BadValueError("gain_max_ratio: expected >= 0")
        check_int(self.bake_normal_rounds, "bake_normal_rounds", 0, 10_000)
        check_int(self.fused_k_views, "fused_k_views", 1, MESH_LIMITS["k_views"])
        check_int(self.fused_normal_rounds, "fused_normal_rounds", 0, 10_000)
        if not _check_max(check_float(self.bake_label_weight, "bake_label_weight"), "bake_label_weight") >= 0:
            raise BadValueError("bake_label_weight: expected >= 0")

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def texture_options(self, source: str) -> "GlobalMeshOptions":
        """The options the texture bake uses on a mesh from ``source`` (choose_source's answer):
        for "fusion", k_views and bake_normal_rounds replaced by fused_k_views and
        fused_normal_rounds; otherwise these options."""
        if source != "fusion":
            return self
        return GlobalMeshOptions(**{**self.to_dict(), "k_views": self.fused_k_views,
                                    "bake_normal_rounds": self.fused_normal_rounds})


def choose_source(scene: Scene, source: str = "auto") -> str:
    """The mesh source ``auto`` resolves to for ``scene`` (see the module docstring)."""
    if source not in SOURCES:
        raise BadValueError(f"mesh source: expected one of {SOURCES}, got {source!r}")
    all_depth = bool(scene.views) and all(v.has_depth for v in scene.views)
    if source == "auto":
        if "reconstructed" in scene.meshes:
            return "reconstructed"
        if all_depth:
            return "fusion"
        if "ground_truth" in scene.meshes:
            return "ground_truth"
        raise BadValueError(f"global mesh: {_without_depth(scene)} and the scene has no mesh; nothing to build "
                            "geometry from (give every view a depth map, e.g. COLMAP's stereo/depth_maps, docs/importers.md; "
                            "or the scene a 'reconstructed' mesh, scene.json \"meshes\", docs/FORMAT.md)")
    if source in ("reconstructed", "ground_truth") and source not in scene.meshes:
        raise BadValueError(f"global mesh: the scene has no {source!r} mesh (it has: "
                            f"{', '.join(scene.meshes) or 'none'})")
    if source == "fusion" and not all_depth:
        raise BadValueError(f"global mesh: fusion needs a depth map for every view; {_without_depth(scene)}")
    return source


def _without_depth(scene: Scene) -> str:
    """Which views lack depth, for an error message: 'no view has depth' or 'N of M views have no
    depth (first: NAME)'."""
    missing = [v.name for v in scene.views if not v.has_depth]
    if not scene.views or len(missing) == len(scene.views):
        return "no view has depth"
    return f"{len(missing)} of {len(scene.views)} views have no depth (first: {missing[0]})"


def depth_extent(cameras: Mapping[str, Camera], depths: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) corners of the world points of the depth maps (subsampled to ~4096 per view)."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for n, cam in cameras.items():
        d = depths[n]
        step = max(1, int(math.sqrt(d.size / 4096)))
        ds = d[::step, ::step]
        ys, xs = np.nonzero(np.isfinite(ds) & (ds > 0))
        if len(ys):
            rays = cam.rays_in_cam(xs * step + 0.5, ys * step + 0.5)
            if cam.model != PINHOLE:  # equirect depth is the distance along the (unit) ray
                rays = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
            p_cam = rays * ds[ys, xs][:, None]
            wfc = cam.world_from_cam
            w = p_cam @ wfc[:3, :3].T + wfc[:3, 3]
            lo, hi = np.minimum(lo, w.min(0)), np.maximum(hi, w.max(0))
    if not np.all(hi >= lo) or not (hi - lo).max() > 0:
        raise BadValueError("global mesh: empty bounds (no view has a valid depth pixel)")
    return lo, hi


def fusion_memory(cameras: Mapping[str, Camera], depths: Mapping[str, np.ndarray],
                  options: GlobalMeshOptions | None = None, extent: tuple | None = None) -> dict:
    """An upper estimate of the peak bytes of :func:`fuse_depth` with ``options``, before any
    voxel is allocated: {"total", "blocks", "voxel"}. ``blocks`` counts the 8^3-voxel blocks that
    the depth samples fall in (as fuse_depth unprojects them, equirect views by their ray
    distance), each costing FUSION_BLOCK_BYTES (measured, above); a sparse grid's memory follows
    the surface, not the volume, so it is the blocks, not the bounds' voxels, that are counted."""
    options = options or GlobalMeshOptions()
    lo, hi = extent if extent is not None else depth_extent(cameras, depths)
    lo = np.asarray(lo, np.float64)
    length = float((np.asarray(hi) - lo).max()) * (1 + 2 * options.trunc_voxels / options.resolution)
    block = 8 * length / options.resolution
    keys = []
    for n, cam in cameras.items():
        d = np.asarray(depths[n], np.float32)
        ok = np.isfinite(d) & (d > 0)
        if not ok.any():
            continue
        ys, xs = np.nonzero(ok)
        rays = cam.rays_in_cam(xs + 0.5, ys + 0.5)
        if cam.model != PINHOLE:
            rays = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
        w = (rays * d[ys, xs][:, None]) @ cam.world_from_cam[:3, :3].T + cam.world_from_cam[:3, 3]
        # +1 and the clip: points a little outside the (subsampled) extent stay in the key's 21 bits
        b = np.clip(np.floor((w - lo) / block).astype(np.int64) + 1, 0, (1 << 21) - 1)
        keys.append(np.unique((b[:, 0] << 42) | (b[:, 1] << 21) | b[:, 2]))
    blocks = int(np.unique(np.concatenate(keys)).size) if keys else 0
    return {"total": blocks * FUSION_BLOCK_BYTES + FUSION_BASE_BYTES, "blocks": blocks,
            "voxel": length / options.resolution}


def fuse_depth(cameras: Mapping[str, Camera], depths: Mapping[str, np.ndarray],
               options: GlobalMeshOptions | None = None, extent: tuple | None = None) -> Mesh:
    """TSDF fusion (open3d's sparse ``VoxelBlockGrid``) of the depth maps, then marching cubes.
    Pinhole z-depth is integrated as it is; an equirect view is first resampled into the 6 faces
    of a cube map (:func:`equirect_to_cube_faces`). Unknown depth (0) and infinity (sky) are left
    out. The voxel is the largest extent of the depth points plus the truncation margin, /
    ``resolution``; only the blocks of 8^3 voxels within the truncation distance of a depth
    sample are stored. The mesh's vertices and faces are put in a canonical order (open3d
    extracts them in thread order)."""
    import open3d as o3d
    import open3d.core as o3c

    options = options or GlobalMeshOptions()
    pin: dict[str, Camera] = {}
    pin_depth: dict[str, np.ndarray] = {}
    for n, c in cameras.items():
        if c.model == PINHOLE:
            pin[n], pin_depth[n] = c, depths[n]
        else:
            for k, (fc, fd) in enumerate(equirect_to_cube_faces(c, depths[n])):
                pin[f"{n}#face{k}"], pin_depth[f"{n}#face{k}"] = fc, fd
    depths = pin_depth
    lo, hi = extent if extent is not None else depth_extent(pin, depths)
    trunc_margin = 2 * options.trunc_voxels / options.resolution
    length = float((hi - lo).max()) * (1 + trunc_margin)
    voxel = length / options.resolution
    # The voxel samples sit where those of a cube of side `length` around the depth points'
    # centre would have theirs at cell centres (the dense volume this replaced): the points'
    # bounding planes then lie ~0.4 voxel from a sample. Where such a plane (lego's base plate)
    # falls on samples, its TSDF is ~0 there and marching cubes frays its outline: ULR on a lego
    # fold lost 0.4 dB at the silhouettes (docs/preprocess.md). open3d works in float32, so the
    # grid lives in a frame whose origin is the first sample (world = local + base): coordinates
    # stay small whatever the scene's world origin.
    base = ((lo + hi) / 2 - length / 2 + voxel / 2).astype(np.float64)
    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight"), attr_dtypes=(o3c.float32, o3c.float32), attr_channels=((1), (1)),
        voxel_size=voxel, block_resolution=8, block_count=4096, device=o3c.Device("CPU:0"))
    for n, cam in pin.items():
        d = np.asarray(depths[n], np.float32)
        d = np.ascontiguousarray(np.where(np.isfinite(d) & (d > 0), d, 0), np.float32)
        if not d.any():
            continue
        # open3d reads the depth pixel int(u) for a projection u: pixel centres at +0.5, as ours.
        intr = o3c.Tensor(np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]], np.float64))
        cfw = np.array(cam.cam_from_world, np.float64)
        cfw[:3, 3] += cfw[:3, :3] @ base
        extr = o3c.Tensor(np.ascontiguousarray(cfw))
        img = o3d.t.geometry.Image(o3c.Tensor(d))
        kw = dict(depth_scale=1.0, depth_max=float(d.max()) + 1.0, trunc_voxel_multiplier=float(options.trunc_voxels))
        # The blocks around every depth sample (open3d's own activation from a depth map reads
        # every 4th pixel of every 4th row, and a structure thinner than that would be lost).
        points = (cam.unproject(d)[d > 0] - base).astype(np.float32)
        blocks = grid.compute_unique_block_coordinates(o3d.t.geometry.PointCloud(o3c.Tensor(points)),
                                                       trunc_voxel_multiplier=float(options.trunc_voxels))
        grid.integrate(blocks, img, intr, extr, **kw)
    no_surface = BadValueError("global mesh: TSDF fusion produced no surface (depth maps disagree or are empty)")
    if grid.hashmap().size() == 0:
        raise no_surface
    try:
        m = grid.extract_triangle_mesh(weight_threshold=0.0)
    except RuntimeError as e:  # open3d 0.20 fails to attach the (absent) vertex colours of an empty mesh
        if "shape {0}" in str(e):
            raise no_surface from None
        raise
    f = m.triangle.indices.numpy().astype(np.int32) if "indices" in m.triangle else np.zeros((0, 3), np.int32)
    if len(f) == 0:
        raise no_surface
    local = m.vertex.positions.numpy()
    v = (local.astype(np.float64) + base).astype(np.float32)
    # Canonical order: vertices sorted by their float32 position (ties, where float32 world
    # coordinates are too coarse to tell them apart, by the grid-frame position), each face rotated
    # to start at its smallest index (the winding kept), faces sorted.
    order = np.lexsort((local[:, 2], local[:, 1], local[:, 0], v[:, 2], v[:, 1], v[:, 0]))
    rank = np.empty(len(order), np.int32)
    rank[order] = np.arange(len(order), dtype=np.int32)
    f = rank[f]
    rot = np.argmin(f, axis=1)
    f = np.take_along_axis(f, (rot[:, None] + np.arange(3)) % 3, axis=1)
    f = f[np.lexsort((f[:, 2], f[:, 1], f[:, 0]))]
    # Marching cubes gives triangles whose normals point outwards of the TSDF's negative side, i.e.
    # towards the cameras, counter-clockwise seen from the front, as mesh.py wants.
    return Mesh(v[order], np.ascontiguousarray(f), kind="reconstructed")


_CUBE_DIRS = (((0, 0, 1), (0, -1, 0)), ((0, 0, -1), (0, -1, 0)), ((1, 0, 0), (0, -1, 0)),
              ((-1, 0, 0), (0, -1, 0)), ((0, 1, 0), (0, 0, 1)), ((0, -1, 0), (0, 0, -1)))


def equirect_to_cube_faces(camera: Camera, depth: np.ndarray) -> list[tuple[Camera, np.ndarray]]:
    """Six 90-degree pinhole cameras at an equirect camera's centre (cube-map faces, side =
    width / 4 clamped to [16, 2048]) and their z-depth, read from the equirect ray distance at
    the nearest pixel (no interpolation across depth edges); 0 outside the equirect's ranges."""
    side = int(min(2048, max(16, camera.width // 4)))
    f = side / 2.0
    x, y = np.meshgrid(np.arange(side) + 0.5, np.arange(side) + 0.5)
    d_face = np.stack([(x - f) / f, (y - f) / f, np.ones_like(x)], -1)  # z = 1 rays in the face
    norm = np.linalg.norm(d_face, axis=-1)
    out = []
    for fwd, up in _CUBE_DIRS:
        face_from_cam = look_at((0.0, 0.0, 0.0), fwd, up)[:3, :3]
        d_cam = d_face @ face_from_cam  # rays in the equirect camera's frame (R^T d)
        lon = np.arctan2(d_cam[..., 0], d_cam[..., 2])
        lat = np.arcsin(np.clip(-d_cam[..., 1] / norm, -1, 1))
        lo0, lo1 = camera.lon_range
        la0, la1 = camera.lat_range
        px = np.floor((lon - lo0) / (lo1 - lo0) * camera.width).astype(np.int64)
        py = np.floor((la1 - lat) / (la1 - la0) * camera.height).astype(np.int64)
        inside = (px >= 0) & (px < camera.width) & (py >= 0) & (py < camera.height)
        r = np.zeros((side, side), np.float32)
        r[inside] = depth[py[inside], px[inside]]
        z = np.where(np.isfinite(r) & (r > 0), r / norm, 0).astype(np.float32)
        pose = np.eye(4)
        pose[:3, :3] = face_from_cam
        cam_from_world = pose @ camera.cam_from_world
        out.append((Camera.pinhole(side, side, f, f, f, f, cam_from_world), z))
    return out


def densify(mesh: Mesh, max_edge: float, max_faces: int = 4_000_000) -> Mesh:
    """Split every triangle with an edge longer than ``max_edge`` into 4 (midpoints), repeatedly,
    until no edge is longer or the next round would pass ``max_faces``. Vertex colours, UVs and
    textures are dropped (colour comes from the views); object ids are kept."""
    if not max_edge > 0:
        raise BadValueError(f"max_edge: expected > 0, got {max_edge}")
    v = mesh.vertices.astype(np.float32)
    f = mesh.faces.copy()
    obj = mesh.object_ids.copy()
    while True:
        e = np.stack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], 1)  # (M, 3, 2)
        length = np.linalg.norm(v[e[..., 0]] - v[e[..., 1]], axis=-1)
        split = (length > max_edge).any(1)
        n_split = int(split.sum())
        if n_split == 0 or len(f) + 3 * n_split > max_faces:
            break
        # Split every edge of a split face (then its neighbours share the midpoints: no T-junction
        # within the split set; a kept face next to a split one keeps a T-junction, which does not
        # matter for per-vertex colour).
        es = np.sort(e[split].reshape(-1, 2), 1)
        key = es[:, 0].astype(np.int64) * len(v) + es[:, 1]
        uk, inv = np.unique(key, return_inverse=True)
        a, b = uk // len(v), uk % len(v)
        mids = ((v[a] + v[b]) * 0.5).astype(np.float32)
        mid_id = (len(v) + inv).reshape(-1, 3).astype(np.int32)  # midpoints of (01, 12, 20)
        v = np.concatenate([v, mids])
        fs = f[split]
        m01, m12, m20 = mid_id[:, 0], mid_id[:, 1], mid_id[:, 2]
        new = np.concatenate([np.stack([fs[:, 0], m01, m20], 1), np.stack([m01, fs[:, 1], m12], 1),
                              np.stack([m20, m12, fs[:, 2]], 1), np.stack([m01, m12, m20], 1)])
        f = np.concatenate([f[~split], new]).astype(np.int32)
        obj = np.concatenate([obj[~split], np.tile(obj[split], 4)])
    return Mesh(v, f, object_ids=obj, materials=mesh.materials, kind=mesh.kind)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (float32 (N, 3); 0 for isolated vertices)."""
    v = vertices.astype(np.float64)
    fn = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        for a in range(3):
            n[:, a] += np.bincount(faces[:, k], weights=fn[:, a], minlength=len(v))
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return (n / np.where(norm > 0, norm, 1)).astype(np.float32)


def smooth_normals(normals: np.ndarray, faces: np.ndarray, rounds: int) -> np.ndarray:
    """``rounds`` rounds of 1-ring averaging of unit vertex normals (N, 3): each round replaces a
    vertex's normal by the normalised sum of its own and its edge neighbours' (each neighbour
    once, however many faces share the edge). Vertices in no face, and zero sums, keep their
    normal. float32 (N, 3)."""
    import scipy.sparse as sp

    rounds = check_int(rounds, "rounds", 0)
    n = np.asarray(normals, np.float64)
    if n.ndim != 2 or n.shape[1] != 3:
        raise ShapeError(f"normals: expected shape (N, 3), got {n.shape}")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ShapeError(f"faces: expected shape (M, 3), got {f.shape}")
    if len(f) and (f.min() < 0 or f.max() >= len(n)):
        raise BadValueError(f"faces: vertex index outside 0..{len(n) - 1}")
    if rounds == 0 or len(f) == 0:
        return n.astype(np.float32)
    nv = len(n)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]]).astype(np.int64)
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]]).astype(np.int64)
    adj = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(nv, nv))
    adj.data[:] = 1.0  # duplicates summed by the constructor: each neighbour once
    adj = (adj + sp.identity(nv, format="csr")).tocsr()
    for _ in range(rounds):
        s = adj @ n
        norm = np.linalg.norm(s, axis=1, keepdims=True)
        n = np.where(norm > 1e-12, s / np.where(norm > 1e-12, norm, 1.0), n)
    return n.astype(np.float32)


def vertex_colors(mesh: Mesh, cameras: Mapping[str, Camera], colors: Mapping[str, np.ndarray],
                  depths: Mapping[str, np.ndarray], options: GlobalMeshOptions | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """ULR-weighted blend of the views' colours at each vertex: (colors (N, 3) f32, seen (N,) int32
    = number of views that see the vertex). Vertices no view sees get colour 0."""
    return point_colors(mesh.vertices, vertex_normals(mesh.vertices, mesh.faces), cameras, colors, depths, options)


def point_colors(points: np.ndarray, normals: np.ndarray, cameras: Mapping[str, Camera],
                 colors: Mapping[str, np.ndarray], depths: Mapping[str, np.ndarray],
                 options: GlobalMeshOptions | None = None) -> tuple[np.ndarray, np.ndarray]:
    """ULR-weighted blend of the views' colours at surface points with unit normals (both (N, 3)):
    (colors (N, 3) f32, seen (N,) int32). The per-vertex texture (:func:`vertex_colors`) and the
    texture atlas (:mod:`ibrtools.hybrid.atlas`, per texel) share it. Points no view sees get 0.

    Per point and view: visible when it projects inside the image, in front, within
    ``depth_tol`` of the view's depth at its pixel and seen from the front (angle between the
    normal and the direction to the camera < 90 degrees - 1e-3 rad); penalty = that angle + 0.5
    max(0, distance / nearest such view's distance - 1) (Buehler et al.'s resolution term); the
    views below the (k+1)-th smallest penalty are blended with weights max(1e-3, 1 - p / p_(k+1))
    (a point seen by one view keeps its colour) of their bilinear colour. The kernel is
    ``_core.point_colors`` (cpp/kernels/hybrid/atlas8.h; the numpy version it replaced, kept as the
    reference in tests/hybrid/test_globalmesh.py, gives the same bits)."""
    from ibrtools import _core

    options = options or GlobalMeshOptions()
    names = list(cameras)
    if not names:
        raise BadValueError("vertex colours: no views")
    v = np.ascontiguousarray(points, np.float64)
    nrm = np.ascontiguousarray(normals, np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or nrm.shape != v.shape:
        raise ShapeError(f"points, normals: expected two (N, 3) arrays, got {v.shape} and {nrm.shape}")
    views = []
    for n in names:
        cam = cameras[n]
        col = np.ascontiguousarray(colors[n], np.float32)
        dep = np.ascontiguousarray(depths[n], np.float32)
        if col.shape != (cam.height, cam.width, 3) or dep.shape != (cam.height, cam.width):
            raise ShapeError(f"view {n!r}: expected colour ({cam.height}, {cam.width}, 3) and depth "
                             f"({cam.height}, {cam.width}), got {col.shape} and {dep.shape}")
        views.append((cam.to_core(), col, dep))
    col, seen = _core.point_colors(v, nrm, views, k=int(options.k_views), depth_tol=float(options.depth_tol))
    return col, seen


def depth_from_mesh(mesh: Mesh, cameras: Mapping[str, Camera]) -> dict[str, np.ndarray]:
    """Each camera's depth rendered from ``mesh`` (z for pinhole, ray distance for equirect;
    0 where no surface), one BVH for all."""
    from ibrtools.raycast.reference import ReferenceRenderer

    if not isinstance(mesh, Mesh):
        raise DtypeError(f"mesh: expected an ibrtools.Mesh, got {type(mesh).__name__}")
    rr = ReferenceRenderer(mesh)
    out = {}
    for n, cam in cameras.items():
        d = np.asarray(rr.render(cam, outputs="depth")["depth"], np.float32)
        out[n] = np.ascontiguousarray(np.where(np.isfinite(d) & (d > 0), d, 0).astype(np.float32))
    return out


def mesh_scale(mesh: Mesh) -> float:
    ext = mesh.bounds()[1] - mesh.bounds()[0]
    return float(ext.max())


def build_global_mesh(scene: Scene, options: GlobalMeshOptions | None = None,
                      depths: Mapping[str, np.ndarray] | None = None) -> tuple[Mesh, dict]:
    """The untextured global mesh and a record {source, vertices, faces, voxel}. The render mesh
    (:func:`build_render_mesh`) is the same surface, less densified."""
    options = options or GlobalMeshOptions()
    src = choose_source(scene, options.source)
    stored = 0
    if src == "fusion":
        cams = {v.name: v.camera for v in scene.views}
        stored = 0 if depths else sum(v.has_depth_stored for v in scene.views)
        deps = depths or {v.name: v.fusion_depth for v in scene.views}
        lo, hi = depth_extent(cams, deps)
        check_fusion_memory(cams, deps, options, extent=(lo, hi))
        mesh = fuse_depth(cams, deps, options, extent=(lo, hi))
        voxel = float((hi - lo).max() / options.resolution)  # (up to the truncation margin)
    else:
        given = scene.meshes[src]
        if len(given.faces) == 0 or not mesh_scale(given) > 0:
            raise BadValueError(f"global mesh: the {src!r} mesh is degenerate (zero extent)")
        voxel = mesh_scale(given) / options.resolution
        mesh = densify(given, options.max_edge_voxels * voxel, options.max_faces)
    return mesh, {"source": src, "vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces)),
                  "voxel": float(f"{voxel:.4g}"), **({"views_depth_as_stored": stored} if stored else {})}


def check_fusion_memory(cameras: Mapping[str, Camera], depths: Mapping[str, np.ndarray],
                        options: GlobalMeshOptions | None = None, extent: tuple | None = None) -> dict:
    """Refuse, before the TSDF grid is allocated, a fusion whose estimate (:func:`fusion_memory`)
    exceeds the available memory (ibrtools.memory.available_memory: $IBR_MEMORY_LIMIT, else the free
    memory): open3d does not fail cleanly when it runs out (it crashed at ~10 GB, resolution
    20000, on a scene of 6 views of 320x240)."""
    import os

    options = options or GlobalMeshOptions()
    est = fusion_memory(cameras, depths, options, extent)
    avail = available_memory()
    if est["total"] > avail:
        gib = 1 << 30
        raise BadValueError.about(
            "stage_options",
            f"TSDF fusion needs about {est['total'] / gib:.1f} GiB "
            f"({est['blocks']} blocks of 8^3 voxels of {est['voxel']:.3g}), only {avail / gib:.1f} GiB is "
            f"available{' (IBR_MEMORY_LIMIT)' if os.environ.get('IBR_MEMORY_LIMIT') else ''}: "
            "use a lower mesh.resolution, or free memory", f"mesh.resolution={options.resolution}")
    return est


def build_render_mesh(scene: Scene, dense: Mesh, source: str, options: GlobalMeshOptions | None = None) -> Mesh:
    """The render mesh (``GlobalMeshOptions.render_edge_voxels``): the given mesh (``source``
    reconstructed / ground_truth) densified to edges <= render_edge_voxels voxels; a fused mesh
    (``source`` fusion) is ``dense`` itself. At most as many faces as ``dense``."""
    options = options or GlobalMeshOptions()
    if source == "fusion" or options.render_edge_voxels <= options.max_edge_voxels:
        return dense
    given = scene.meshes[source]
    voxel = mesh_scale(given) / options.resolution
    return densify(given, options.render_edge_voxels * voxel, options.max_faces)
