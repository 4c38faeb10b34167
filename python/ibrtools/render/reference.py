"""Reference renderer: Embree ray casting of a mesh (docs/reference.md).

The ground truth that every other method is measured against, and the renderer that makes the
synthetic scenes. One ray per pixel through its centre; the mesh's BVH is built once per
:class:`ReferenceRenderer`. The C++ side is ``cpp/ibr/embree_scene.h`` (the BVH) and
``cpp/kernels/raycast.h`` (rays, buffers and the shading model, stated in full there).

Outputs of :meth:`ReferenceRenderer.render` (all C-contiguous, allocated once by the engine):

=============  =================  ==========================================================
key            array              meaning (no hit)
=============  =================  ==========================================================
``color``      (H, W, 3) float32  shaded linear RGB (``background``)
``depth``      (H, W) float32     the scene model's depth: pinhole z in the camera, equirect
                                  distance along the ray (0 = unknown)
``distance``   (H, W) float32     distance from the camera centre (0)
``normal``     (H, W, 3) float32  unit geometric normal in world axes, facing the camera (0)
``object_id``  (H, W) int32       ``mesh.object_ids`` of the hit face (-1)
``prim_id``    (H, W) int32       index of the hit face (-1)
``bary``       (H, W, 2) float32  (u, v) with p = (1-u-v) v0 + u v1 + v v2 (0)
``hit``        (H, W) bool        True where a face is hit
=============  =================  ==========================================================

Shading (``color``): albedo from the texture (bilinear, repeat, OBJ uv convention), else the
vertex colours, else 0.8 grey; ``albedo * (ambient + sum E N.L) + sum ks E (N.H)^shininess``
with hard shadows by occlusion rays, (ks, shininess) = ``mesh.materials[object_id]``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from .._core import RayScene
from ..camera import Camera
from ..checks import check_float
from ..errors import BadValueError, DtypeError, ShapeError
from ..mesh import Mesh

OUTPUTS = ("color", "depth", "distance", "normal", "object_id", "prim_id", "bary", "hit")
LIGHT_KINDS = ("point", "directional")


def _vec3(value, name: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(x) for x in np.asarray(value, dtype=np.float64).reshape(-1))
    except (TypeError, ValueError):
        raise DtypeError(f"{name}: expected 3 numbers, got {value!r}") from None
    if len(v) != 3:
        raise ShapeError(f"{name}: expected 3 numbers, got {len(v)}")
    if not all(math.isfinite(x) for x in v):
        raise BadValueError(f"{name}: expected finite numbers, got {v}")
    return v


@dataclass(frozen=True)
class Light:
    """A light of the reference shading model.

    ``kind`` "point": ``vector`` is the light's *position* in world units; the irradiance at
    a distance d is ``color / d**2`` (inverse-square law).
    ``kind`` "directional": ``vector`` is the *direction towards the light* (from the surface
    to the light, any length); the irradiance is ``color``.
    ``color`` is linear RGB intensity (>= 0): a white Lambert surface facing a directional light
    of colour c head-on shades to ``c + ambient``. ``shadows``: cast hard shadows (one occlusion
    ray per lit pixel).
    """

    kind: str
    vector: tuple[float, float, float]
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    shadows: bool = True

    def __post_init__(self) -> None:
        if self.kind not in LIGHT_KINDS:
            raise BadValueError(f"light kind: expected one of {LIGHT_KINDS}, got {self.kind!r}")
        object.__setattr__(self, "vector", _vec3(self.vector, f"{self.kind} light vector"))
        color = _vec3(self.color, "light color")
        if min(color) < 0:
            raise BadValueError(f"light color: expected values >= 0, got {color}")
        object.__setattr__(self, "color", color)
        if self.kind == "directional" and not any(self.vector):
            raise BadValueError("directional light vector: must not be zero")
        object.__setattr__(self, "shadows", bool(self.shadows))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "vector": list(self.vector), "color": list(self.color),
                "shadows": self.shadows}


def default_lights(bounds: np.ndarray) -> list[Light]:
    """A key light with shadows plus a shadowless fill, placed from the scene bounds (2, 3).

    Assumes +y is up (``look_at``'s default). The key is a point light above, to the right and
    in front (+z) of the box, at 1.5 box diagonals from its centre, with an intensity that gives
    an irradiance of 0.8 at the centre; the fill is a directional light of 0.25 from the
    opposite side, so that no lit-side surface is pitch black.
    """
    b = np.asarray(bounds, dtype=np.float64)
    if b.shape != (2, 3):
        raise ShapeError(f"bounds: expected shape (2, 3) (min and max corner), got {b.shape}")
    if not np.all(np.isfinite(b)):
        raise BadValueError("bounds: contain NaN or infinity")
    centre = b.mean(axis=0)
    diag = float(np.linalg.norm(b[1] - b[0])) or 1.0
    offset = np.array([0.45, 1.0, 0.6])
    offset *= 1.5 * diag / np.linalg.norm(offset)
    key_pos = centre + offset
    key = 0.8 * float(offset @ offset)
    return [
        Light("point", tuple(key_pos), (key, key, key), shadows=True),
        Light("directional", (-0.5, 0.6, -0.6), (0.25, 0.25, 0.25), shadows=False),
    ]


def _output_names(outputs: str | Iterable[str]) -> list[str]:
    if isinstance(outputs, str):
        outputs = (outputs,)
    try:
        names = list(outputs)
    except TypeError:
        raise DtypeError(f"outputs: expected names from {OUTPUTS}, got {outputs!r}") from None
    if not names:
        raise BadValueError(f"outputs: expected at least one of {OUTPUTS}")
    for n in names:
        if n not in OUTPUTS:
            raise BadValueError(f"outputs: unknown output {n!r}; expected any of {', '.join(OUTPUTS)}")
    return list(dict.fromkeys(names))


class ReferenceRenderer:
    """Ray-casts one mesh for any number of cameras; the BVH is built once, here."""

    def __init__(self, mesh: Mesh, *, quality: str = "high"):
        if not isinstance(mesh, Mesh):
            raise DtypeError(f"mesh: expected an ibrtools.Mesh, got {type(mesh).__name__}")
        self.mesh = mesh
        textured = mesh.uvs is not None and len(mesh.textures) > 0
        self._scene = RayScene(
            mesh.vertices, mesh.faces, mesh.object_ids,
            vertex_colors=mesh.vertex_colors,
            uvs=mesh.uvs if textured else None,
            texture_ids=mesh.texture_ids if textured else None,
            textures=list(mesh.textures) if textured else [],
            materials=mesh.materials, quality=quality)
        self._default_lights: list[Light] | None = None

    @property
    def build_ms(self) -> float:
        """BVH build time of this mesh (ms)."""
        return self._scene.build_ms

    def _core_camera(self, camera: Camera):
        if not isinstance(camera, Camera):
            raise DtypeError(f"camera: expected an ibrtools.Camera, got {type(camera).__name__}")
        return camera.to_core()

    def render(self, camera: Camera, *, outputs: Sequence[str] | str = ("color", "depth"),
               lights: Sequence[Light] | None = None, ambient: float = 0.15,
               background: Sequence[float] = (0.0, 0.0, 0.0), packet: int = 16) -> dict[str, np.ndarray]:
        """Render ``outputs`` (names in the module docstring) for one camera.

        ``lights`` None uses :func:`default_lights` of the mesh bounds; ``[]`` means ambient only.
        ``packet`` is the number of primary rays per Embree query (16 fastest, 1 = the scalar
        reference path; results agree to float rounding).
        """
        core_cam = self._core_camera(camera)
        names = _output_names(outputs)
        if lights is None:
            if self._default_lights is None:
                self._default_lights = default_lights(self.mesh.bounds())
            lights = self._default_lights
        if isinstance(lights, Light):
            lights = [lights]
        for i, light in enumerate(lights):
            if not isinstance(light, Light):
                raise DtypeError(f"lights[{i}]: expected an ibrtools.render.reference.Light, "
                                 f"got {type(light).__name__}")
        ambient = check_float(ambient, "ambient", 0.0)
        bg = _vec3(background, "background")
        return self._scene.render(core_cam, names,
                                  [(l.kind, l.vector, l.color, l.shadows) for l in lights],
                                  ambient, list(bg), packet)

    def visible_objects(self, camera: Camera) -> np.ndarray:
        """Sorted unique object ids (int32) hit by any primary ray of ``camera``."""
        return self._scene.visible_objects(self._core_camera(camera))
