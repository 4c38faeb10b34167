"""Warping-based occlusion culling (WOC; Lee, Kim, Eisemann 2018, sec. 5; docs/culling.md).

The depth buffer predicted for a new frame (``ibrtools.depthwarp.core.warp_depth`` of the previous
frame's depth) is the occlusion map: every surface seen in the previous frame is an occluder, no
occluder selection. For conservative culling the map is the warp's proven occluder depth
(``warp_depth(..., surface_ids=...).occluder``: a depth only where the warp proves that an object
covers the pixel no farther; 0 = far), passed with ``hole=None``; the warp's converged depth and
holes are accepted too (AWOC fills them) but cull visible objects seen through sub-pixel gaps
between occluders (docs/culling.md). Per frame:

1. **View-frustum culling** of each object's world AABB (:func:`object_boxes`): a box whose 8
   corners are all outside one frustum plane, or whose projection misses the image, is
   ``frustum_culled``. A box crossing the near plane is kept visible untested (its projection
   is unbounded).
2. **Occlusion test** of the remaining boxes: the screen rectangle of the projected corners (one
   pixel of slack on each side, ``pad``) is queried for the maximum warped depth with
   :class:`ibrtools.depthwarp.core.MaxDepthQuery` (Y-map: two max-mipmap levels, then N-buffers;
   Décoret 2005, Schwarz & Stamminger 2008), holes and empty pixels set to +inf (far:
   conservative, paper sec. 5.3). The box is ``occlusion_culled`` when its least camera z
   exceeds that maximum: every point of it is behind every occluder over its whole rectangle.
3. **AWOC** (``approximate=True``, paper sec. 5.3, for fast motion where WOC's holes make it
   too conservative): before the test, each hole pixel p takes an approximate depth: the
   nearest of the source pixels at the corners of p's local search bound (the region
   [p - max V, p - min V] of the source where p's solution would lie, narrowed by min-max
   motion mipmaps as in the paper's Fig. 5), moved into the new camera. Those source pixels do
   not converge (else p would not be a hole); the paper "simply considers the nearest of them as
   an approximate depth". AWOC needs the source frame: ``source_depth`` and ``source_camera``
   (and the object motion, if any), since the warp's result does not carry the motion buffer.
   AWOC is not conservative: it may cull a visible object (the paper reports >= 30 dB colour
   PSNR against WOC). Our depth buffers hold 0 where there is no surface, so sky pixels are holes
   of our warp, while the paper's rasteriser has them converge to the far plane: a hole whose
   direction (a point at infinity) was empty in the source frame stays a hole (far) here.

For culling, warp with ``DepthWarpParams(dilate=False)``: the dilation fills small holes with a
neighbour's depth, which can close a one-pixel gap through which an object appears.

Ground truth: :meth:`ibrtools.raycast.reference.ReferenceRenderer.visible_objects` (the object
ids hit by a primary ray of the new camera); :meth:`CullResult.evaluate` compares.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ibrtools import _core
from ibrtools.camera import PINHOLE, Camera
from ibrtools.checks import check_float, check_int
from ibrtools.errors import BadValueError, DtypeError, NotBuiltError, ShapeError
from ibrtools.mesh import Mesh

# Objects of at most this many pixels in the reference object-id buffer are reported apart:
# the paper (sec. 5.3) expects "only tiny objects (of 1-2 pixels)" to be falsely culled, through
# rasterisation precision of the warped depth.
SMALL_OBJECT_PIXELS = 2

STATE_OUTSIDE, STATE_NEAR, STATE_TEST = 0, 1, 2


def object_boxes(mesh: Mesh) -> np.ndarray:
    """World AABB of each object id of ``mesh``: (K, 2, 3) float32 (min corner, max corner),
    K = ``mesh.num_objects``; an id with no face gets (+inf, -inf) and is always culled."""
    if not isinstance(mesh, Mesh):
        raise DtypeError(f"mesh: expected an ibrtools.Mesh, got {type(mesh).__name__}")
    return _core.cull_object_boxes(mesh.vertices, mesh.faces, mesh.object_ids, mesh.num_objects)


@dataclass
class CullResult:
    """Outcome of :func:`cull_objects` for K objects.

    ``visible`` (K,) bool: the drawn set (not culled). ``frustum_culled`` / ``occlusion_culled``
    (K,) bool, disjoint, and ``visible == ~(frustum_culled | occlusion_culled)``. ``max_depth`` (K,)
    float32: the queried max depth of each tested box (+inf where untested or where a hole
    covers its rectangle); ``min_z`` (K,) float32 the box's least camera z (0 where untested).
    ``times_ms``: {"prepare": holes to far (and the AWOC fill), "nbuffer": MaxDepthQuery build,
    "test": frustum + rectangles + queries + compare} wall ms of this call.
    """

    visible: np.ndarray
    frustum_culled: np.ndarray
    occlusion_culled: np.ndarray
    max_depth: np.ndarray
    min_z: np.ndarray
    times_ms: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)

    def evaluate(self, ideal_visible_ids: Any, pixel_counts: Any = None) -> dict:
        """Compare with the ideal visible set (object ids seen by the reference renderer).

        ``pixel_counts`` (K,) int: pixels of each object in the reference object-id buffer
        (``np.bincount(object_id[object_id >= 0], minlength=K)``); without it every falsely
        culled object counts as large. Returns {"objects": K, "drawn": visible count, "ideal":
        ideal count, "frustum_culled", "occlusion_culled", "falsely_culled": visible in the
        reference but culled, "falsely_culled_small": those of them with <= 2 reference pixels,
        "falsely_culled_large": the rest (the target is 0), "false_ids": their ids,
        "culled_fraction": culled / K, "ideal_culled_fraction": (K - ideal) / K,
        "overdraw": drawn / ideal}.
        """
        k = len(self.visible)
        ids = np.asarray(ideal_visible_ids)
        if ids.ndim != 1 or (ids.size and not np.issubdtype(ids.dtype, np.integer)):
            raise DtypeError(f"ideal_visible_ids: expected a 1-D integer array, got {ids.dtype} {ids.shape}")
        if ids.size and (ids.min() < 0 or ids.max() >= k):
            raise BadValueError(f"ideal_visible_ids: ids must lie in [0, {k}), got [{ids.min()}, {ids.max()}]")
        ideal = np.zeros(k, bool)
        ideal[ids] = True
        if pixel_counts is None:
            counts = np.full(k, SMALL_OBJECT_PIXELS + 1, np.int64)
        else:
            counts = np.asarray(pixel_counts)
            if counts.shape != (k,) or not np.issubdtype(counts.dtype, np.integer):
                raise ShapeError(f"pixel_counts: expected an integer array of shape ({k},), got "
                                 f"{counts.dtype} {counts.shape}")
        false = ideal & ~self.visible
        small = false & (counts <= SMALL_OBJECT_PIXELS)
        drawn = int(self.visible.sum())
        n_ideal = int(ideal.sum())
        return {
            "objects": k,
            "drawn": drawn,
            "ideal": n_ideal,
            "frustum_culled": int(self.frustum_culled.sum()),
            "occlusion_culled": int(self.occlusion_culled.sum()),
            "falsely_culled": int(false.sum()),
            "falsely_culled_small": int(small.sum()),
            "falsely_culled_large": int((false & ~small).sum()),
            "false_ids": np.flatnonzero(false).tolist(),
            "culled_fraction": (k - drawn) / k if k else 0.0,
            "ideal_culled_fraction": (k - n_ideal) / k if k else 0.0,
            "overdraw": drawn / n_ideal if n_ideal else float("inf") if drawn else 1.0,
        }


def _depth_arrays(warped_depth: Any, hole: Any, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(warped_depth, np.ndarray) or warped_depth.dtype != np.float32:
        raise DtypeError("warped_depth: expected a float32 numpy array of shape (H, W), got "
                         f"{getattr(warped_depth, 'dtype', type(warped_depth).__name__)}")
    shape = (camera.height, camera.width)
    if warped_depth.shape != shape:
        raise ShapeError(f"warped_depth: expected shape (H, W) = {shape} (the camera's size), got {warped_depth.shape}")
    if hole is None:
        hole = np.zeros(shape, bool)
    if not isinstance(hole, np.ndarray) or hole.dtype not in (np.bool_, np.uint8):
        raise DtypeError(f"hole: expected a bool numpy array of shape (H, W), got "
                         f"{getattr(hole, 'dtype', type(hole).__name__)}")
    if hole.shape != shape:
        raise ShapeError(f"hole: expected shape (H, W) = {shape}, got {hole.shape}")
    return warped_depth, hole.astype(bool, copy=False)


def _check_camera(camera: Any, name: str) -> Camera:
    if not isinstance(camera, Camera):
        raise DtypeError(f"{name}: expected an ibrtools.Camera, got {type(camera).__name__}")
    if camera.model != PINHOLE:
        raise BadValueError(f"{name}: {camera.model} camera not supported by culling (pinhole only)")
    return camera


def _check_boxes(boxes: Any) -> np.ndarray:
    if not isinstance(boxes, np.ndarray) or boxes.dtype != np.float32:
        raise DtypeError(f"boxes: expected a float32 numpy array of shape (K, 2, 3), got "
                         f"{getattr(boxes, 'dtype', type(boxes).__name__)}")
    if boxes.ndim != 3 or boxes.shape[1:] != (2, 3):
        raise ShapeError(f"boxes: expected shape (K, 2, 3) (min, max corner), got {boxes.shape}")
    if np.isnan(boxes).any():
        raise BadValueError("boxes: contain NaN")
    return np.ascontiguousarray(boxes)


def _intrinsics(c: Camera) -> np.ndarray:
    return np.array([[c.fx, 0.0, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]])


def _sky_from_target(src: Camera, dst: Camera) -> np.ndarray:
    """Image map of points at infinity from ``dst`` to ``src``: K_src R_src R_dst^T K_dst^-1."""
    r_src, r_dst = src.cam_from_world[:3, :3], dst.cam_from_world[:3, :3]
    return np.ascontiguousarray(_intrinsics(src) @ r_src @ r_dst.T @ np.linalg.inv(_intrinsics(dst)))


def cull_objects(warped_depth: np.ndarray, hole: np.ndarray | None, camera: Camera, boxes: np.ndarray,
                 approximate: bool = False, *, near: float = 1e-3, pad: int = 1, mip_levels: int = 2,
                 source_depth: np.ndarray | None = None, source_camera: Camera | None = None,
                 object_ids: np.ndarray | None = None, object_motion: np.ndarray | None = None,
                 awoc_steps: int = 3) -> CullResult:
    """Cull the objects whose world boxes (K, 2, 3) are outside ``camera``'s frustum or behind the
    warped depth buffer (module docstring).

    ``warped_depth`` (H, W) float32 pinhole z in ``camera`` (0 = empty), ``hole`` (H, W) bool
    (None = no hole): the conservative map is ``warp_depth(..., surface_ids=...).occluder`` with
    ``hole=None``; AWOC takes the warp's ``depth`` and ``hole``. Holes and empty pixels never
    occlude (far). ``near`` (world units): boxes with a corner nearer are kept.
    ``pad`` (pixels): slack around each screen rectangle. ``mip_levels``: max-mipmap levels of the
    Y-map before the N-buffers (2 as in the paper). ``approximate``: AWOC, needs
    ``source_depth`` (H0, W0) float32 and ``source_camera`` (the frame the warp started from) and
    the ``object_ids`` / ``object_motion`` given to the warp, if any; ``awoc_steps`` narrowing
    steps of the local search bound (2-4, Fig. 5).
    """
    camera = _check_camera(camera, "camera")
    depth, hole = _depth_arrays(warped_depth, hole, camera)
    boxes = _check_boxes(boxes)
    near = check_float(near, "near", 0.0)
    if near <= 0:
        raise BadValueError(f"near: expected a number > 0, got {near}")
    pad = check_int(pad, "pad", 0)
    mip_levels = check_int(mip_levels, "mip_levels", 0)
    if not isinstance(approximate, (bool, np.bool_)):
        raise DtypeError(f"approximate: expected a bool, got {approximate!r}")
    try:
        from ibrtools.depthwarp.core import MaxDepthQuery
    except ImportError:
        raise NotBuiltError("culling: occlusion test not built yet (ibrtools.depthwarp.core.MaxDepthQuery "
                            "is missing)") from None

    t0 = time.perf_counter()
    if approximate:
        if source_depth is None or source_camera is None:
            raise BadValueError("approximate: AWOC needs source_depth and source_camera (the frame "
                                "the warp started from)")
        source_camera = _check_camera(source_camera, "source_camera")
        steps = check_int(awoc_steps, "awoc_steps", 0)
        from ibrtools.depthwarp.core import motion_buffer
        motion, dst_depth = motion_buffer(source_depth, source_camera, camera, object_ids=object_ids,
                                          object_motion=object_motion)
        depth, hole = depth.copy(), hole.copy()
        _core.cull_awoc_fill(depth, hole, np.ascontiguousarray(motion, np.float32),
                             np.ascontiguousarray(dst_depth, np.float32), steps,
                             _sky_from_target(source_camera, camera), source_depth)
    occluder = np.where(hole | ~(depth > 0), np.float32(np.inf), depth).astype(np.float32, copy=False)
    t1 = time.perf_counter()
    query = MaxDepthQuery(occluder, mip_levels=mip_levels)
    t2 = time.perf_counter()
    state, rect, min_z = _core.cull_project_boxes(boxes, camera.to_core(), near, pad)
    test = state == STATE_TEST
    max_depth = np.full(len(boxes), np.inf, np.float32)
    if test.any():
        max_depth[test] = query.max_depth(np.ascontiguousarray(rect[test]))
    occluded = test & (min_z > max_depth)
    t3 = time.perf_counter()
    frustum = state == STATE_OUTSIDE
    return CullResult(
        visible=~(frustum | occluded), frustum_culled=frustum, occlusion_culled=occluded,
        max_depth=max_depth, min_z=min_z,
        times_ms={"prepare": (t1 - t0) * 1e3, "nbuffer": (t2 - t1) * 1e3, "test": (t3 - t2) * 1e3},
        stats={"tested": int(test.sum()), "near": int((state == STATE_NEAR).sum()),
               "hole_fraction": float(hole.mean()) if hole.size else 0.0, "approximate": bool(approximate)})
