"""Triangle meshes: the ground-truth or reconstructed global mesh of a scene.

Arrays (all C-contiguous):
  vertices       (N, 3) float32, world units
  faces          (M, 3) int32, counter-clockwise seen from the front (outward normal)
  vertex_colors  (N, 3) float32 linear RGB, optional
  uvs            (M, 3, 2) float32 per face corner, OBJ convention (origin at the texture's
                 bottom-left: texel row = (1 - v) * H), optional
  textures       list of (H, W, 3) float32 linear RGB images, optional
  texture_ids    (M,) int32 index into ``textures`` (-1 = untextured face), optional
  object_ids     (M,) int32 object of each face (0 when the mesh is one object)
  materials      (K, 2) float32 per object id: (specular strength in [0, 1], Blinn-Phong
                 shininess exponent); missing = diffuse only
``kind`` is "ground_truth" or "reconstructed".
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ibrtools.errors import BadValueError, DtypeError, ShapeError

MESH_KINDS = ("ground_truth", "reconstructed")


def _as(a, dtype, name: str, shape: tuple) -> np.ndarray:
    arr = np.ascontiguousarray(np.asarray(a), dtype=dtype)
    if arr.ndim != len(shape) or any(s >= 0 and arr.shape[i] != s for i, s in enumerate(shape)):
        raise ShapeError(f"mesh {name}: expected shape {tuple('N' if s < 0 else s for s in shape)}, got {arr.shape}")
    return arr


@dataclass(eq=False)
class Mesh:
    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray | None = None
    uvs: np.ndarray | None = None
    textures: list[np.ndarray] = field(default_factory=list)
    texture_ids: np.ndarray | None = None
    object_ids: np.ndarray | None = None
    materials: np.ndarray | None = None
    kind: str = "ground_truth"

    def __post_init__(self) -> None:
        for name in ("vertices", "faces"):
            v = getattr(self, name)
            if not isinstance(v, np.ndarray) and not isinstance(v, (list, tuple)):
                raise DtypeError(f"mesh {name}: expected an array, got {type(v).__name__}")
        self.vertices = _as(self.vertices, np.float32, "vertices", (-1, 3))
        self.faces = _as(self.faces, np.int32, "faces", (-1, 3))
        n, m = len(self.vertices), len(self.faces)
        if m == 0:
            raise BadValueError("mesh faces: the mesh has no triangles")
        if not np.all(np.isfinite(self.vertices)):
            raise BadValueError("mesh vertices: contain NaN or infinity")
        if self.faces.min() < 0 or self.faces.max() >= n:
            raise BadValueError(f"mesh faces: vertex index out of range [0, {n})")
        if self.vertex_colors is not None:
            self.vertex_colors = _as(self.vertex_colors, np.float32, "vertex_colors", (n, 3))
        if self.uvs is not None:
            self.uvs = _as(self.uvs, np.float32, "uvs", (m, 3, 2))
        self.textures = [_as(t, np.float32, "texture", (-1, -1, 3)) for t in self.textures]
        if self.texture_ids is not None:
            self.texture_ids = _as(self.texture_ids, np.int32, "texture_ids", (m,))
            if self.texture_ids.max(initial=-1) >= len(self.textures):
                raise BadValueError("mesh texture_ids: index past the list of textures")
        elif self.textures and self.uvs is not None:
            self.texture_ids = np.zeros(m, np.int32)
        if self.object_ids is None:
            self.object_ids = np.zeros(m, np.int32)
        self.object_ids = _as(self.object_ids, np.int32, "object_ids", (m,))
        if self.materials is not None:
            self.materials = _as(self.materials, np.float32, "materials", (-1, 2))
        if self.kind not in MESH_KINDS:
            raise BadValueError(f"mesh kind: expected one of {MESH_KINDS}, got {self.kind!r}")

    @property
    def num_objects(self) -> int:
        return int(self.object_ids.max()) + 1 if len(self.object_ids) else 0

    def bounds(self) -> np.ndarray:
        """(2, 3): min and max corner."""
        return np.stack([self.vertices.min(0), self.vertices.max(0)])
