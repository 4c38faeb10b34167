"""Deterministic synthetic scenes with exact ground truth (docs/synth.md).

A preset builds a textured, partly glossy triangle mesh (metres, world **y up**, ground plane
y = 0), cameras (OpenCV axes, ``look_at``), held-out target cameras and named camera paths;
:func:`make_scene` renders every input view and every target with the reference ray caster
(``ibrtools.raycast.reference``): colour (linear RGB) and z-depth. Same arguments and seed ->
identical arrays.

Building blocks, all vectorised numpy (no per-triangle Python loops):

* geometry: :func:`boxes` (N boxes at once), :func:`uv_sphere`, :func:`torus`, :func:`cylinder`,
  :func:`ground_grid`, :func:`load_placed` (any OBJ/PLY, scaled and placed), :func:`merge`;
* textures: :func:`procedural_texture` (checkers + value-noise octaves + stripes, seeded);
* camera rigs: :func:`ring`, :func:`forward_grid`, :func:`random_sphere`, :func:`smooth_path`
  (Catmull-Rom through keyframes), :func:`orbit`;
* motion: :func:`path_motion` (the per-frame maximal image motion of a camera path, the measure
  of Lee, Kim, Eisemann 2018 sec. 4.1); the ``walk`` paths (15-35 px/frame at 1920x1080) and
  ``stress`` paths (100+ px/frame) of the crowd, city and spheres presets.
"""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ibrtools.camera import Camera, look_at
from ibrtools.checks import check_float, check_int
from ibrtools.errors import BadValueError, DtypeError, MissingFileError
from ibrtools.mesh import Mesh
from ibrtools.scene import Scene, View
from ibrtools.memory import available_memory
from ibrtools.meshio import read_mesh

PRESETS: dict[str, str] = {
    "objects": "textured and glossy boxes, spheres and a cylinder on a ground plane; ring of cameras",
    "crowd": "thousands of small textured boxes (distinct object ids) on a ground plane, for culling; ring of cameras",
    "city": "blocks of buildings along streets on a ground plane; street-level forward-facing camera grid",
    "spheres": "high-polygon scene (1.2 M triangles): dense meshed tori and spheres on a ground plane; ring of cameras",
}

UP = np.array([0.0, 1.0, 0.0])
# Independent random streams per purpose: changing e.g. the jitter never changes the geometry.
_STREAM = {"geometry": 1, "textures": 2, "cameras": 3, "jitter": 4, "depth_noise": 5, "reconstructed": 6,
           "motion": 7}


def _rng(seed: int, stream: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), _STREAM[stream]])


# ============================================================================================
# Geometry
# ============================================================================================
@dataclass
class Part:
    """A piece of a mesh before merging: float64 vertices, faces local to the part, per-face
    corner UVs (OBJ convention), texture id and object id per face, optional vertex colours."""

    vertices: np.ndarray      # (n, 3) float64
    faces: np.ndarray         # (m, 3) int64
    uvs: np.ndarray           # (m, 3, 2) float64
    texture_ids: np.ndarray   # (m,) int64, -1 = untextured
    object_ids: np.ndarray    # (m,) int64
    vertex_colors: np.ndarray | None = None


def _rot_y(yaw: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations about +y by yaw (radians)."""
    c, s = np.cos(yaw), np.sin(yaw)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


# Unit cube [-0.5, 0.5]^3: 6 faces x 4 corners (own vertices per face so each face has its
# own UV square), two counter-clockwise triangles per face seen from outside.
def _cube_template() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    verts, faces, uvs = [], [], []
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u = np.zeros(3)
            u[(axis + 1) % 3] = 1.0
            v = np.cross(n, u)  # (u, v, n) right-handed => corners CCW seen from outside
            corners = [0.5 * n + (a - 0.5) * u + (b - 0.5) * v for a, b in square]
            base = len(verts)
            verts += corners
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
            uvs += [square[[0, 1, 2]], square[[0, 2, 3]]]
    return np.array(verts), np.array(faces), np.array(uvs)


_CUBE_V, _CUBE_F, _CUBE_UV = _cube_template()


def boxes(centers: Any, sizes: Any, yaws: Any = 0.0, texture_ids: Any = 0, object_ids: Any = 0) -> Part:
    """N boxes at once: ``centers`` (N, 3), ``sizes`` (N, 3) full extents, ``yaws`` (N,)
    rotations about +y in radians; texture and object ids per box (scalars broadcast)."""
    centers = np.atleast_2d(np.asarray(centers, float))
    n = len(centers)
    sizes = np.broadcast_to(np.asarray(sizes, float), (n, 3))
    yaws = np.broadcast_to(np.asarray(yaws, float), (n,))
    local = _CUBE_V[None] * sizes[:, None, :]                                   # (N, 24, 3)
    verts = np.einsum("nij,nkj->nki", _rot_y(yaws), local) + centers[:, None, :]
    faces = _CUBE_F[None] + 24 * np.arange(n)[:, None, None]
    per_face = lambda ids: np.repeat(np.broadcast_to(np.asarray(ids, np.int64), (n,)), 12)  # noqa: E731
    return Part(verts.reshape(-1, 3), faces.reshape(-1, 3), np.tile(_CUBE_UV, (n, 1, 1)),
                per_face(texture_ids), per_face(object_ids))


def _grid_faces(rows: int, cols: int) -> np.ndarray:
    """Two CCW triangles per cell of a (rows+1) x (cols+1) vertex grid, row-major."""
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    i00 = (r * (cols + 1) + c).ravel()
    i01, i10 = i00 + 1, i00 + cols + 1
    i11 = i10 + 1
    return np.concatenate([np.stack([i00, i10, i11], -1), np.stack([i00, i11, i01], -1)])


def _corner_uvs(faces: np.ndarray, vertex_uv: np.ndarray) -> np.ndarray:
    return vertex_uv[faces]


def uv_sphere(center: Any, radius: float, n_lon: int = 48, n_lat: int = 24, texture_id: int = 0,
              object_id: int = 0) -> Part:
    """A UV sphere; u follows longitude (seam duplicated), v latitude (1 at the north pole)."""
    lat = np.linspace(math.pi / 2, -math.pi / 2, n_lat + 1)
    lon = np.linspace(0.0, 2 * math.pi, n_lon + 1)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    # Rows go north to south, columns east-ward: CCW from outside with _grid_faces' winding
    # requires the longitude to grow clockwise seen from above, hence -sin.
    dirs = np.stack([np.cos(la) * np.cos(lo), np.sin(la), -np.cos(la) * np.sin(lo)], -1).reshape(-1, 3)
    verts = np.asarray(center, float) + radius * dirs
    faces = _grid_faces(n_lat, n_lon)
    # Drop the degenerate triangles at the poles (two corners on the pole vertex row).
    p = verts[faces]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    faces = faces[area > 1e-12 * radius * radius]
    vuv = np.stack([(lo / (2 * math.pi)).ravel(), ((la + math.pi / 2) / math.pi).ravel()], -1)
    m = len(faces)
    return Part(verts, faces, _corner_uvs(faces, vuv), np.full(m, texture_id), np.full(m, object_id))


def torus(center: Any, major: float, minor: float, n_u: int = 64, n_v: int = 32, tilt: float = 0.0,
          texture_id: int = 0, object_id: int = 0) -> Part:
    """A torus of radii ``major`` (ring) and ``minor`` (tube) around the +y axis, tilted by
    ``tilt`` radians about +x; u follows the ring, v the tube (seams duplicated)."""
    u = np.linspace(0.0, 2 * math.pi, n_u + 1)
    v = np.linspace(0.0, 2 * math.pi, n_v + 1)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    ring = major + minor * np.cos(vv)
    # Rows follow u, columns v: outward normals with _grid_faces' winding need -sin(u) in z.
    pts = np.stack([ring * np.cos(uu), minor * np.sin(vv), -ring * np.sin(uu)], -1).reshape(-1, 3)
    c, s = math.cos(tilt), math.sin(tilt)
    pts = pts @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T
    verts = np.asarray(center, float) + pts
    faces = _grid_faces(n_u, n_v)
    vuv = np.stack([(uu / (2 * math.pi)).ravel(), (vv / (2 * math.pi)).ravel()], -1)
    m = len(faces)
    return Part(verts, faces, _corner_uvs(faces, vuv), np.full(m, texture_id), np.full(m, object_id))


def cylinder(base_center: Any, radius: float, height: float, n: int = 48, texture_id: int = 0,
             object_id: int = 0) -> Part:
    """A closed vertical cylinder standing on ``base_center``: side (u = angle, v = height)
    and two caps (planar UVs)."""
    b = np.asarray(base_center, float)
    ang = np.linspace(0.0, 2 * math.pi, n + 1)
    ring = np.stack([np.cos(ang), np.zeros_like(ang), -np.sin(ang)], -1) * radius
    top, bottom = ring + b + [0, height, 0], ring + b
    side_v = np.concatenate([top, bottom])                   # grid rows: top, bottom
    side_f = _grid_faces(1, n)
    side_uv = np.stack([np.tile(ang / (2 * math.pi), 2), np.repeat([1.0, 0.0], n + 1)], -1)
    # Caps: a centre vertex and the ring, fans CCW seen from outside.
    k = np.arange(n)
    cap_uv_ring = np.stack([0.5 + 0.5 * np.cos(ang), 0.5 - 0.5 * np.sin(ang)], -1)
    top_v = np.concatenate([[b + [0, height, 0]], top])
    top_f = np.stack([np.zeros(n, int), 1 + k, 2 + k], -1)
    bot_v = np.concatenate([[b], bottom])
    bot_f = np.stack([np.zeros(n, int), 2 + k, 1 + k], -1)
    cap_uv = np.concatenate([[[0.5, 0.5]], cap_uv_ring])
    verts = np.concatenate([side_v, top_v, bot_v])
    o1, o2 = len(side_v), len(side_v) + len(top_v)
    faces = np.concatenate([side_f, top_f + o1, bot_f + o2])
    uvs = np.concatenate([side_uv[side_f], cap_uv[top_f], cap_uv[bot_f]])
    m = len(faces)
    return Part(verts, faces, uvs, np.full(m, texture_id), np.full(m, object_id))


def ground_grid(size: float, cells: int = 8, y: float = 0.0, center: Any = (0.0, 0.0),
                texture_id: int = 0, object_id: int = 0) -> Part:
    """A square ground plane of side ``size`` at height y, facing +y, split into cells x cells
    quads; the texture is mapped once over the whole plane."""
    t = np.linspace(-0.5, 0.5, cells + 1) * size
    zz, xx = np.meshgrid(t, t, indexing="ij")
    # Rows along +z, columns along +x: _grid_faces' order is counter-clockwise seen from +y.
    verts = np.stack([xx + center[0], np.full_like(xx, y), zz + center[1]], -1).reshape(-1, 3)
    faces = _grid_faces(cells, cells)
    vuv = np.stack([(xx / size + 0.5).ravel(), (0.5 - zz / size).ravel()], -1)
    m = len(faces)
    return Part(verts, faces, vuv[faces], np.full(m, texture_id), np.full(m, object_id))


def load_placed(path: str | Path, *, center: Any, extent: float, object_id: int,
                texture_offset: int = 0) -> tuple[Part, list[np.ndarray]]:
    """Read an OBJ/PLY with ``ibrtools.meshio.read_mesh``, scale it uniformly so its largest
    bounding-box side is ``extent`` metres, and stand it on the ground (min y = 0) centred at
    ``center`` (x, z). Returns the part and its textures."""
    p = Path(path)
    if not p.is_file():
        raise MissingFileError(f"extra mesh {p}: no such file")
    m = read_mesh(p)
    v = m.vertices.astype(np.float64)
    lo, hi = v.min(0), v.max(0)
    scale = extent / max(float((hi - lo).max()), 1e-12)
    v = (v - [(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2]) * scale + [center[0], 0.0, center[1]]
    nf = len(m.faces)
    if m.uvs is not None and m.textures:
        tids = (m.texture_ids if m.texture_ids is not None else np.zeros(nf, np.int64)).astype(np.int64)
        tids = np.where(tids >= 0, tids + texture_offset, -1)
        uvs = m.uvs.astype(np.float64)
        textures = list(m.textures)
    else:
        tids, uvs, textures = np.full(nf, -1), np.zeros((nf, 3, 2)), []
    vc = None if m.vertex_colors is None else m.vertex_colors.astype(np.float64)
    if vc is None and not textures:
        vc = np.full((len(v), 3), 0.6)  # a plain grey: the file has neither colours nor texture
    return Part(v, m.faces.astype(np.int64), uvs, tids, np.full(nf, object_id), vc), textures


def merge(parts: Sequence[Part], textures: list[np.ndarray], materials: np.ndarray | None,
          kind: str = "ground_truth") -> Mesh:
    """One :class:`Mesh` from parts (vertex indices offset; vertex colours only when a part
    has them, textured parts then get white, i.e. neutral, vertex colours)."""
    offs = np.cumsum([0] + [len(p.vertices) for p in parts])
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offs)])
    any_vc = any(p.vertex_colors is not None for p in parts)
    vc = (np.concatenate([p.vertex_colors if p.vertex_colors is not None else np.ones((len(p.vertices), 3))
                          for p in parts]) if any_vc else None)
    tids = np.concatenate([p.texture_ids for p in parts])
    return Mesh(vertices=np.concatenate([p.vertices for p in parts]), faces=faces, vertex_colors=vc,
                uvs=np.concatenate([p.uvs for p in parts]), textures=textures,
                texture_ids=tids if textures else None,
                object_ids=np.concatenate([p.object_ids for p in parts]), materials=materials, kind=kind)


# ============================================================================================
# Textures
# ============================================================================================
def _smooth_upsample(lattice: np.ndarray, size: int) -> np.ndarray:
    """Value noise: a lattice of random values interpolated with smoothstep weights (periodic)."""
    c = lattice.shape[0]
    t = (np.arange(size) + 0.5) / size * c
    i0 = np.floor(t).astype(int) % c
    f = t - np.floor(t)
    w = f * f * (3 - 2 * f)
    i1 = (i0 + 1) % c
    rows = lattice[i0] * (1 - w)[:, None] + lattice[i1] * w[:, None]
    return rows[:, i0] * (1 - w)[None, :] + rows[:, i1] * w[None, :]


def value_noise(rng: np.random.Generator, size: int, base_cells: int = 4, octaves: int = 5) -> np.ndarray:
    """Fractal value noise in [0, 1], (size, size): octaves of doubling frequency, halving amplitude."""
    acc = np.zeros((size, size))
    total = 0.0
    for o in range(octaves):
        cells = min(base_cells * 2 ** o, size)
        amp = 0.5 ** o
        acc += amp * _smooth_upsample(rng.random((cells, cells)), size)
        total += amp
    return acc / total


def procedural_texture(rng: np.random.Generator, size: int, style: str = "mixed") -> np.ndarray:
    """A high-frequency linear-RGB texture (size, size, 3) in [0.02, 0.9]: checkers of a random
    period, fractal value noise and oriented stripes, tinted by two random colours.
    ``style``: "mixed" (objects), "ground" (fine noise and tiles), "facade" (window grid)."""
    y, x = (np.mgrid[0:size, 0:size] + 0.5) / size
    col_a, col_b = rng.uniform(0.05, 0.85, 3), rng.uniform(0.05, 0.85, 3)
    noise = value_noise(rng, size, base_cells=int(rng.integers(3, 8)))
    if style == "facade":
        nx, ny = int(rng.integers(3, 7)), int(rng.integers(4, 10))
        fx, fy = (x * nx) % 1.0, (y * ny) % 1.0
        window = ((fx > 0.2) & (fx < 0.8) & (fy > 0.25) & (fy < 0.75)).astype(float)
        pattern = 0.75 * (1 - window) * (0.6 + 0.4 * noise) + window * (0.15 + 0.3 * noise)
    else:
        n_check = int(rng.integers(4, 17)) if style == "mixed" else int(rng.integers(24, 48))
        checker = ((np.floor(x * n_check) + np.floor(y * n_check)) % 2)
        ang = rng.uniform(0, math.pi)
        freq = rng.uniform(8, 40)
        stripes = 0.5 + 0.5 * np.sin(2 * math.pi * freq * (x * math.cos(ang) + y * math.sin(ang)))
        pattern = 0.45 * checker + 0.35 * noise + 0.2 * stripes
    mix = pattern[..., None]
    tex = col_a * (1 - mix) + col_b * mix
    tex *= (0.75 + 0.5 * noise)[..., None]  # fine luminance detail everywhere
    return np.clip(tex, 0.02, 0.9).astype(np.float32)


def _texture_size(size: tuple[int, int], factor: float) -> int:
    """Texture side as a power of two that follows the image size (so small test scenes stay
    cheap), within [32, 1024]."""
    s = int(2 ** round(math.log2(max(size) * factor)))
    return int(min(1024, max(32, s)))


# ============================================================================================
# Camera rigs
# ============================================================================================
def _cam(size: tuple[int, int], fov_x: float, eye: Any, target: Any) -> Camera:
    return Camera.from_fov(size[0], size[1], fov_x, look_at(eye, target, UP))


def ring(n: int, *, size: tuple[int, int], center: Any = (0, 0, 0), radius: float = 5.0,
         height: float = 2.0, look_at_point: Any = None, fov_x: float = 60.0,
         phase: float = 0.0) -> list[Camera]:
    """n cameras evenly spaced on a horizontal circle, looking in at ``look_at_point``."""
    c = np.asarray(center, float)
    target = c if look_at_point is None else np.asarray(look_at_point, float)
    a = phase + 2 * math.pi * np.arange(n) / n
    eyes = c + np.stack([radius * np.sin(a), np.full(n, height), -radius * np.cos(a)], -1)
    return [_cam(size, fov_x, e, target) for e in eyes]


def forward_grid(n: int, *, size: tuple[int, int], center: Any, direction: Any, spacing: float = 0.3,
                 fov_x: float = 65.0, focus: float = 20.0) -> list[Camera]:
    """LLFF-like: n cameras on a grid in the plane facing ``direction`` (cols >= rows), all
    looking the same way (at center + focus * direction); row-major, top row first."""
    d = np.asarray(direction, float)
    d /= np.linalg.norm(d)
    right = np.cross(d, UP)
    right /= np.linalg.norm(right)
    up = np.cross(right, d)
    cols = int(math.ceil(math.sqrt(n * 1.5)))
    rows = int(math.ceil(n / cols))
    idx = np.arange(n)
    gx = (idx % cols) - (cols - 1) / 2
    gy = (rows - 1) / 2 - (idx // cols)
    eyes = np.asarray(center, float) + spacing * (gx[:, None] * right + gy[:, None] * up)
    return [_cam(size, fov_x, e, e + focus * d) for e in eyes]


def random_sphere(n: int, *, size: tuple[int, int], seed: int, center: Any = (0, 0, 0),
                  radius: float = 5.0, min_elevation_deg: float = 5.0, fov_x: float = 60.0) -> list[Camera]:
    """n cameras at uniformly random directions on the upper part of a sphere (elevation
    above ``min_elevation_deg``), looking at the centre; seeded."""
    rng = _rng(seed, "cameras")
    c = np.asarray(center, float)
    zmin = math.sin(math.radians(min_elevation_deg))
    h = rng.uniform(zmin, 0.95, n)  # sin(elevation), uniform => uniform on the sphere cap
    a = rng.uniform(0, 2 * math.pi, n)
    r = np.sqrt(1 - h * h)
    eyes = c + radius * np.stack([r * np.sin(a), h, -r * np.cos(a)], -1)
    return [_cam(size, fov_x, e, c) for e in eyes]


def catmull_rom(points: Any, n: int, closed: bool = False) -> np.ndarray:
    """n points on a centripetal... uniform Catmull-Rom spline through ``points`` (K, 3),
    K >= 2, evenly spaced in the spline parameter; closed splines wrap around."""
    p = np.asarray(points, float)
    k = len(p)
    segs = k if closed else k - 1
    t = np.linspace(0, segs, n, endpoint=not closed)
    i = np.minimum(np.floor(t).astype(int), segs - 1)
    u = (t - i)[:, None]
    idx = lambda j: (j % k) if closed else np.clip(j, 0, k - 1)  # noqa: E731
    p0, p1, p2, p3 = p[idx(i - 1)], p[idx(i)], p[idx(i + 1)], p[idx(i + 2)]
    return 0.5 * (2 * p1 + (p2 - p0) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u ** 2
                  + (3 * p1 - p0 - 3 * p2 + p3) * u ** 3)


def smooth_path(eyes: Any, targets: Any, n: int, *, size: tuple[int, int], fov_x: float = 60.0,
                closed: bool = False) -> list[Camera]:
    """n cameras along Catmull-Rom splines through keyframe eye positions and look-at targets."""
    e = catmull_rom(eyes, n, closed)
    t = catmull_rom(targets, n, closed)
    return [_cam(size, fov_x, a, b) for a, b in zip(e, t)]


def orbit(n: int, *, size: tuple[int, int], center: Any, radius: float, height: float,
          look_at_point: Any, fov_x: float, turns: float = 1.0, bob: float = 0.0) -> list[Camera]:
    """n cameras on a (possibly bobbing) circle: the "orbit" path of ring presets."""
    c = np.asarray(center, float)
    a = 2 * math.pi * turns * np.arange(n) / n
    eyes = c + np.stack([radius * np.sin(a), height + bob * np.sin(2 * a), -radius * np.cos(a)], -1)
    return [_cam(size, fov_x, e, look_at_point) for e in eyes]


def walk_orbit(n: int, *, step_deg: float, size: tuple[int, int], center: Any, radius: float,
               height: float, look_at_point: Any, fov_x: float, bob: float = 0.0, bob_period: int = 40,
               phase_deg: float = 0.0) -> list[Camera]:
    """n cameras on a horizontal circle advancing a fixed ``step_deg`` per frame (so the
    per-frame motion does not depend on n), height bobbing by ``bob`` over ``bob_period`` frames."""
    c = np.asarray(center, float)
    a = np.radians(phase_deg + step_deg * np.arange(n))
    h = height + bob * np.sin(2 * math.pi * np.arange(n) / bob_period)
    eyes = c + np.stack([radius * np.sin(a), h, -radius * np.cos(a)], -1)
    return [_cam(size, fov_x, e, look_at_point) for e in eyes]


def walk_forward(n: int, *, step: float, size: tuple[int, int], start: Any, fov_x: float,
                 sway: float = 0.3, yaw_deg: float = 3.0, period: int = 40) -> list[Camera]:
    """n cameras walking along +z at ``step`` metres per frame from ``start``, swaying sideways
    by ``sway`` metres and turning by +-``yaw_deg`` over ``period`` frames."""
    t = np.arange(n)
    ph = 2 * math.pi * t / period
    eyes = np.asarray(start, float) + np.stack([sway * np.sin(ph), 0.05 * np.sin(2 * ph), step * t], -1)
    yaw = np.radians(yaw_deg) * np.sin(ph + 0.7)
    look = eyes + 20.0 * np.stack([np.sin(yaw), np.zeros(n), np.cos(yaw)], -1)
    return [_cam(size, fov_x, e, g) for e, g in zip(eyes, look)]


def path_motion(mesh: Mesh, cameras: Sequence[Camera], *, renderer=None) -> np.ndarray:
    """Per-frame maximal image motion (pixels) along a camera path: for t >= 1, the largest
    distance any surface point seen by frame t - 1 moves in the image between frames t - 1 and
    t (its reference depth unprojected from t - 1 and projected into t; points that land behind
    camera t are left out). Lee, Kim, Eisemann 2018 sec. 4.1 report the mean of these maxima."""
    from ibrtools.raycast.reference import ReferenceRenderer

    if len(cameras) < 2:
        raise BadValueError("cameras: a path needs at least 2 cameras to have motion")
    renderer = renderer or ReferenceRenderer(mesh)
    out = []
    for a, b in zip(cameras[:-1], cameras[1:]):
        depth = renderer.render(a, outputs=("depth",), lights=[])["depth"]
        ok = depth > 0
        if not ok.any():
            out.append(0.0)
            continue
        x, y = a.pixel_grid()
        xy, z = b.project(a.unproject(depth)[ok])
        good = np.isfinite(z) & (z > 0)
        d = np.hypot(xy[good, 0] - x[ok][good], xy[good, 1] - y[ok][good])
        out.append(float(d.max()) if d.size else 0.0)
    return np.asarray(out)


# ============================================================================================
# Presets
# ============================================================================================
@dataclass
class _Built:
    parts: list[Part]
    textures: list[np.ndarray]
    materials: np.ndarray
    views: list[Camera]
    targets: list[Camera]
    paths: dict[str, list[Camera]]
    thin_object: int | None          # removed from the "reconstructed" mesh
    free_spot: tuple[float, float]   # (x, z) where extra meshes go
    free_extent: float


def _between_ring(n_views: int, k: int) -> np.ndarray:
    """Angles (as fractions of a view step) of k targets half-way between ring inputs."""
    return (np.round(np.arange(k) * n_views / max(k, 1)).astype(int) % n_views) + 0.5


def _preset_objects(size, views, seed, k_targets, path_frames) -> _Built:
    rng = _rng(seed, "geometry")
    trng = _rng(seed, "textures")
    ts_obj, ts_ground = _texture_size(size, 0.5), _texture_size(size, 2.0)
    textures = [procedural_texture(trng, ts_ground, "ground")] + [procedural_texture(trng, ts_obj) for _ in range(6)]
    parts = [ground_grid(24.0, cells=8, texture_id=0, object_id=0)]
    # Objects on a ring of slots around the centre (jittered), so every camera sees several.
    slot = rng.permutation(6)
    ang = 2 * math.pi * (np.arange(6) + rng.uniform(-0.15, 0.15, 6)) / 6
    rad = rng.uniform(1.1, 1.7, 6)
    xz = np.stack([rad * np.sin(ang), -rad * np.cos(ang)], -1)
    oid = 1
    for j in range(3):  # boxes
        s = rng.uniform([0.4, 0.4, 0.4], [0.7, 1.2, 0.7])
        p = boxes([xz[slot[j], 0], s[1] / 2, xz[slot[j], 1]], s, rng.uniform(0, math.pi), 1 + j, oid)
        parts.append(p)
        oid += 1
    for j in range(2):  # spheres
        r = rng.uniform(0.3, 0.45)
        q = xz[slot[3 + j]]
        parts.append(uv_sphere([q[0], r, q[1]], r, 48, 24, texture_id=4 + j, object_id=oid))
        oid += 1
    q = xz[slot[5]]
    parts.append(cylinder([q[0], 0, q[1]], rng.uniform(0.25, 0.35), rng.uniform(0.8, 1.4), 48, 6, oid))
    oid += 1
    # A thin pole near the centre: the object a reconstruction loses.
    thin = oid
    parts.append(cylinder([0.15, 0, -0.1], 0.03, 1.6, 12, 3, thin))
    oid += 1
    # (specular, shininess) per object id: ground matte, boxes 1 and sphere 4 glossy.
    mats = np.zeros((oid, 2), np.float32)
    mats[:, 1] = 8.0
    mats[[2, 4], :] = [[0.6, 64.0], [0.8, 128.0]]
    mats[6] = [0.3, 32.0]
    fov = 55.0
    kw = dict(size=size, radius=4.5, height=2.0, look_at_point=(0, 0.45, 0), fov_x=fov)
    cams = ring(views, **kw)
    step = 2 * math.pi / views
    targets = [ring(1, phase=f * step, **kw)[0] for f in _between_ring(views, k_targets)]
    paths = {
        "orbit": orbit(path_frames, size=size, center=(0, 0, 0), radius=4.2, height=1.8,
                       look_at_point=(0, 0.5, 0), fov_x=fov, bob=0.3),
        "wander": smooth_path(
            [[4.0, 1.8, -3.0], [1.0, 1.6, -4.5], [-3.5, 2.2, -3.0], [-4.5, 1.5, 1.0], [-1.0, 2.5, 4.5]],
            [[0, 0.5, 0], [0.5, 0.6, 0], [0, 0.4, 0.5], [0, 0.5, 0], [0, 0.3, 0]],
            path_frames, size=size, fov_x=fov),
    }
    return _Built(parts, textures, mats, cams, targets, paths, thin, (0.0, 0.0), 0.6)


def _preset_crowd(size, views, seed, k_targets, path_frames, n_objects: int = 3000) -> _Built:
    rng = _rng(seed, "geometry")
    trng = _rng(seed, "textures")
    ts = _texture_size(size, 0.25)
    textures = [procedural_texture(trng, _texture_size(size, 2.0), "ground")] + \
        [procedural_texture(trng, ts) for _ in range(8)]
    r = 12.0 * np.sqrt(rng.random(n_objects))
    a = rng.uniform(0, 2 * math.pi, n_objects)
    sizes = rng.uniform([0.12, 0.1, 0.12], [0.45, 0.7, 0.45], (n_objects, 3))
    centers = np.stack([r * np.sin(a), sizes[:, 1] / 2, -r * np.cos(a)], -1)
    parts = [ground_grid(32.0, cells=16, texture_id=0, object_id=0),
             boxes(centers, sizes, rng.uniform(0, math.pi, n_objects), 1 + rng.integers(0, 8, n_objects),
                   1 + np.arange(n_objects))]
    mats = np.zeros((n_objects + 1, 2), np.float32)
    mats[:, 1] = 8.0
    glossy = 1 + np.flatnonzero(rng.random(n_objects) < 0.2)
    mats[glossy] = [0.5, 48.0]
    fov = 70.0
    kw = dict(size=size, radius=15.0, height=3.5, look_at_point=(0, 0, 0), fov_x=fov)
    cams = ring(views, **kw)
    step = 2 * math.pi / views
    targets = [ring(1, phase=f * step, **kw)[0] for f in _between_ring(views, k_targets)]
    paths = {"orbit": orbit(path_frames, size=size, center=(0, 0, 0), radius=14.0, height=3.0,
                            look_at_point=(0, 0.3, 0), fov_x=fov, bob=0.5)}
    # Fixed-step paths for depth warping (docs/synth.md "Motion"): walk 15-35 px/frame and
    # stress 100+ px/frame of average maximal motion at 1920x1080 (scales with the width).
    walk = dict(size=size, center=(0, 0, 0), radius=14.0, height=3.0, look_at_point=(0, 0.3, 0), fov_x=fov,
                bob=0.3)
    paths["walk"] = walk_orbit(path_frames, step_deg=_WALK["crowd"][0], **walk)
    paths["stress"] = walk_orbit(path_frames, step_deg=_WALK["crowd"][1], **walk)
    return _Built(parts, textures, mats, cams, targets, paths, None, (0.0, 0.0), 1.0)


def _preset_city(size, views, seed, k_targets, path_frames, blocks_x: int = 6, blocks_z: int = 5) -> _Built:
    rng = _rng(seed, "geometry")
    trng = _rng(seed, "textures")
    ts = _texture_size(size, 0.5)
    n_facades = 8
    textures = [procedural_texture(trng, _texture_size(size, 2.0), "ground")] + \
        [procedural_texture(trng, ts, "facade") for _ in range(n_facades)]
    block, street = 20.0, 10.0
    pitch = block + street
    # Blocks centred on a grid; the camera street runs along z through x = 0, between the two
    # middle columns of blocks (blocks_x is even).
    bx = (np.arange(blocks_x) - (blocks_x - 1) / 2) * pitch
    bz = (np.arange(blocks_z) - (blocks_z - 1) / 2) * pitch
    gx, gz = np.meshgrid(bx, bz, indexing="ij")
    # Each block holds 2 x 2 buildings of random footprint and height.
    sub = np.array([[-0.25, -0.25], [-0.25, 0.25], [0.25, -0.25], [0.25, 0.25]]) * block
    centers_xz = (np.stack([gx.ravel(), gz.ravel()], -1)[:, None, :] + sub[None]).reshape(-1, 2)
    nb = len(centers_xz)
    foot = rng.uniform(0.6, 0.92, (nb, 2)) * (block / 2)
    height = rng.uniform(6.0, 30.0, nb)
    sizes = np.stack([foot[:, 0], height, foot[:, 1]], -1)
    centers = np.stack([centers_xz[:, 0], height / 2, centers_xz[:, 1]], -1)
    ground_size = max(blocks_x, blocks_z) * pitch + 2 * street
    # Cameras start in the street x = 0, just before the first row of blocks, looking +z.
    start = np.array([0.0, 1.7, -pitch * (blocks_z - 1) / 2 - 2.0])
    parts = [ground_grid(ground_size, cells=max(blocks_x, blocks_z) * 4, texture_id=0, object_id=0),
             boxes(centers, sizes, 0.0, 1 + rng.integers(0, n_facades, nb), 1 + np.arange(nb))]
    thin = nb + 1  # a lamp post by the street: the reconstruction loses it
    parts.append(cylinder([street / 2 - 1.0, 0, start[2] + 12.0], 0.08, 5.0, 12, 1, thin))
    mats = np.zeros((nb + 2, 2), np.float32)
    mats[:, 1] = 8.0
    mats[1 + np.flatnonzero(rng.random(nb) < 0.3)] = [0.4, 64.0]  # glass-like facades
    fov = 70.0
    fwd = np.array([0.0, 0.0, 1.0])
    cams = forward_grid(views, size=size, center=start, direction=fwd, spacing=0.4, fov_x=fov)
    # Targets: between grid positions (half a step right and down of an input), and a step
    # forward along the street.
    tg = []
    for j in range(k_targets):
        base = cams[(j * max(views // max(k_targets, 1), 1)) % views].centre
        off = np.array([0.2, -0.2 if j % 2 else 0.2, 0.3 * (j % 3)])
        tg.append(_cam(size, fov, base + off, base + off + 20.0 * fwd))
    keys = np.array([[0.0, 1.7, 0.0], [0.8, 1.8, 10.0], [-0.8, 1.6, 20.0], [0.5, 1.7, 30.0], [0.0, 1.7, 40.0]])
    keys = keys + start
    paths = {"street": smooth_path(keys, keys + [0.0, 0.0, 20.0], path_frames, size=size, fov_x=fov)}
    paths["walk"] = walk_forward(path_frames, step=_WALK["city"][0], size=size, start=start, fov_x=fov)
    paths["stress"] = walk_forward(path_frames, step=_WALK["city"][1], size=size, start=start, fov_x=fov)
    return _Built(parts, textures, mats, cams, tg, paths, thin, (street / 2 - 2.5, start[2] + 10.0), 1.5)


def _preset_spheres(size, views, seed, k_targets, path_frames) -> _Built:
    """The high-polygon scene: 8 interlinked, tilted tori (129600 triangles each) and 6 UV
    spheres (~36700 each) on a ground plane: 1.26 M triangles, depth complexity up to ~8."""
    rng = _rng(seed, "geometry")
    trng = _rng(seed, "textures")
    ts = _texture_size(size, 0.5)
    textures = [procedural_texture(trng, _texture_size(size, 2.0), "ground")] + \
        [procedural_texture(trng, ts) for _ in range(6)]
    parts = [ground_grid(24.0, cells=8, texture_id=0, object_id=0)]
    oid = 1
    ang = 2 * math.pi * (np.arange(8) + rng.uniform(-0.2, 0.2, 8)) / 8
    rad = rng.uniform(0.6, 2.2, 8)
    for j in range(8):
        major, minor = rng.uniform(0.45, 0.8), rng.uniform(0.1, 0.22)
        tilt = rng.uniform(0.3, 1.4)
        c = [rad[j] * math.sin(ang[j]), major * math.sin(tilt) + minor + 0.02, -rad[j] * math.cos(ang[j])]
        parts.append(torus(c, major, minor, 360, 180, tilt, 1 + j % 6, oid))
        oid += 1
    ang = 2 * math.pi * (np.arange(6) + 0.5 + rng.uniform(-0.2, 0.2, 6)) / 6
    rad = rng.uniform(0.8, 2.6, 6)
    for j in range(6):
        r = rng.uniform(0.25, 0.55)
        parts.append(uv_sphere([rad[j] * math.sin(ang[j]), r, -rad[j] * math.cos(ang[j])], r, 192, 96,
                               1 + (j + 3) % 6, oid))
        oid += 1
    mats = np.zeros((oid, 2), np.float32)
    mats[:, 1] = 8.0
    mats[1 + np.flatnonzero(rng.random(oid - 1) < 0.4)] = [0.6, 64.0]
    fov = 60.0
    kw = dict(size=size, radius=6.0, height=2.2, look_at_point=(0, 0.5, 0), fov_x=fov)
    cams = ring(views, **kw)
    step = 2 * math.pi / views
    targets = [ring(1, phase=f * step, **kw)[0] for f in _between_ring(views, k_targets)]
    walk = dict(size=size, center=(0, 0, 0), radius=5.5, height=2.0, look_at_point=(0, 0.5, 0), fov_x=fov,
                bob=0.2)
    paths = {"orbit": orbit(path_frames, size=size, center=(0, 0, 0), radius=5.5, height=2.0,
                            look_at_point=(0, 0.5, 0), fov_x=fov, bob=0.3),
             "walk": walk_orbit(path_frames, step_deg=_WALK["spheres"][0], **walk),
             "stress": walk_orbit(path_frames, step_deg=_WALK["spheres"][1], **walk)}
    return _Built(parts, textures, mats, cams, targets, paths, None, (3.5, 3.5), 0.8)


# Per-frame steps of the "walk" and "stress" paths (degrees on the orbit, or metres along the
# street), tuned so that at 1920x1080 the average maximal motion (path_motion) is 15-35 px/frame
# (walk) and >= 100 px/frame (stress); measured figures in docs/synth.md.
_WALK = {"crowd": (0.38, 2.0), "city": (0.045, 0.4), "spheres": (0.9, 4.0)}

_BUILDERS = {"objects": _preset_objects, "crowd": _preset_crowd, "city": _preset_city,
             "spheres": _preset_spheres}


# ============================================================================================
# make_scene
# ============================================================================================
# Bounds of a synthetic scene's size (docs/synth.md "Size and memory"): a side of at most 16384
# pixels (16K; the engine's frame buffers index pixels with int32), at most 4096 input views and
# 1000 video frames; within them, check_scale refuses a scene whose memory estimate exceeds what
# is available (ibrtools.memory.available_memory: $IBR_MEMORY_LIMIT, else the free memory).
MAX_SIDE = 16384
MAX_VIEWS = 4096
MAX_FRAMES = 1000
# Bytes a rendered pixel holds until the scene is written (colour float32 x 3, depth, the PNG
# and EXR encodings' copies), and the scratch of one reference render per pixel (every output
# buffer of ReferenceRenderer.render, shading rays): fitted to the peak RSS of ibr-preprocess
# synth:objects at 8 and 32 views of 1280x960 and 8 of 320x240 (/usr/bin/time -v: 15.3 bytes a
# stored pixel, a 200 MB base) and rounded up so that the estimate is 1.5-1.8x above them.
_STORED_BPP = 24
_RENDER_BPP = 160
_BASE_BYTES = 400 << 20


def estimate_memory(size: Sequence[int], views: int, frames: int = 1, holdout_targets: int = 3) -> int:
    """An upper estimate of the peak bytes of :func:`make_scene` (:func:`make_video` with
    ``frames``: every frame's scene is held until it is written)."""
    w, h = int(size[0]), int(size[1])
    return int(frames * (views + holdout_targets) * w * h * _STORED_BPP + w * h * _RENDER_BPP + _BASE_BYTES)


def check_scale(size: Sequence[int], views: int, frames: int = 1, holdout_targets: int = 3, *,
                flags: tuple[str, str, str] = ("size", "views", "frames")) -> None:
    """Refuse, before anything is rendered, a scene past the bounds above or larger than the
    available memory (BadValueError naming ``flags``: the size, views and frames arguments)."""
    fs, fv, ff = flags
    w, h = _check_size(size, fs)
    if max(w, h) > MAX_SIDE:
        raise BadValueError(f"{fs}: expected at most {MAX_SIDE} pixels a side, got {w}x{h}")
    check_int(views, fv, 1, MAX_VIEWS)
    check_int(frames, ff, 1, MAX_FRAMES)
    need, avail = estimate_memory((w, h), views, frames, holdout_targets), available_memory()
    if need > avail:
        gib = 1 << 30
        what = f"{fs} {w}x{h}, {fv} {views}" + (f", {ff} {frames}" if frames > 1 else "")
        raise BadValueError(f"{fs}: a synthetic scene of {what} needs about {need / gib:.1f} GiB, only "
                            f"{avail / gib:.1f} GiB is available"
                            f"{' (IBR_MEMORY_LIMIT)' if os.environ.get('IBR_MEMORY_LIMIT') else ''}: "
                            f"use a smaller {fs} or fewer {fv}")


def scene_spec(source: str, options: dict[str, Any], *, source_label: str = "source",
               options_label: str = "synth", flags: tuple[str, str, str] = ("synth size", "synth views", "synth frames")
               ) -> dict[str, Any]:
    """The import's description of a ``synth:PRESET`` source with :func:`make_scene`'s keyword
    ``options`` (and ``frames``): {"preset": PRESET, **options}, after checking the preset, that
    every option is one make_scene takes, and the scale (:func:`check_scale`, naming ``flags``),
    before anything is rendered. BadValueError names ``source_label`` / ``options_label``."""
    import inspect

    preset = source.split(":", 1)[1]
    if preset not in PRESETS:
        raise BadValueError(f"{source_label} {source!r}: unknown preset (expected one of "
                            f"{', '.join('synth:' + k for k in PRESETS)})")
    params = inspect.signature(make_scene).parameters
    known = (set(params) | {"frames"}) - {"preset"}
    bad = sorted(set(options) - known)
    if bad:
        raise BadValueError(f"{options_label}: unknown option(s) {', '.join(bad)} (options: {', '.join(sorted(known))})")
    spec = {"preset": preset, **options}
    check_scale(spec.get("size", params["size"].default), spec.get("views", params["views"].default),
                spec.get("frames", 1), flags=flags)
    if "size" in spec:
        spec["size"] = list(spec["size"])
    return spec


def _check_size(size: Any, name: str = "size") -> tuple[int, int]:
    if isinstance(size, str) or not hasattr(size, "__len__") or len(size) != 2:
        raise DtypeError(f"{name}: expected (width, height), got {size!r}")
    w = check_int(size[0], f"{name} width", 1)
    h = check_int(size[1], f"{name} height", 1)
    return w, h


def build_mesh(preset: str, *, size: tuple[int, int] = (480, 360), views: int = 12, seed: int = 0,
               holdout_targets: int = 3, path_frames: int = 48,
               extra_meshes: Sequence[str | Path] = ()) -> tuple[Mesh, _Built]:
    """The preset's ground-truth mesh and cameras, without rendering (for tests and tools)."""
    if preset not in _BUILDERS:
        raise BadValueError(f"preset {preset!r}: unknown (presets: {', '.join(PRESETS)})")
    built = _BUILDERS[preset](size, views, seed, holdout_targets, path_frames)
    parts, textures = list(built.parts), list(built.textures)
    mats = built.materials
    n_obj = len(mats)
    for j, path in enumerate(extra_meshes):
        # Extra meshes stand side by side at the preset's free spot, each its own object.
        spot = (built.free_spot[0] + 1.2 * built.free_extent * (j - (len(extra_meshes) - 1) / 2),
                built.free_spot[1])
        part, tex = load_placed(path, center=spot, extent=built.free_extent, object_id=n_obj + j,
                                texture_offset=len(textures))
        parts.append(part)
        textures += tex
    if extra_meshes:
        extra = np.zeros((len(extra_meshes), 2), np.float32)
        extra[:, 1] = 8.0
        mats = np.concatenate([mats, extra])
    return merge(parts, textures, mats), built


def _jitter_colours(views_rgb: list[np.ndarray], names: list[str], seed: int, exposure: float,
                    white_balance: float) -> dict:
    """Per-view gains exp(N(0, exposure)) and per-channel exp(N(0, white_balance)) (applied in
    linear RGB, in place); returns the record for scene.source."""
    rng = _rng(seed, "jitter")
    record = {}
    for name, rgb in zip(names, views_rgb):
        g = float(math.exp(rng.normal(0.0, exposure))) if exposure > 0 else 1.0
        wb = np.exp(rng.normal(0.0, white_balance, 3)) if white_balance > 0 else np.ones(3)
        rgb *= (g * wb).astype(np.float32)
        record[name] = {"exposure_gain": g, "white_balance_gains": [float(x) for x in wb]}
    return record


def reconstructed_mesh(mesh: Mesh, *, seed: int, thin_object: int | None = None, keep: float = 0.5,
                       noise: float = 0.01) -> Mesh:
    """A degraded copy of ``mesh``, like a reconstruction: the thin object removed, colours
    baked to vertices (texture averaged at each vertex's corners), vertices welded, decimated
    to ``keep`` of the triangles (open3d quadric decimation), vertices perturbed by
    N(0, noise) metres. No object ids (one object), no textures; kind "reconstructed"."""
    import open3d as o3d

    keep_faces = np.ones(len(mesh.faces), bool) if thin_object is None else mesh.object_ids != thin_object
    faces = mesh.faces[keep_faces]
    # Vertex colours: mean texture colour at the corners that use each vertex (nearest texel).
    n = len(mesh.vertices)
    if mesh.textures and mesh.uvs is not None:
        uvs = mesh.uvs[keep_faces]
        tids = mesh.texture_ids[keep_faces]
        corner_rgb = np.full((len(faces), 3, 3), 0.5, np.float64)
        for t, tex in enumerate(mesh.textures):  # a loop over textures, not triangles
            sel = tids == t
            if not sel.any():
                continue
            h, w = tex.shape[:2]
            uv = uvs[sel]
            col = np.clip((uv[..., 0] * w).astype(int), 0, w - 1)
            row = np.clip(((1 - uv[..., 1]) * h).astype(int), 0, h - 1)
            corner_rgb[sel] = tex[row, col]
        if mesh.vertex_colors is not None:
            corner_rgb *= mesh.vertex_colors[faces]
        sums = np.zeros((n, 3))
        counts = np.zeros(n)
        np.add.at(sums, faces.ravel(), corner_rgb.reshape(-1, 3))
        np.add.at(counts, faces.ravel(), 1.0)
        vc = sums / np.maximum(counts, 1)[:, None]
    elif mesh.vertex_colors is not None:
        vc = mesh.vertex_colors.astype(np.float64)
    else:
        vc = np.full((n, 3), 0.5)
    o = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices.astype(np.float64)),
                                  o3d.utility.Vector3iVector(faces.astype(np.int32)))
    o.vertex_colors = o3d.utility.Vector3dVector(vc)
    o = o.merge_close_vertices(1e-6)
    o = o.remove_unreferenced_vertices()
    target = max(4, int(len(faces) * keep))
    d = o.simplify_quadric_decimation(target)
    d = d.remove_degenerate_triangles().remove_unreferenced_vertices()
    v = np.asarray(d.vertices)
    rng = _rng(seed, "reconstructed")
    v = v + rng.normal(0.0, noise, v.shape)
    return Mesh(vertices=v, faces=np.asarray(d.triangles), vertex_colors=np.clip(np.asarray(d.vertex_colors), 0, 1),
                kind="reconstructed")


def make_scene(preset: str, *, size: Sequence[int] = (480, 360), views: int = 12, seed: int = 0,
               holdout_targets: int = 3, exposure_jitter: float = 0.0, white_balance_jitter: float = 0.0,
               depth_noise: float = 0.0, reconstructed: bool = False,
               extra_meshes: Sequence[str | Path] = (), path_frames: int = 48, time: float = 0.0) -> Scene:
    """Render a synthetic scene (see docs/synth.md).

    Inputs ``views`` "v000", "v001", ... (colour + z-depth rendered from the ground-truth mesh;
    colour jitter and depth noise applied to them only), targets "t000", ... (``holdout_targets``
    cameras between the inputs, rendered: their colour and depth are ground truth), camera
    paths (``path_frames`` cameras each, not rendered), meshes "ground_truth" and, with
    ``reconstructed=True``, a degraded "reconstructed" copy. ``size`` is (width, height).
    ``exposure_jitter`` / ``white_balance_jitter``: standard deviation of log gains per view /
    per channel; ``depth_noise``: standard deviation of the multiplicative depth error.
    ``time``: the instant of a video frame (:func:`make_video`): every object but the ground
    (object id 0) is moved by ``time`` times its own velocity (:func:`move_objects`)."""
    if not isinstance(preset, str) or preset not in PRESETS:
        raise BadValueError(f"preset {preset!r}: unknown (presets: {', '.join(PRESETS)})")
    size = _check_size(size)
    views = check_int(views, "views", 1)
    seed = check_int(seed, "seed", 0)
    holdout_targets = check_int(holdout_targets, "holdout_targets", 0, MAX_VIEWS)
    check_scale(size, views, 1, holdout_targets)
    path_frames = check_int(path_frames, "path_frames", 2)
    exposure_jitter = check_float(exposure_jitter, "exposure_jitter", 0.0)
    white_balance_jitter = check_float(white_balance_jitter, "white_balance_jitter", 0.0)
    depth_noise = check_float(depth_noise, "depth_noise", 0.0)
    if isinstance(extra_meshes, (str, Path)):
        extra_meshes = [extra_meshes]
    extra_meshes = [Path(p) for p in extra_meshes]
    for p in extra_meshes:
        if not p.is_file():
            raise MissingFileError(f"extra mesh {p}: no such file")

    mesh, built = build_mesh(preset, size=size, views=views, seed=seed, holdout_targets=holdout_targets,
                             path_frames=path_frames, extra_meshes=extra_meshes)
    time = check_float(time, "time")
    if time != 0.0:
        mesh = move_objects(mesh, time, seed)
    from ibrtools.raycast.reference import ReferenceRenderer, default_lights

    renderer = ReferenceRenderer(mesh)
    lights = default_lights(mesh.bounds())
    ambient, background = 0.15, (0.0, 0.0, 0.0)

    def render(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
        out = renderer.render(cam, outputs=("color", "depth"), lights=lights, ambient=ambient,
                              background=background)
        # No surface hit = the sky: background at infinity (scene.py, docs/FORMAT.md), not unknown.
        depth = np.where(out["depth"] > 0, out["depth"], np.float32(np.inf))
        return np.ascontiguousarray(out["color"], np.float32), np.ascontiguousarray(depth, np.float32)

    names = [f"v{i:03d}" for i in range(views)]
    rendered = [render(c) for c in built.views]
    colors = [c for c, _ in rendered]
    depths = [d for _, d in rendered]
    source: dict[str, Any] = {
        "format": f"synth:{preset}", "preset": preset, "description": PRESETS[preset],
        "size": list(size), "views": views, "seed": seed, "holdout_targets": holdout_targets,
        "renderer": "ibrtools.raycast.reference", "world_up": [0, 1, 0],
        "extra_meshes": [str(p) for p in extra_meshes],
    }
    if exposure_jitter > 0 or white_balance_jitter > 0:
        source["color_jitter"] = {"exposure_sigma": exposure_jitter, "white_balance_sigma": white_balance_jitter,
                                  "views": _jitter_colours(colors, names, seed, exposure_jitter,
                                                           white_balance_jitter)}
    if depth_noise > 0:
        rng = _rng(seed, "depth_noise")
        for d in depths:
            noisy = d * (1.0 + depth_noise * rng.standard_normal(d.shape)).astype(np.float32)
            # Keep the sky (inf) at infinity and noise from flipping a depth's sign.
            d[...] = np.where(np.isfinite(d), np.maximum(noisy, 1e-3 * d), d)
        source["depth_noise"] = {"relative_sigma": depth_noise}
    scene_views = [View.create(n, c, color=col, depth=dep) for n, c, col, dep in zip(names, built.views, colors, depths)]
    targets = []
    for i, cam in enumerate(built.targets):
        col, dep = render(cam)
        targets.append(View.create(f"t{i:03d}", cam, color=col, depth=dep))
    meshes = {"ground_truth": mesh}
    if reconstructed:
        meshes["reconstructed"] = reconstructed_mesh(mesh, seed=seed, thin_object=built.thin_object)
        source["reconstructed"] = {"decimation_keep": 0.5, "vertex_noise_m": 0.01,
                                   "removed_object_id": built.thin_object}
    light_dicts = [lt.to_dict() for lt in lights]
    return Scene(views=scene_views, targets=targets, paths=built.paths, meshes=meshes, units="m",
                 source=source, lights=light_dicts, shading={"ambient": ambient, "background": list(background)})


def move_objects(mesh: Mesh, time: float, seed: int, speed: float = 0.12) -> Mesh:
    """``mesh`` with every object but the ground (object id 0) translated by ``time`` times a
    velocity of its own: horizontal, ``speed`` scene units per frame at most, drawn from the
    seed's "motion" stream (the same velocities for every frame of a video)."""
    if mesh.object_ids is None:
        raise BadValueError("move_objects: the mesh has no object ids")
    n_obj = int(mesh.object_ids.max()) + 1
    vel = _rng(seed, "motion").uniform(-speed, speed, (n_obj, 3))
    vel[:, 1] = 0.0
    vel[0] = 0.0  # the ground stays
    vertex_obj = np.zeros(len(mesh.vertices), np.int64)
    vertex_obj[mesh.faces.ravel()] = np.repeat(mesh.object_ids.astype(np.int64), 3)
    moved = (mesh.vertices.astype(np.float64) + time * vel[vertex_obj]).astype(np.float32)
    return dataclasses.replace(mesh, vertices=moved)


def make_video(preset: str, *, frames: int = 3, **kwargs: Any) -> tuple[Scene, dict[str, Scene]]:
    """A synthetic video scene (docs/FORMAT.md "Frames"): ``frames`` still scenes "f000", ...
    made by :func:`make_scene` at times 0, 1, ... (the objects move, the ground and the cameras
    stay), and the shared scene (targets' cameras, paths, units, source) that
    :func:`ibrtools.formats.native.save_video` writes beside them."""
    frames = check_int(frames, "frames", 1, MAX_FRAMES)
    check_scale(kwargs.get("size", (480, 360)), kwargs.get("views", 12), frames, kwargs.get("holdout_targets", 3))
    out = {f"f{i:03d}": make_scene(preset, time=float(i), **kwargs) for i in range(frames)}
    first = next(iter(out.values()))
    source = {**first.source, "frames": frames, "motion": "objects move by time x a per-object velocity "
                                                          "(ibrtools.synth.move_objects), ground and cameras fixed"}
    video = Scene(targets=[View.create(t.name, t.camera) for t in first.targets], paths=first.paths,
                  units=first.units, source=source)
    return video, out
