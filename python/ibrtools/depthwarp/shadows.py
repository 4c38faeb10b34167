"""Soft shadows of a rectangular area light from synthesised shadow maps (Lee, Kim, Eisemann
2018, sec. 6; docs/shadows.md).

An area light is sampled at S points stratified on its rectangle. The visibility of a surface
point (what a view sees, from the view's depth) is the fraction of the S samples it sees. With
``method="warp"`` (the paper's) the S shadow maps are *synthesised*: an L-layer deep depth buffer
is rendered once at the light's centre (depth peeling, :meth:`ReferenceRenderer.peel`, with an
optional ground-only last layer as in the paper's set-up) and warped to each light sample with
:func:`ibrtools.depthwarp.core.warp_depth` (iterative backward warping, N seeds). The shadow-map test
(``cpp/kernels/depthwarp/shadows.h``, S x H x W work in C++) then counts the maps in which the point is lit.
Peers in the same engine:

* ``method="render"``: each of the S shadow maps rendered by the Embree reference renderer (the
  paper's "reference geometry rendering" of Table 8, on our CPU ray caster);
* ``method="trace"``: no shadow map at all, one Embree occlusion ray from the surface point to
  each light sample (the exact visibility of the same S samples: the quality reference).

Shadow-map cameras: pinhole, ``resolution`` x ``resolution`` square pixels, field of view
``light.fov_deg``, all with the orientation of the light (looking from ``center`` at ``target``):
the samples differ by a translation in the light's plane. A point outside a map's frustum counts
as lit by that sample; so does a point over a hole of a warped map (no known occluder).
"""
from __future__ import annotations

import math
import time
import weakref
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ibrtools import _core
from ibrtools.camera import PINHOLE, Camera, look_at
from ibrtools.checks import check_float, check_int
from ibrtools.errors import BadValueError, DtypeError, NotBuiltError, ShapeError
from ibrtools.raycast.reference import ReferenceRenderer

METHODS = ("warp", "render", "trace")

# Shadow-map bias (shadows.h): a constant half texel (world size of a texel at the point's depth)
# plus the slope-scaled term with factor 1 (the point is within half a texel of the texel centre
# along each axis, so its own surface differs from the sampled depth by at most half the summed
# slopes: factor 1 is twice that). A constant-only bias of 2 texels lost the shadows of the crowd's
# 0.1-0.7 m boxes at 256^2 (2 texels of depth = 0.33 m there).
DEFAULT_BIAS = 0.5
DEFAULT_SLOPE_BIAS = 1.0
# Occlusion-ray start offset relative to the view depth: the float32 depth puts the surface
# point within ~1e-7 z of the surface; 1e-4 z clears it even at grazing angles to ~1 deg.
DEFAULT_EPS_REL = 1e-4


def _vec3(v: Any, name: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise DtypeError(f"{name}: expected 3 numbers, got {v!r}") from None
    if a.shape != (3,):
        raise ShapeError(f"{name}: expected 3 numbers, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise BadValueError(f"{name}: expected finite numbers, got {a.tolist()}")
    return a


@dataclass(frozen=True)
class AreaLight:
    """A rectangular area light facing ``target``.

    ``center`` (3,) world position of the rectangle's centre; ``target`` (3,) the point the light
    faces (its shadow-map cameras look from the samples in this direction); ``size`` (w, h) the
    rectangle's extent in world units along the light camera's x and y axes (OpenCV axes of
    ``look_at(center, target, up)``); (0, 0) is a point light. ``fov_deg``: the shadow maps' field
    of view (x and y: square maps), which must cover what the view sees.
    """

    center: Any
    target: Any
    size: Any = (1.0, 1.0)
    up: Any = (0.0, 1.0, 0.0)
    fov_deg: float = 90.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3(self.center, "light center"))
        object.__setattr__(self, "target", _vec3(self.target, "light target"))
        object.__setattr__(self, "up", _vec3(self.up, "light up"))
        try:
            size = tuple(float(s) for s in self.size)
        except (TypeError, ValueError):
            raise DtypeError(f"light size: expected (width, height), got {self.size!r}") from None
        if len(size) != 2 or not all(math.isfinite(s) and s >= 0 for s in size):
            raise BadValueError(f"light size: expected two finite numbers >= 0, got {self.size!r}")
        object.__setattr__(self, "size", size)
        fov = check_float(self.fov_deg, "light fov_deg", 0.0)
        if not 0 < fov < 180:
            raise BadValueError(f"light fov_deg: expected a number in (0, 180), got {fov}")
        object.__setattr__(self, "fov_deg", fov)
        if np.linalg.norm(self.target - self.center) == 0:
            raise BadValueError("light: center and target coincide")
        fwd = (self.target - self.center) / np.linalg.norm(self.target - self.center)
        if np.linalg.norm(np.cross(fwd, self.up)) < 1e-9:
            raise BadValueError("light up: parallel to the light's direction")

    def cam_from_world(self) -> np.ndarray:
        return look_at(self.center, self.target, self.up)

    def camera(self, resolution: int, center: Any = None) -> Camera:
        """The pinhole shadow-map camera at ``center`` (default: the light's centre)."""
        pose = self.cam_from_world()
        if center is not None:
            c = _vec3(center, "center")
            pose = pose.copy()
            pose[:3, 3] = -pose[:3, :3] @ c
        return Camera.from_fov(resolution, resolution, self.fov_deg, pose)

    def samples(self, count: int, *, seed: int | None = 0) -> np.ndarray:
        """``count`` light positions (S, 3) float64 stratified on the rectangle: an a x b grid of
        strata with a * b = S and a the largest divisor of S not above sqrt(S) (S = 4, 16, 64, 256
        give square grids), one jittered point per stratum (``seed`` None: stratum centres)."""
        s = check_int(count, "samples", 1)
        a = max(d for d in range(1, int(math.isqrt(s)) + 1) if s % d == 0)
        b = s // a
        if seed is None:
            jx, jy = np.full((a, b), 0.5), np.full((a, b), 0.5)
        else:
            rng = np.random.default_rng(check_int(seed, "seed", 0))
            jx, jy = rng.random((a, b)), rng.random((a, b))
        # Stratum (i, j) spans [i, i + 1) / b along x and [j, j + 1) / a along y of the unit square.
        fx = (np.arange(b)[None, :] + jx) / b - 0.5
        fy = (np.arange(a)[:, None] + jy) / a - 0.5
        r = self.cam_from_world()[:3, :3]
        x_axis, y_axis = r[0], r[1]  # rows of R: camera axes in world
        pts = (self.center[None] + (fx.reshape(-1, 1) * self.size[0]) * x_axis[None]
               + (fy.reshape(-1, 1) * self.size[1]) * y_axis[None])
        return np.ascontiguousarray(pts, dtype=np.float64)


@dataclass
class ShadowResult:
    """``visibility`` (H, W) float32 in [0, 1]: fraction of the light samples each view pixel's
    surface point sees (1 where the view has no surface). ``light_positions`` (S, 3) float64.
    ``times_ms``: wall ms per stage of this call ("layers": the deep depth buffer at the light's
    centre, "maps": the S shadow maps (warps or renders), "shade": the shadow-map test, "trace":
    the occlusion rays, "total"). ``stats``: e.g. the mean hole fraction of the warped maps."""

    visibility: np.ndarray
    light_positions: np.ndarray
    times_ms: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)


_OCCLUSION_SCENES: "weakref.WeakKeyDictionary[Any, Any]" = weakref.WeakKeyDictionary()


def _occlusion_scene(renderer):
    """The Embree BVH for occlusion rays of ``renderer``'s mesh, built once per renderer."""
    scene = _OCCLUSION_SCENES.get(renderer)
    if scene is None:
        scene = _core.OcclusionScene(renderer.mesh.vertices, renderer.mesh.faces)
        _OCCLUSION_SCENES[renderer] = scene
    return scene


def soft_shadows(renderer, light: AreaLight, view: Camera, view_depth: np.ndarray, *, samples: int = 16,
                 resolution: int = 512, method: str = "warp", layers: int = 3, ground_object: int | None = None,
                 umbra: bool = False,
                 params=None, bias: float = DEFAULT_BIAS, slope_bias: float = DEFAULT_SLOPE_BIAS,
                 eps_rel: float = DEFAULT_EPS_REL,
                 seed: int | None = 0) -> ShadowResult:
    """Visibility of ``light`` (an :class:`AreaLight`) for each pixel of ``view``.

    ``renderer``: the :class:`ibrtools.raycast.reference.ReferenceRenderer` of the scene's mesh
    (its BVH renders the light's depth layers or maps; ``method="trace"`` builds an occlusion BVH of
    the same mesh once per renderer). ``view_depth`` (H, W) float32: the view's depth (pinhole z /
    equirect ray distance; 0 = no surface), e.g. its reference depth; surface points are
    reconstructed from it. ``samples`` S light samples (:meth:`AreaLight.samples` with ``seed``),
    ``resolution`` shadow-map side in pixels. ``method``: "warp" | "render" | "trace" (module
    docstring). "warp" only: ``layers`` L of the deep depth buffer at the light's centre (L = 1: its
    plain depth), ``ground_object`` (the ground's object id: the last layer is the ground alone, the
    paper's set-up; needs L >= 2), ``umbra`` (generalised umbra culling while peeling, Eq. 1, towards
    the S sample positions: fragments no sample can see behind a nearer pixel quad are skipped),
    ``params`` a :class:`ibrtools.depthwarp.core.DepthWarpParams`
    (default: N = 4 seeds as in the paper's sec. 6). ``bias`` (texels) and ``slope_bias`` (times the
    map's own depth slope): the shadow-map bias ("warp", "render"; shadows.h); ``eps_rel``: occlusion-ray start offset relative to the view depth ("trace").
    """
    if not isinstance(renderer, ReferenceRenderer):
        raise DtypeError(f"renderer: expected an ibrtools.raycast.reference.ReferenceRenderer, got "
                         f"{type(renderer).__name__}")
    if not isinstance(light, AreaLight):
        raise DtypeError(f"light: expected an ibrtools.depthwarp.shadows.AreaLight, got {type(light).__name__}")
    if not isinstance(view, Camera):
        raise DtypeError(f"view: expected an ibrtools.Camera, got {type(view).__name__}")
    if not isinstance(view_depth, np.ndarray):
        raise DtypeError(f"view_depth: expected a float32 numpy array of shape (H, W), got {type(view_depth).__name__}")
    if not isinstance(umbra, (bool, np.bool_)):
        raise DtypeError(f"umbra: expected a bool, got {umbra!r}")
    if method not in METHODS:
        raise BadValueError(f"method: expected one of {METHODS}, got {method!r}")
    s = check_int(samples, "samples", 1)
    res = check_int(resolution, "resolution", 1)
    layers = check_int(layers, "layers", 1)
    bias = check_float(bias, "bias", 0.0)
    slope_bias = check_float(slope_bias, "slope_bias", 0.0)
    eps_rel = check_float(eps_rel, "eps_rel", 0.0)
    positions = light.samples(s, seed=seed)
    core_view = view.to_core()
    times: dict[str, float] = {}
    stats: dict[str, float] = {}
    t_start = time.perf_counter()
    if method == "trace":
        scene = _occlusion_scene(renderer)
        t0 = time.perf_counter()
        vis = scene.visibility(view_depth, core_view, positions, eps_rel)
        times["trace"] = (time.perf_counter() - t0) * 1e3
    else:
        cams = [light.camera(res, p) for p in positions]
        maps = np.empty((s, res, res), np.float32)
        if method == "render":
            t0 = time.perf_counter()
            for i, c in enumerate(cams):
                maps[i] = renderer.render(c, outputs=("depth",), lights=[])["depth"]
            times["maps"] = (time.perf_counter() - t0) * 1e3
        else:
            try:
                from ibrtools.depthwarp.core import DepthWarpParams, warp_depth
            except ImportError:
                raise NotBuiltError("soft_shadows: method 'warp' needs ibrtools.depthwarp.core, not built yet") from None
            if params is None:
                params = DepthWarpParams(seeds=4)
            centre = light.camera(res)
            t0 = time.perf_counter()
            if layers == 1 and ground_object is None:
                deep = renderer.render(centre, outputs=("depth",), lights=[])["depth"][None]
            else:
                deep = renderer.peel(centre, layers, ground_object=ground_object,
                                     umbra=positions if umbra else None).depth
            t1 = time.perf_counter()
            holes = 0.0
            for i, c in enumerate(cams):
                w = warp_depth(deep, centre, c, params)
                maps[i] = w.depth
                holes += float(w.hole.mean())
            times["layers"] = (t1 - t0) * 1e3
            times["maps"] = (time.perf_counter() - t1) * 1e3
            stats["hole_fraction"] = holes / s
        t0 = time.perf_counter()
        vis = _core.shadow_map_visibility(view_depth, core_view, maps, [c.to_core() for c in cams], bias,
                                          slope_bias)
        times["shade"] = (time.perf_counter() - t0) * 1e3
    times["total"] = (time.perf_counter() - t_start) * 1e3
    return ShadowResult(vis, positions, times, stats)


def shadow_map_visibility(view: Camera, view_depth: np.ndarray, maps: np.ndarray, cameras: list[Camera],
                          bias: float = DEFAULT_BIAS, slope_bias: float = DEFAULT_SLOPE_BIAS) -> np.ndarray:
    """The shadow-map test alone (``cpp/kernels/depthwarp/shadows.h``): fraction of the S maps (S, Hs, Ws)
    float32 (pinhole z of ``cameras[s]``, 0 = no occluder) in which each view pixel's surface
    point is lit; ``bias`` in texels, ``slope_bias`` times the map's depth slope."""
    if not isinstance(view, Camera):
        raise DtypeError(f"view: expected an ibrtools.Camera, got {type(view).__name__}")
    cams = list(cameras)
    for i, c in enumerate(cams):
        if not isinstance(c, Camera):
            raise DtypeError(f"cameras[{i}]: expected an ibrtools.Camera, got {type(c).__name__}")
        if c.model != PINHOLE:
            raise BadValueError(f"cameras[{i}]: expected a pinhole camera")
    bias = check_float(bias, "bias", 0.0)
    slope_bias = check_float(slope_bias, "slope_bias", 0.0)
    return _core.shadow_map_visibility(view_depth, view.to_core(), maps, [c.to_core() for c in cams], bias,
                                       slope_bias)
