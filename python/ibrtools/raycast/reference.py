"""Reference renderer: Embree ray casting of a mesh (docs/reference.md).

The ground truth that every other method is measured against, and the renderer that makes the
synthetic scenes. One ray per pixel through its centre; the mesh's BVH is built once per
:class:`ReferenceRenderer`. The C++ side is ``cpp/ibr/embree_scene.h`` (the BVH) and
``cpp/kernels/raycast/raycast.h`` (rays, buffers and the shading model, stated in full there).

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

Deep depth buffers (:meth:`ReferenceRenderer.peel`, Lee, Kim, Eisemann 2018 sec. 3.4): L layers
of z-depth and object ids per pixel by depth peeling (each layer continues the pixel's ray past
the previous layer's hit), optionally with generalised umbra culling (Eq. 1; the derivation of
c, e, h and s is in ``cpp/kernels/raycast/raycast.h``) and a last "ground only" layer.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from ibrtools._core import RayScene
from ibrtools.camera import Camera
from ibrtools.checks import check_float
from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.mesh import Mesh
from ibrtools.checks import check_int

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
                raise DtypeError(f"lights[{i}]: expected an ibrtools.raycast.reference.Light, "
                                 f"got {type(light).__name__}")
        ambient = check_float(ambient, "ambient", 0.0)
        bg = _vec3(background, "background")
        return self._scene.render(core_cam, names,
                                  [(l.kind, l.vector, l.color, l.shadows) for l in lights],
                                  ambient, list(bg), packet)

    def visible_objects(self, camera: Camera) -> np.ndarray:
        """Sorted unique object ids (int32) hit by any primary ray of ``camera``."""
        return self._scene.visible_objects(self._core_camera(camera))

    def peel(self, camera: Camera, layers: int = 4, *, umbra=None,
             umbra_radius: float = 0.0, ground_object: int | None = None) -> "DeepDepth":
        """Deep depth buffer of ``camera`` by depth peeling (Lee, Kim, Eisemann 2018 sec. 3.4).

        ``layers`` L >= 1 in total. ``umbra``: the novel cameras the buffer will be warped to (a list
        of :class:`Camera` or their centres as (K, 3) world positions; each may lie anywhere within
        ``umbra_radius`` of its given position, e.g. the extent of an area light): fragments that
        none of them can see behind a nearer pixel quad are skipped (generalised umbra culling,
        Eq. 1), so the useful layers come sooner; pinhole cameras only. ``ground_object``: the
        object id of the ground; the *last* of the L layers is then the depth of that object alone
        (rays against its faces only), the first L - 1 are peeled (the paper's sec. 4.1 set-up).
        """
        core_cam = self._core_camera(camera)
        layers = check_int(layers, "layers", 1)
        umbra_radius = check_float(umbra_radius, "umbra_radius", 0.0)
        positions = None
        if umbra is not None:
            if isinstance(umbra, Camera):
                umbra = [umbra]
            if isinstance(umbra, (list, tuple)) and umbra and all(isinstance(c, Camera) for c in umbra):
                umbra = [c.centre for c in umbra]
            positions = _umbra_positions(umbra)
            if camera.model != "pinhole":
                raise BadValueError("umbra: generalised umbra culling needs a pinhole source camera")
        peeled = layers
        if ground_object is not None:
            ground_object = check_int(ground_object, "ground_object", 0)
            if not np.any(self.mesh.object_ids == ground_object):
                raise BadValueError(f"ground_object: no face of the mesh has object id {ground_object}")
            if layers < 2:
                raise BadValueError("layers: a ground-only last layer needs layers >= 2")
            peeled = layers - 1
        t0 = time.perf_counter()
        out = self._scene.peel(core_cam, peeled, umbra_positions=positions, umbra_radius=umbra_radius)
        times = {"peel": (time.perf_counter() - t0) * 1e3}
        depth, ids = out["depth"], out["object_id"]
        if ground_object is not None:
            ground = self._ground_scene(ground_object)
            t1 = time.perf_counter()
            g = ground.render(core_cam, ["depth", "hit"], [], 0.0, [0.0, 0.0, 0.0], 16)
            times["ground"] = (time.perf_counter() - t1) * 1e3
            depth = np.concatenate([depth, g["depth"][None]])
            ids = np.concatenate([ids, np.where(g["hit"], np.int32(ground_object), np.int32(-1))[None]])
        return DeepDepth(depth, ids, ground_object is not None, positions is not None, times)


    def _ground_scene(self, ground_object: int):
        """An Embree scene of the ground object's faces alone (built once per object id)."""
        cache = self.__dict__.setdefault("_ground_scenes", {})
        if ground_object not in cache:
            faces = np.ascontiguousarray(self.mesh.faces[self.mesh.object_ids == ground_object])
            cache[ground_object] = RayScene(self.mesh.vertices, faces, None)
        return cache[ground_object]


@dataclass
class DeepDepth:
    """A deep depth buffer of one camera (:meth:`ReferenceRenderer.peel`).

    ``depth`` (L, H, W) float32: z in the camera (pinhole; ray distance for equirect), 0 = empty;
    per pixel the peeled layers are non-empty first and strictly increasing in depth. When
    ``ground_layer`` is set, the last layer is the depth of the ground object alone (the first
    hit of a ray against only that object's faces): it may repeat a depth of an earlier layer.
    ``object_id`` (L, H, W) int32, -1 = empty. ``times_ms``: "peel" (the L or L - 1 peeled layers)
    and "ground" (the ground-only layer). ``fill`` (L,): fraction of non-empty pixels per layer.
    """

    depth: np.ndarray
    object_id: np.ndarray
    ground_layer: bool = False
    umbra: bool = False
    times_ms: dict = field(default_factory=dict)

    @property
    def layers(self) -> int:
        return int(self.depth.shape[0])

    @property
    def fill(self) -> np.ndarray:
        return (self.depth > 0).reshape(self.layers, -1).mean(axis=1)


def _umbra_positions(positions) -> np.ndarray:
    try:
        p = np.asarray(positions, dtype=np.float64)
    except (TypeError, ValueError):
        raise DtypeError(f"umbra: expected camera positions (K, 3) or cameras, got {positions!r}") from None
    if p.ndim == 1 and p.shape == (3,):
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ShapeError(f"umbra: expected camera positions of shape (K, 3), K >= 1, got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise BadValueError("umbra: camera positions contain NaN or infinity")
    return np.ascontiguousarray(p)

