"""Iterative backward depth warping (Lee, Kim, Eisemann 2018, *Iterative Depth Warping*,
``../shared/papers/001_*``, sections 3, 4.1 and 5.2): predict the depth buffer of a new camera
from (deep) depth buffers that exist, without rendering the geometry again.

The algorithm, its parameters and what each option does: docs/depthwarp.md ("Kernels"). The
hot loops are C++ (``cpp/kernels/depthwarp/depthwarp.h``, ``cpp/kernels/depthwarp/nbuffer.h``); this module checks
arguments, orchestrates the stages and times them.

Conventions: pinhole cameras only (:class:`ibrtools.camera.Camera`, OpenCV axes, pixel centres at
+0.5); depth = z in the camera, float32, 0 = empty / no surface. Source and target cameras may
differ in size. Every function checks its inputs and raises the typed errors of
:mod:`ibrtools.errors` naming the argument.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ibrtools.camera import PINHOLE, Camera
from ibrtools.checks import check_float, check_int
from ibrtools.errors import BadValueError, DtypeError, ShapeError

__all__ = ["DepthWarpParams", "WarpResult", "motion_buffer", "warp_depth", "forward_warp_depth",
           "MaxDepthQuery", "BOUNDS", "FORWARD_KINDS"]

BOUNDS = ("tight", "global")
FORWARD_KINDS = ("vfw", "afw")


def _core():
    from ibrtools import _core as core

    return core


@dataclass
class DepthWarpParams:
    """Parameters of :func:`warp_depth` (docs/depthwarp.md, "Kernels")."""

    seeds: int = 16          # N, stratified seeds in the (tight) search bound
    iters: int = 3           # T, fixed-point iterations per seed (T + 1 lookups: the seed is tested too)
    threshold: float = 0.5   # convergence: |q + V(q) - p| < threshold pixels
    bound: str = "tight"     # "tight" (min-max mipmap narrowing, Fig. 5) | "global" (top level only)
    steps: int = 3           # narrowing steps (2..4)
    oriented: bool = False   # PCA-oriented bound when its area is smaller than the axis-aligned one
    early_exit: float = 0.5  # px; local bound extent below which one seed suffices (homogeneous motion)
    dilate: bool = True      # fill small holes surrounded by converged pixels (nearest-neighbour depth)
    seed: int = 0            # jitter of the stratified seeds (deterministic for a fixed seed)
    dilate_min_neighbors: int = 5  # converged pixels among the 8 neighbours needed to fill a hole
    pca_samples: int = 16    # oriented bounds: PCA of the motions at a pca_samples^2 grid of pixels
    tile: int = 8            # side of the target tiles whose bound is narrowed together (1 = per pixel)
    pixel_step: bool = True  # one more narrowing step per pixel from its tile's bound
    skip_farther: bool = True  # skip a layer's search where its nearest possible depth cannot win (not in
    #                            the paper; False = every layer searched at every pixel, as in the paper)
    edge_motion: float = 0.5  # px; silhouette test of a converged sample (0 = off; not in the paper)
    unseen_reject: bool = True  # a deep-layer (>= 1) sample needs the target ray in front of it inside the
    #                             source's view (not in the paper; docs/depthwarp.md, "unseen space")

    def checked(self) -> "DepthWarpParams":
        """A copy with every field checked (typed errors naming the field)."""
        if self.bound not in BOUNDS:
            raise BadValueError(f"bound: expected one of {BOUNDS}, got {self.bound!r}")
        for name in ("oriented", "dilate", "skip_farther", "pixel_step", "unseen_reject"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise DtypeError(f"{name}: expected a bool, got {getattr(self, name)!r}")
        p = DepthWarpParams(
            seeds=check_int(self.seeds, "seeds", 1, 4096), iters=check_int(self.iters, "iters", 0, 1000),
            threshold=check_float(self.threshold, "threshold"), bound=self.bound,
            steps=check_int(self.steps, "steps", 0, 64), oriented=bool(self.oriented),
            early_exit=check_float(self.early_exit, "early_exit", 0.0), dilate=bool(self.dilate),
            seed=check_int(self.seed, "seed", 0, 0xFFFFFFFF),
            dilate_min_neighbors=check_int(self.dilate_min_neighbors, "dilate_min_neighbors", 1, 8),
            pca_samples=check_int(self.pca_samples, "pca_samples", 2, 1024), skip_farther=bool(self.skip_farther),
            tile=check_int(self.tile, "tile", 1, 16), pixel_step=bool(self.pixel_step),
            unseen_reject=bool(self.unseen_reject), edge_motion=check_float(self.edge_motion, "edge_motion", 0.0))
        if not p.threshold > 0:
            raise BadValueError(f"threshold: expected a number > 0, got {p.threshold}")
        return p


@dataclass
class WarpResult:
    depth: np.ndarray        # (H',W') f32 z in dst; 0 in holes
    hole: np.ndarray         # (H',W') bool; True where no layer converged (after dilation if on)
    layer: np.ndarray        # (H',W') int8: index of the source layer that supplied the depth, -1 in holes
    times_ms: dict = field(default_factory=dict)  # {"motion", "mipmap", "warp", "dilate"} wall ms of this call
    stats: dict = field(default_factory=dict)     # converged_fraction, early_exit_fraction, dilated_pixels, ...
    # (H',W') f32 proven occluder depth (warp_depth with surface_ids): an upper bound of the depth seen at
    # each pixel where the warp proves one, 0 elsewhere (never dilated); None without surface_ids.
    occluder: np.ndarray | None = None


def _check_camera(cam: Any, name: str) -> Camera:
    if not isinstance(cam, Camera):
        raise DtypeError(f"{name}: expected an ibrtools.camera.Camera, got {type(cam).__name__}")
    if cam.model != PINHOLE:
        raise BadValueError(f"{name}: {cam.model} camera not supported by depthwarp (pinhole only)")
    return cam


def _as_layers(layers: Any, src: Camera, name: str = "layers") -> np.ndarray:
    """(L, H, W) float32 view of ``layers`` ((H, W) is one layer); no dtype conversion."""
    if not isinstance(layers, np.ndarray):
        raise DtypeError(f"{name}: expected a numpy float32 array (L, H, W) or (H, W), got {type(layers).__name__}")
    if layers.dtype != np.float32:
        raise DtypeError(f"{name}: expected float32, got {layers.dtype}")
    if layers.ndim == 2:
        layers = layers[None]
    if layers.ndim != 3 or layers.shape[1:] != (src.height, src.width):
        raise ShapeError(f"{name}: expected shape (L, H, W) or (H, W) with (H, W) = ({src.height}, {src.width}) "
                         f"(the src camera), got {layers.shape}")
    return np.ascontiguousarray(layers)


def _as_ids(object_ids: Any, object_motion: Any, shape: tuple[int, ...]) -> tuple[Any, Any]:
    if object_ids is None and object_motion is None:
        return None, None
    if object_ids is None or object_motion is None:
        raise BadValueError("object_ids and object_motion: give both or neither")
    if not isinstance(object_ids, np.ndarray):
        raise DtypeError(f"object_ids: expected a numpy int32 array, got {type(object_ids).__name__}")
    if object_ids.dtype != np.int32:
        raise DtypeError(f"object_ids: expected int32, got {object_ids.dtype}")
    if object_ids.ndim == 2:
        object_ids = object_ids[None]
    if object_ids.shape != shape:
        raise ShapeError(f"object_ids: expected shape {shape} (as the depth layers), got {object_ids.shape}")
    if not isinstance(object_motion, np.ndarray):
        try:
            object_motion = np.asarray(object_motion, dtype=np.float64)
        except (TypeError, ValueError):
            raise DtypeError("object_motion: expected a float64 array (K, 4, 4)") from None
    if object_motion.dtype != np.float64:
        raise DtypeError(f"object_motion: expected float64, got {object_motion.dtype}")
    if object_motion.ndim != 3 or object_motion.shape[1:] != (4, 4):
        raise ShapeError(f"object_motion: expected shape (K, 4, 4), got {object_motion.shape}")
    return np.ascontiguousarray(object_ids), np.ascontiguousarray(object_motion)


def motion_buffer(depth, src, dst, *, object_ids=None, object_motion=None) -> tuple[np.ndarray, np.ndarray]:
    """Exact per-pixel motion of a source depth buffer into camera dst.

    depth (H,W) f32 z in src; object_ids (H,W) int32 (-1 = static) with object_motion (K,4,4) float64 rigid
    world-space transforms (new_world_from_old_world) of object k between the two frames.
    Returns motion (H,W,2) f32 = target pixel position - source pixel position (x, y), and
    dst_depth (H,W) f32 = z of the moved point in dst. Pixels with depth 0, or whose point lands at or
    behind dst's image plane, get motion 0 and dst_depth 0 (invalid)."""
    src = _check_camera(src, "src")
    dst = _check_camera(dst, "dst")
    if isinstance(depth, np.ndarray) and depth.ndim != 2:
        raise ShapeError(f"depth: expected shape (H, W) = ({src.height}, {src.width}), got {depth.shape}")
    layers = _as_layers(depth, src, "depth")
    ids, mot = _as_ids(object_ids, object_motion, layers.shape)
    packed = _core().dw_motion(layers, src.to_core(), dst.to_core(), ids, mot)[0]
    return np.ascontiguousarray(packed[..., :2]), np.ascontiguousarray(packed[..., 2])


def _result(depth: np.ndarray, layer: np.ndarray, times: dict, stats: dict,
            occluder: np.ndarray | None = None) -> WarpResult:
    hole = layer < 0
    stats["hole_fraction"] = float(np.count_nonzero(hole)) / hole.size if hole.size else 0.0
    if occluder is not None:
        stats["proven_fraction"] = float(np.count_nonzero(occluder)) / occluder.size if occluder.size else 0.0
    return WarpResult(depth=depth, hole=hole, layer=layer, times_ms=times, stats=stats, occluder=occluder)


def _as_surface_ids(surface_ids: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    """(L, H, W) int32 view of ``surface_ids`` ((H, W) for L = 1), or None; no dtype conversion."""
    if surface_ids is None:
        return None
    if not isinstance(surface_ids, np.ndarray) or surface_ids.dtype != np.int32:
        raise DtypeError(f"surface_ids: expected an int32 numpy array of shape (L, H, W) = {shape}, got "
                         f"{getattr(surface_ids, 'dtype', type(surface_ids).__name__)}")
    ids = surface_ids[None] if surface_ids.ndim == 2 else surface_ids
    if ids.shape != shape:
        raise ShapeError(f"surface_ids: expected shape (L, H, W) = {shape} (the layers' shape), got {surface_ids.shape}")
    return np.ascontiguousarray(ids)


_local = threading.local()


def _scratch(shape: tuple[int, ...]) -> dict:
    """This thread's motion buffer and mipmaps of the last call with layers of ``shape``: reused
    so that a sequence of frames does not page-fault ~20 bytes per pixel and layer anew each call
    (the kernels overwrite every element). One set per thread: concurrent calls never share."""
    cache = getattr(_local, "scratch", None)
    if cache is None or cache["shape"] != shape:
        cache = {"shape": shape}
        _local.scratch = cache
    return cache


def warp_depth(layers, src, dst, params=DepthWarpParams(), *, object_ids=None, object_motion=None,
               surface_ids=None) -> WarpResult:
    """Iterative backward depth warping (Lee et al. 2018, Fig. 2/3/5/6) of an L-layer deep depth buffer.
    layers (L,H,W) f32 (layer 0 = nearest surfaces, 0 = empty), or (H,W) for L = 1; object_ids (L,H,W) int32
    (with object_motion). surface_ids (L,H,W) int32: the object id of each source pixel (< 0 = none); when
    given, the result's ``occluder`` is the proven occluder depth (cpp/kernels/depthwarp/depthwarp.h, "proof": a target
    pixel inside the moved triangle of three neighbouring source samples of one convex object), the
    conservative occlusion map of warping-based culling (docs/culling.md)."""
    src = _check_camera(src, "src")
    dst = _check_camera(dst, "dst")
    if not isinstance(params, DepthWarpParams):
        raise DtypeError(f"params: expected a DepthWarpParams, got {type(params).__name__}")
    p = params.checked()
    lay = _as_layers(layers, src)
    ids, mot = _as_ids(object_ids, object_motion, lay.shape)
    surface = _as_surface_ids(surface_ids, lay.shape)
    core = _core()
    scratch = _scratch(lay.shape)
    src_core, dst_core = src.to_core(), dst.to_core()
    t0 = time.perf_counter()
    # Motion buffers and mipmaps in one call (with axis-aligned bounds level 1 is built in the
    # motion pass; its time counts as "motion"); "mipmap" = the C++ time of the other levels.
    packed, mips, _, mipmap_ms = core.dw_motion_mips(lay, src_core, dst_core, ids, mot, p.oriented, p.pca_samples,
                                                     scratch.get("packed"), scratch.get("mips"))
    call_ms = (time.perf_counter() - t0) * 1e3
    scratch["packed"], scratch["mips"] = packed, mips
    depth, layer, c, occluder = core.dw_warp(packed, mips, dst.height, dst.width, p.seeds, p.iters, p.threshold,
                                             p.bound == "tight", p.steps, p.early_exit, p.seed, p.dilate,
                                             p.dilate_min_neighbors, p.skip_farther, p.tile, p.pixel_step,
                                             *((src_core, dst_core) if p.unseen_reject else (None, None)),
                                             p.edge_motion, surface)
    times = {"motion": call_ms - mipmap_ms, "mipmap": mipmap_ms, "warp": c["warp_ms"], "dilate": c["dilate_ms"]}
    n = dst.height * dst.width
    stats = {
        "converged_fraction": c["converged"] / n,
        "early_exit_fraction": c["early_exit"] / max(1, c["searched"]),
        "dilated_pixels": int(c["dilated"]),
        "searches": int(c["searched"]),
        "samples": int(c["samples"]),
        "lookups": int(c["lookups"]),
        "bound_axes": list(mips.axes),
        "layers": int(lay.shape[0]),
    }
    return _result(depth, layer, times, stats, occluder)


def forward_warp_depth(layers, src, dst, kind="vfw", *, object_ids=None, object_motion=None) -> WarpResult:
    """Forward baselines with the half-pixel support expansion: "vfw" (quad splatting of pixel quads,
    depth-tested) and "afw" (atomic-min point splats)."""
    src = _check_camera(src, "src")
    dst = _check_camera(dst, "dst")
    if kind not in FORWARD_KINDS:
        raise BadValueError(f"kind: expected one of {FORWARD_KINDS}, got {kind!r}")
    lay = _as_layers(layers, src)
    ids, mot = _as_ids(object_ids, object_motion, lay.shape)
    depth, layer, motion_ms, warp_ms = _core().dw_forward(lay, src.to_core(), dst.to_core(), ids, mot, kind)
    times = {"motion": motion_ms, "mipmap": 0.0, "warp": warp_ms, "dilate": 0.0}
    stats = {"converged_fraction": float((layer >= 0).mean()), "early_exit_fraction": 0.0, "dilated_pixels": 0,
             "layers": int(lay.shape[0]), "kind": kind}
    return _result(depth, layer, times, stats)


class MaxDepthQuery:
    """Y-map (first `mip_levels` levels max-mipmaps, then N-buffers, Décoret 2005 / Schwarz & Stamminger 2008)
    of a depth buffer, for conservative max-depth queries over screen rectangles. The caller sets holes to far
    (conservative) before building."""

    def __init__(self, depth, *, mip_levels: int = 2):
        if not isinstance(depth, np.ndarray):
            raise DtypeError(f"depth: expected a numpy float32 array (H, W), got {type(depth).__name__}")
        mip_levels = check_int(mip_levels, "mip_levels", 0)
        self._ymap = _core().YMap(depth, mip_levels)
        self.height, self.width, self.mip_levels = self._ymap.height, self._ymap.width, mip_levels

    @property
    def num_nbuffer_levels(self) -> int:
        return self._ymap.num_nbuffer_levels

    def max_depth(self, boxes) -> np.ndarray:
        """boxes (K,4) int32 pixel rectangles x0, y0, x1, y1 (x1, y1 exclusive; clipped to the image;
        empty after clipping -> returns +inf for that box). Returns (K,) f32, >= the true max over the box."""
        return self._ymap.max_depth(boxes)
