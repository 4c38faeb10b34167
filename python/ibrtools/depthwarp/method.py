"""Iterative backward depth warping along a camera path (Lee, Kim, Eisemann 2018): ``--method depthwarp``.

For frame t of a pose sequence (``--poses``, ``--path``), the depth buffer of camera t is
*predicted* from frame t - 1 instead of being rendered:

  peel       the reference deep depth buffer of frame t - 1: L layers by depth peeling with the
             Embree reference renderer (``ReferenceRenderer.peel``), optionally with generalised
             umbra culling towards camera t (``umbra``) and optionally (``ground``), for L >= 2,
             the last layer = the ground alone (the paper's sec. 4.1 set-up; off by default: on
             the three synthetic scenes it scored worse than plain peeling at L = 2, 3 and no
             better at L = 4, docs/depthwarp.md);
  warp       ``ibrtools.depthwarp.core.warp_depth`` (motion buffers, min-max motion mipmaps, tight or
             oriented bounds, N seeds x T fixed-point iterations, cross-layer seeding, dilation) or,
             with ``forward`` vfw / afw, the forward baselines ``forward_warp_depth`` through the
             same path;
  cull       (``cull``) warping-based occlusion culling of the scene's objects with the warp's
             proven occluder depth (the peel's object ids as surface ids; ``ibrtools.depthwarp.culling``,
             docs/culling.md), scored against the objects the reference render of frame t sees;
  reference  the Embree depth render of frame t: the ground truth of the scores and the cost the
             warp replaces.

Frame 0 has no previous frame: its output is the reference depth (report "source": null).

Output image: the warped depth visualised (near bright, far dark: grey level 1 - z / far,
sRGB-encoded), holes black; ``"depth"`` the warped z (0 in holes; ``--depth`` writes it as EXR),
``"hole"`` the pixels no layer converged for (after dilation).

Scores (report.json "metrics" of each warped frame):
  depth_psnr, depth_ssim  of the warped depth against the reference depth of the same frame,
      both normalised by ``far``: the largest camera z of the 8 corners of the mesh's bounding
      box in that frame's camera (the farthest any surface can be), with empty pixels at far and
      the warp's holes filled with the background depth around them (``fill_background``; the
      paper's single-layer warp "keeps holes (filled with the background depth)", sec. 4.1),
      clamped to [0, far]; PSNR = 10 log10(1 / MSE) of z / far; SSIM with data range 1
      (ibrtools.metrics.ssim, scikit-image's).
  hole_fraction  fraction of the frame's pixels that are holes.
Stage times (report "time_ms"): peel, motion, mipmap, warp, dilate, cull, reference; the frame's
"depthwarp" entry adds warp_ms (motion + mipmap + warp + dilate: the predicted depth buffer's
cost), reference_ms and their ratio, the per-layer fill of the source buffer and the warp stats.

Parameters (flags of ibr-render or ``--param key=value``)
  layers            L in 1..16 (default 3)
  seeds, iters      N in 1..256 (default 16), T in 1..64 (default 3)
  threshold         convergence threshold in pixels, (0, 1e6] (default 0.5)
  oriented_bounds   PCA-oriented search bounds (default false)
  umbra             generalised umbra culling while peeling (default false)
  ground            "none" (default: L peeled layers), "auto" (object 0 as the ground layer
                    when L >= 2 and the mesh has several objects), or an object id
  cull              warping-based occlusion culling (default false); turns dilation off (a
                    dilated hole holds an occluder's depth and could cull what shows through it)
  forward           "none" (the iterative backward warp), "vfw" or "afw" (forward baselines)
  dilate            fill small holes surrounded by converged pixels (default true)
  bound             "tight" (default) or "global"
  far_plane         empty source pixels of layer 0 warp as a far plane (default true; see
                    ``warp_with_far_plane``)
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ibrtools import _core
from ibrtools.camera import PINHOLE, Camera
from ibrtools.errors import BadValueError, InputError, NotBuiltError, ParamError
from ibrtools.scene import Scene
from ibrtools import params as P
from ibrtools.depthwarp.core import DepthWarpParams, forward_warp_depth, warp_depth
from ibrtools.imageio import srgb_to_linear
from ibrtools.inpaint.pushpull import nearest_covered
from ibrtools.metrics import psnr, ssim

# seeds, iters, threshold, dilate, bound: the kernel's defaults, defined once (cpp/kernels/depthwarp/front.h).
_KERNEL = _core.DEPTHWARP_DEFAULTS
FORWARD = ("none", "vfw", "afw")
# Upper bounds of the numeric parameters (docs/depthwarp.md "Parameters"), checked for ibr-render,
# ibr-bench and DepthWarpMethod alike. The kernels take up to 127 layers, 4096 seeds and 1000
# iterations (cpp/bindings/depthwarp.cpp); the method's bounds are lower:
# layers  the deep buffer holds 8 bytes a pixel a layer (z + object id) and the warp's min-max
#         motion mipmaps as much again: ~2 GB at 3840x2160 for 16 layers; the paper peels <= 4;
# seeds x iters  fixed-point steps per pixel and layer: 256 x 64 is 340x the default 16 x 3,
#         minutes per 1080p frame already; the kernel's bounds multiply to hours.


def _ground(g, name: str) -> str | int:
    """"auto", "none" or an object id (int32)."""
    if isinstance(g, str) and g.strip().lower() in ("auto", "none"):
        return g.strip().lower()
    try:
        return P.to_integer(g, name, 0, 2**31 - 1)
    except ParamError:
        raise ParamError(name, f"expected auto, none or an object id (an integer >= 0 and <= {2**31 - 1}), "
                               f"got {g!r}") from None


@dataclass(frozen=True)
class DepthWarpMethodParams(P.MethodParams):
    """Parameters of ``--method depthwarp`` (the module doc)."""

    method: ClassVar[str] = "depthwarp"
    layers: int = P.integer(3, 1, 16)
    seeds: int = P.integer(_KERNEL["seeds"], 1, 256)
    iters: int = P.integer(_KERNEL["iters"], 1, 64)
    threshold: float = P.number(_KERNEL["threshold"], 0.0, strict=True, maximum=P.FINITE_MAX)
    oriented_bounds: bool = P.boolean(False)
    umbra: bool = P.boolean(False)
    ground: str | int = P.custom("none", _ground)
    cull: bool = P.boolean(False)
    forward: str = P.choice("none", FORWARD)
    dilate: bool = P.boolean(_KERNEL["dilate"])
    bound: str = P.choice(_KERNEL["bound"], ("tight", "global"))
    far_plane: bool = P.boolean(True)


def fill_background(depth: np.ndarray, hole: np.ndarray, far: float) -> np.ndarray:
    """``depth`` with its holes filled by the background depth around them: each hole pixel takes
    the largest depth of the nearest known pixels to its left, right, top and bottom (the far
    side of a disocclusion; Lee et al. sec. 4.1: the single-layer warp "keeps holes (filled with
    the background depth)"; the classic DIBR background fill). Empty pixels (0) count as ``far``;
    a hole with no known pixel in its row and column is ``far``. Vectorised (no pixel loop)."""
    d = np.where(depth > 0, depth, np.float32(far)).astype(np.float32)
    hole = np.asarray(hole, bool)
    if not hole.any():
        return d
    ys, xs = np.nonzero(hole)
    best = np.full(len(ys), -np.inf, np.float32)
    for ny, nx, found in nearest_covered(hole):
        best = np.maximum(best, np.where(found, d[np.where(found, ny, 0), np.where(found, nx, 0)], -np.inf))
    out = d.copy()
    out[ys, xs] = np.where(np.isfinite(best), best, np.float32(far))
    return out


HOLE_SCORING = ("background", "far")


def depth_scores(warped: np.ndarray, hole: np.ndarray | None, reference: np.ndarray, far: float,
                 holes: str = "background") -> dict:
    """Depth PSNR / SSIM of ``warped`` against ``reference`` (module doc: z / far, empty at far) and
    the hole fraction. ``holes``: "background" (the report's scores: holes filled with the background
    depth by :func:`fill_background`, what a user of the depth image gets) or "far" (holes at far:
    what occlusion culling sees)."""
    far = float(far)
    if not far > 0:
        raise BadValueError(f"far: expected a positive depth, got {far}")
    if holes not in HOLE_SCORING:
        raise BadValueError(f"holes: expected one of {HOLE_SCORING}, got {holes!r}")
    if hole is None:
        hole = np.zeros(warped.shape, bool)
    if holes == "far":
        w = np.where(np.asarray(hole, bool) | ~(warped > 0), np.float32(far), warped).astype(np.float32)
    else:
        w = fill_background(warped, hole, far)
    r = np.where(reference > 0, reference, far)
    a = (np.clip(w, 0.0, far) / far).astype(np.float32)
    b = (np.clip(r, 0.0, far) / far).astype(np.float32)
    p = psnr(a, b, 1.0)
    return {"depth_psnr": float(p) if p is not None and np.isfinite(p) else None,
            "depth_ssim": float(ssim(a, b, 1.0)),
            "hole_fraction": float(hole.mean())}


def far_depth(bounds: np.ndarray, camera: Camera) -> float:
    """The largest camera z of the 8 corners of ``bounds`` (2, 3): no surface is farther."""
    b = np.asarray(bounds, np.float64)
    corners = np.array([[b[i, 0], b[j, 1], b[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    z = corners @ camera.cam_from_world[2, :3] + camera.cam_from_world[2, 3]
    return float(max(z.max(), 1e-6))


def visualise(depth: np.ndarray, far: float) -> np.ndarray:
    """(H, W, 3) linear RGB whose sRGB grey level is 1 - z / far (0 where z = 0)."""
    v = np.where(depth > 0, 1.0 - np.clip(depth / far, 0.0, 1.0), 0.0).astype(np.float32)
    return np.ascontiguousarray(np.repeat(srgb_to_linear(v)[..., None], 3, axis=2), np.float32)


def warp_with_far_plane(layers: np.ndarray, src: Camera, dst: Camera, bounds: np.ndarray, forward: str = "none",
                        params=None, far_plane: bool = True, surface_ids: np.ndarray | None = None):
    """Warp a deep depth buffer (L, H, W) from ``src`` into ``dst`` (``forward`` "none" = the
    iterative backward warp with ``params``, else "vfw" / "afw"), returning the WarpResult with
    ``depth`` 0 in holes and where nothing is.

    ``far_plane``: like a cleared GL depth buffer, the empty pixels of layer 0 become a surface
    at z = 2 far_src (far_src: the farthest corner of the scene ``bounds`` in src, so the plane is
    behind every surface), so that the background's motion converges instead of leaving holes;
    a converged depth beyond far_dst (no surface can be farther in dst) is that plane: reported
    as empty (depth 0), not as a hole. ``surface_ids`` (L, H, W) int32 (the layers' object ids; backward
    warp only): the result's ``occluder`` is the proven occluder depth (``warp_depth``); the far plane
    has no surface id, so it never proves a depth."""
    layers = np.ascontiguousarray(layers[None] if layers.ndim == 2 else layers, np.float32)
    if far_plane:
        layers = layers.copy()
        layers[0][layers[0] <= 0] = np.float32(2.0 * far_depth(bounds, src))
    if forward == "none":
        res = warp_depth(layers, src, dst, params, surface_ids=surface_ids)
    else:
        res = forward_warp_depth(layers, src, dst, forward)
    hole = np.asarray(res.hole, bool)
    depth = np.where(hole, np.float32(0), res.depth)
    if far_plane:
        depth = np.where(depth > far_depth(bounds, dst), np.float32(0), depth)
    res.depth = np.ascontiguousarray(depth, np.float32)
    res.hole = hole
    return res


def _jsonable(v):
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if np.isfinite(v) else None
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    return v if isinstance(v, (str, type(None))) else str(v)


class DepthWarpMethod:
    """``--method depthwarp`` (see the module doc)."""

    name = "depthwarp"
    image_is_depth = True  # its image is the warped depth visualised: not completed (inpaint/complete.py)

    def __init__(self, params: dict | DepthWarpMethodParams | None = None):
        self.params = DepthWarpMethodParams.from_dict(params)
        self._renderer = None
        self._prev: Camera | None = None
        self.last_frame: dict = {}
        self.last_metrics: dict = {}

    def prepare(self, scene: Scene) -> dict[str, float]:
        from ibrtools.raycast.reference import ReferenceRenderer

        mesh = scene.meshes.get("ground_truth") or scene.mesh
        if mesh is None:
            raise InputError.about("method", "needs the scene's geometry (a synthetic scene, or a mesh "
                                   "given to ibr-preprocess): the scene has no mesh", "depthwarp")
        try:
            from ibrtools.depthwarp import core as _dw  # noqa: F401
        except ImportError:
            raise NotBuiltError.about("method", "the depth-warping kernels (ibrtools.depthwarp.core) are "
                                      "not built yet", "depthwarp") from None
        self._mesh = mesh
        p = self.params
        ground = p.ground
        if ground == "auto":
            ground = 0 if p.layers >= 2 and mesh.num_objects > 1 and np.any(mesh.object_ids == 0) else None
        elif ground == "none":
            ground = None
        else:
            if p.layers < 2:
                raise ParamError("ground", "a ground-only last layer needs layers >= 2")
            if not np.any(mesh.object_ids == ground):
                raise ParamError("ground", f"no face of the mesh has object id {ground}")
        self._ground = ground
        t0 = time.perf_counter()
        self._renderer = ReferenceRenderer(mesh)
        setup = {"bvh": (time.perf_counter() - t0) * 1e3}
        self._bounds = mesh.bounds()
        if p.cull:
            from ibrtools.depthwarp.culling import object_boxes

            t1 = time.perf_counter()
            self._boxes = object_boxes(mesh)
            setup["object_boxes"] = (time.perf_counter() - t1) * 1e3
        self._prev = None
        return setup

    def _warp_params(self):
        p = self.params
        # Culling needs conservative holes: a dilated hole takes a neighbour's (occluder's) depth
        # and culled a 5-px object seen through a 1-px gap (docs/culling.md), so --cull warps
        # without dilation (the report says so).
        return DepthWarpParams(seeds=p.seeds, iters=p.iters, threshold=p.threshold, bound=p.bound,
                               oriented=p.oriented_bounds, dilate=p.dilate and not p.cull)

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        if self._renderer is None:
            raise InputError("depthwarp: prepare(scene) must be called before render(camera)")
        if camera.model != PINHOLE:
            raise BadValueError(f"camera: {camera.model} cameras are not supported by depthwarp (pinhole only)")
        p = self.params
        far = far_depth(self._bounds, camera)
        stages: dict[str, float] = {}
        src, self._prev = self._prev, camera
        if src is None:
            t0 = time.perf_counter()
            ref = self._renderer.render(camera, outputs=("depth",), lights=[])["depth"]
            stages["reference"] = (time.perf_counter() - t0) * 1e3
            hole = np.zeros(ref.shape, bool)
            self.last_frame = {"depthwarp": {"source": None, "note": "first frame: the reference depth "
                                             "(no previous frame to warp from)", "reference_ms": stages["reference"]}}
            self.last_metrics = {}
            return {"color": visualise(ref, far), "depth": ref, "hole": hole}, stages

        deep = self._renderer.peel(src, p.layers, umbra=[camera] if p.umbra else None,
                                   ground_object=self._ground)
        stages["peel"] = sum(deep.times_ms.values())
        backward = p.forward == "none"
        res = warp_with_far_plane(deep.depth, src, camera, self._bounds, p.forward,
                                  self._warp_params() if backward else None, p.far_plane,
                                  surface_ids=deep.object_id if p.cull and backward else None)
        for k in ("motion", "mipmap", "warp", "dilate"):
            if k in res.times_ms:
                stages[k] = float(res.times_ms[k])
        warp_ms = sum(stages.get(k, 0.0) for k in ("motion", "mipmap", "warp", "dilate"))
        t0 = time.perf_counter()
        ref_out = self._renderer.render(camera, outputs=("depth", "object_id") if p.cull else ("depth",),
                                        lights=[])
        stages["reference"] = (time.perf_counter() - t0) * 1e3
        ref = ref_out["depth"]
        hole = np.asarray(res.hole, bool)
        depth = res.depth
        report = {"source": "previous frame", "layers": deep.layers, "ground_layer": deep.ground_layer,
                  "umbra": deep.umbra, "forward": p.forward,
                  "dilate": bool(p.dilate and not p.cull and p.forward == "none"),
                  "source_fill": [round(float(f), 6) for f in deep.fill],
                  "warp_ms": round(warp_ms, 3), "reference_ms": round(stages["reference"], 3),
                  "reference_over_warp": round(stages["reference"] / warp_ms, 3) if warp_ms > 0 else None,
                  "stats": {k: _jsonable(v) for k, v in dict(res.stats).items()}}
        self.last_frame = {"depthwarp": report}
        if p.cull:
            from ibrtools.depthwarp.culling import cull_objects

            t0 = time.perf_counter()
            # The backward warp's proven occluder depth (conservative); the forward baselines prove
            # nothing, so they cull with their depth and holes (docs/culling.md).
            if res.occluder is not None:
                cr = cull_objects(res.occluder, None, camera, self._boxes)
            else:
                cr = cull_objects(np.ascontiguousarray(depth), hole, camera, self._boxes)
            stages["cull"] = (time.perf_counter() - t0) * 1e3
            ids = ref_out["object_id"]
            k = len(self._boxes)
            counts = np.bincount(ids[ids >= 0].ravel(), minlength=k)[:k]
            ev = cr.evaluate(np.flatnonzero(counts > 0), counts)
            ev["times_ms"] = {kk: round(float(v), 3) for kk, v in cr.times_ms.items()}
            self.last_frame["cull"] = ev
        self.last_metrics = depth_scores(depth, hole, ref, far)
        return {"color": visualise(depth, far), "depth": depth, "hole": hole}, stages

    def frame_report(self) -> dict:
        """What report.json records for the last frame (see the module doc)."""
        return dict(self.last_frame)

    def frame_metrics(self) -> dict:
        """Depth scores of the last frame (merged into its "metrics")."""
        return dict(self.last_metrics)
