"""PatchMatch multi-view stereo over a scene's views (docs/mvs.md).

For every reference view: its source views (:func:`select_sources`), its depth range
(:func:`depth_range`), then three passes over all references, each view independent of the
others within a pass:

1. photometric: ``_core.mvs_patchmatch`` from random planes (``iterations`` red/black passes),
2. geometric (``geom_iterations`` > 0): the same kernel started from pass 1, its cost adding
   ``geom_weight`` x the forward-backward reprojection error (px, capped at ``geom_max_error``)
   through the sources' pass-1 depth (Schonberger et al. 2016, sec. 4.4),
3. filter: a pixel keeps its depth when its cost is below ``max_cost`` and at least
   ``min_consistent`` sources agree with it (``_core.mvs_consistent_views``: reprojection within
   ``consistency_px``, depth within ``consistency_depth``, triangulation angle at least
   ``min_angle_deg``); the rest is unknown (0), as textureless windows are.

Outputs per view: depth (z, float32, 0 = unknown), normal (camera axes, float32 (H, W, 3)),
confidence (float32 in [0, 1]: 1 - cost / 2 where kept, else 0).
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable

import numpy as np

from ibrtools import _core
from ibrtools.camera import PINHOLE, Camera
from ibrtools.checks import check_float, check_int
from ibrtools.errors import BadValueError
from ibrtools.memory import available_memory
from ibrtools.imageio import linear_to_srgb

_K = _core.PatchMatchOptions()  # the kernel's defaults, defined once (cpp/kernels/mvs/patchmatch.h)


def _f(v: float) -> float:
    return float(f"{v:.6g}")  # float32 defaults as the decimal they were written as


# refine_only "auto": a view with at most this many sources runs the full candidate set at every
# level (13 planes a pixel and source instead of 7): 2 sources x 13 cost less per pixel than the
# default 6 x 7, and with one or two sources the full set is the more accurate (docs/mvs.md
# "Choices, measured": Middlebury's two views, bad-2.0 lower on all 5 pairs); with more sources
# refine-only keeps the kept pixels more accurate for 1.7x less CPU (synth:objects).
AUTO_FULL_SOURCES = 2


@dataclass
class MvsOptions:
    """Parameters of the ``mvs`` stage (``--set mvs.KEY=VALUE``; docs/mvs.md has the table)."""

    sources: int = 6                  # source views per reference view (1..32)
    window_radius: int = _K.window_radius
    window_step: int = _K.window_step
    sigma_color: float = _f(_K.sigma_color)
    sigma_spatial: float = _f(_K.sigma_spatial)
    iterations: int = _K.iterations   # photometric red/black iterations at the coarsest level
    levels: int = 3                   # image pyramid levels (1: full resolution only)
    fine_iterations: int = 2          # iterations at each finer level, started from the coarser one
    refine_only: bool | str = "auto"  # finer levels and the geometric pass: near neighbours and
                                      #   perturbations only (no random planes, no far neighbours);
                                      #   "auto": so for a view with more than AUTO_FULL_SOURCES sources
    best_k: int = _K.best_k           # source costs aggregated per hypothesis
    seed: int = 0
    min_variance: float = _f(_K.min_variance)
    geom_iterations: int = 1          # geometric-consistency iterations (0: none)
    geom_weight: float = 0.2
    geom_max_error: float = _f(_K.geom_max_error)
    max_cost: float = 0.8             # filter: aggregated cost (photometric + geometric) below this
    min_consistent: int = 2           # filter: consistent sources (at most the view's source count)
    consistency_px: float = 1.0
    consistency_depth: float = 0.01
    min_angle_deg: float = 1.0
    depth_range: str = "auto"         # "auto" or "MIN,MAX" (z, scene units)

    def __post_init__(self) -> None:
        self.check()

    def check(self) -> None:
        """Bounds of every option (BadValueError naming ``mvs.KEY``); the kernel's own options
        are checked by the kernel's Check() (one definition of their bounds)."""
        self.sources = check_int(self.sources, "mvs.sources", 1, _core.MVS_MAX_SOURCE_VIEWS)
        self.geom_iterations = check_int(self.geom_iterations, "mvs.geom_iterations", 0, _core.MVS_MAX_ITERATIONS)
        self.levels = check_int(self.levels, "mvs.levels", 1, 6)
        self.iterations = check_int(self.iterations, "mvs.iterations", 0, _core.MVS_MAX_ITERATIONS)
        self.fine_iterations = check_int(self.fine_iterations, "mvs.fine_iterations", 0, _core.MVS_MAX_ITERATIONS)
        self.min_consistent = check_int(self.min_consistent, "mvs.min_consistent", 0, _core.MVS_MAX_SOURCE_VIEWS)
        self.seed = check_int(self.seed, "mvs.seed", 0, 2 ** 63 - 1)
        for k in ("max_cost", "consistency_px", "consistency_depth", "min_angle_deg"):
            setattr(self, k, check_float(getattr(self, k), f"mvs.{k}", 0.0))
        if not 0 < self.max_cost <= 2:
            raise BadValueError(f"mvs.max_cost: expected a cost in (0, 2], got {self.max_cost}")
        if self.consistency_px <= 0 or self.consistency_depth <= 0 or self.min_angle_deg >= 90:
            raise BadValueError("mvs.consistency_px, mvs.consistency_depth: expected > 0; mvs.min_angle_deg: < 90")
        if not (isinstance(self.refine_only, bool) or self.refine_only == "auto"):
            raise BadValueError(f"mvs.refine_only: expected true, false or auto, got {self.refine_only!r}")
        parse_range(self.depth_range)
        o = self.kernel_options(1.0, 2.0)
        o.check()

    def kernel_options(self, min_depth: float, max_depth: float, geometric: bool = False, level: int = 0,
                       sources: int | None = None):
        """The kernel's options for a pass of a view with ``sources`` source views: photometric at
        pyramid ``level`` (0 = full resolution; the coarsest level runs ``iterations`` from random
        planes, each finer one ``fine_iterations`` from the coarser result, continuing its
        refinement schedule), or geometric (at full resolution, after them)."""
        o = _core.PatchMatchOptions()
        for k in ("window_radius", "window_step", "sigma_color", "sigma_spatial", "best_k", "seed", "min_variance",
                  "geom_max_error"):
            setattr(o, k, getattr(self, k))
        steps = self.levels - 1 - level  # levels between the coarsest and this one
        refine = self.refine_only if isinstance(self.refine_only, bool) else \
            (sources is None or sources > AUTO_FULL_SOURCES)
        o.refine_only = refine and (geometric or steps > 0)
        if geometric:
            o.iterations = self.geom_iterations
            o.first_iteration = self.iterations + self.fine_iterations * (self.levels - 1)
        elif steps == 0:
            o.iterations, o.first_iteration = self.iterations, 0
        else:
            o.iterations = self.fine_iterations
            o.first_iteration = self.iterations + self.fine_iterations * (steps - 1)
        o.geom_weight = self.geom_weight if geometric else 0.0
        o.min_depth, o.max_depth = float(min_depth), float(max_depth)
        return o

    def to_dict(self) -> dict:
        return asdict(self)


def parse_range(text: str) -> tuple[float, float] | None:
    """``"auto"`` -> None; ``"MIN,MAX"`` -> (MIN, MAX) with 0 < MIN < MAX finite."""
    if text == "auto":
        return None
    try:
        lo, hi = (float(v) for v in str(text).split(","))
    except ValueError:
        raise BadValueError(f"mvs.depth_range: expected 'auto' or MIN,MAX, got {text!r}") from None
    if not (0 < lo < hi < math.inf):
        raise BadValueError(f"mvs.depth_range: expected 0 < MIN < MAX (finite), got {text!r}")
    return lo, hi


@dataclass
class MvsResult:
    """One view's multi-view stereo: depth (z, 0 = unknown), normal (H, W, 3), confidence."""

    depth: np.ndarray
    normal: np.ndarray
    confidence: np.ndarray
    sources: list[str]
    depth_range: tuple[float, float]
    stats: dict = field(default_factory=dict)


def grey(color: np.ndarray) -> np.ndarray:
    """The matching image of a view: Rec. 709 luminance of linear RGB, sRGB-encoded (the NCC is
    invariant to gain and offset, not to the curve: texture is matched where it is visible)."""
    c = np.asarray(color, np.float32)
    y = c[..., 0] * np.float32(0.2126) + c[..., 1] * np.float32(0.7152) + c[..., 2] * np.float32(0.0722)
    return np.ascontiguousarray(linear_to_srgb(y), np.float32)


def _centre(cam: Camera) -> np.ndarray:
    r, t = cam.cam_from_world[:3, :3], cam.cam_from_world[:3, 3]
    return -r.T @ t


def _axis(cam: Camera) -> np.ndarray:
    return cam.cam_from_world[2, :3].astype(np.float64)  # the camera's z axis in world axes


def capture_focus(cameras: list[Camera]) -> tuple[np.ndarray | None, float]:
    """What the automatic depth ranges of a capture are made of, computed once for all its views:
    the point nearest to every camera's optical axis (least squares; None when the axes are
    nearly parallel) and the median distance between neighbouring camera centres."""
    centres = np.array([_centre(c) for c in cameras])
    axes = np.array([_axis(c) for c in cameras])
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for c, d in zip(centres, axes):
        p = np.eye(3) - np.outer(d, d)
        a += p
        b += p @ c
    point = None
    if len(cameras) >= 2 and np.linalg.eigvalsh(a)[0] > 1e-3 * len(cameras):
        point = np.linalg.solve(a, b)
    gaps = [np.min(np.linalg.norm(np.delete(centres, i, 0) - c, axis=1)) for i, c in enumerate(centres)]
    return point, float(np.median(gaps)) if len(centres) > 1 else 0.0


def depth_range(cam: Camera, cameras: list[Camera], option: str = "auto",
                focus: tuple[np.ndarray | None, float] | None = None) -> tuple[float, float]:
    """The depth (z) range searched in view ``cam``: ``option`` "MIN,MAX", else "auto": the point
    nearest to every camera's optical axis (the object a capture circles or faces) at depth z_c in
    the view, and [z_c / 4, 4 z_c]. Cameras whose axes are (nearly) parallel have no such point:
    then z_c is 20 x the median distance between neighbouring camera centres. ``focus``: the
    capture's :func:`capture_focus`, when the caller has it."""
    given = parse_range(option)
    if given is not None:
        return given
    point, gap = focus if focus is not None else capture_focus(cameras)
    zc = None
    if point is not None:
        zc = float((cam.cam_from_world[:3, :3] @ point + cam.cam_from_world[:3, 3])[2])
    if zc is None or not zc > 0:
        if not gap > 0:
            raise BadValueError.about("stage_options", "mvs: cannot find a depth range (the cameras share one "
                                                       "centre); give it as mvs.depth_range=MIN,MAX")
        zc = 20.0 * gap
    return zc / 4.0, zc * 4.0


def _angle_weight(theta_deg: np.ndarray) -> np.ndarray:
    """The view-pair weight of a triangulation angle (MVSNet's piecewise Gaussian, Yao et al.
    2018 sec. 4.1: peak at 5 degrees, sigma 1 below and 10 above)."""
    t = np.asarray(theta_deg)
    return np.where(t <= 5.0, np.exp(-(t - 5.0) ** 2 / 2.0), np.exp(-(t - 5.0) ** 2 / 200.0))


def select_sources(ref: Camera, candidates: dict[str, Camera], k: int, zrange: tuple[float, float]
                   ) -> list[tuple[str, float]]:
    """The ``k`` best source views of ``ref`` among ``candidates``, best first, as (name, score):
    a 7 x 7 grid of the view's pixels at three depths of its range, each point that a candidate
    sees (in front of it, inside its image) scores the candidate the weight of its triangulation
    angle there (:func:`_angle_weight`). Candidates with no score (no overlap, no baseline) are
    never chosen."""
    zs = np.geomspace(zrange[0], zrange[1], 5)[1:4]
    us = (np.arange(7) + 0.5) / 7 * ref.width
    vs = (np.arange(7) + 0.5) / 7 * ref.height
    uu, vv = np.meshgrid(us, vs)
    rays = np.stack([(uu.ravel() - ref.cx) / ref.fx, (vv.ravel() - ref.cy) / ref.fy, np.ones(uu.size)], 1)
    r, t = ref.cam_from_world[:3, :3], ref.cam_from_world[:3, 3]
    pts = np.concatenate([(rays * z - t) @ r for z in zs])  # world points: R^T (X - t)
    c_ref = _centre(ref)
    scores = []
    for name, cam in candidates.items():
        c = _centre(cam)
        if not np.linalg.norm(c - c_ref) > 1e-9 * max(1.0, np.linalg.norm(c_ref)):
            continue
        pc = pts @ cam.cam_from_world[:3, :3].T + cam.cam_from_world[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = cam.fx * pc[:, 0] / pc[:, 2] + cam.cx
            v = cam.fy * pc[:, 1] / pc[:, 2] + cam.cy
        seen = (pc[:, 2] > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        if not seen.any():
            continue
        a = pts[seen] - c_ref
        b = pts[seen] - c
        cos = np.sum(a * b, 1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-30)
        theta = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        s = float(_angle_weight(theta).sum())
        if s > 1e-6:
            scores.append((name, s))
    scores.sort(key=lambda x: (-x[1], x[0]))
    return scores[:k]


def _half(img: np.ndarray) -> np.ndarray:
    """2 x 2 box average (an odd last row / column dropped): pixel i covers pixels 2i, 2i + 1."""
    h, w = img.shape[0] // 2 * 2, img.shape[1] // 2 * 2
    a = img[:h, :w]
    return np.ascontiguousarray(0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]), np.float32)


def _half_camera(cam: Camera) -> Camera:
    """The camera of :func:`_half`'s image: continuous coordinates halved, exactly."""
    return Camera.pinhole(cam.width // 2, cam.height // 2, cam.fx / 2, cam.fy / 2, cam.cx / 2, cam.cy / 2,
                          cam.cam_from_world)


def _upsample(a: np.ndarray, h: int, w: int) -> np.ndarray:
    """A coarser level's per-pixel array at the finer size (h, w): each fine pixel takes its
    coarse parent's value (the last row / column that :func:`_half` dropped, its neighbour's)."""
    ys = np.minimum(np.arange(h) // 2, a.shape[0] - 1)
    xs = np.minimum(np.arange(w) // 2, a.shape[1] - 1)
    return np.ascontiguousarray(a[ys][:, xs], np.float32)


# Bytes held per pixel of every view in a run (colour float32 x 3 as loaded, the grey pyramid,
# the passes' depth, normal and cost of the views matched, the filter's copies): peak RSS of
# fountain-P11's 10 views (3.9 M pixels) measured 356 MB with /usr/bin/time -v, i.e. ~40 B a pixel
# above the interpreter; rounded up to stay above it.
_BYTES_PER_PIXEL = 64
_BASE_BYTES = 400 << 20  # the interpreter, numpy, OpenImageIO, the engine (as pipeline/job.py)


def check_memory(views) -> int:
    """The run's memory estimate in bytes, after refusing (BadValueError with the estimate and
    the limit) a run that needs more than is available (ibrtools.memory.available_memory)."""
    px = sum(v.camera.width * v.camera.height for v in views)
    need, avail = px * _BYTES_PER_PIXEL + _BASE_BYTES, available_memory()
    if need > avail:
        gib = 1 << 30
        raise BadValueError(f"mvs: multi-view stereo of {len(views)} views ({px / 1e6:.1f} M pixels) needs about "
                            f"{need / gib:.1f} GiB, only {avail / gib:.1f} GiB is available"
                            f"{' (IBR_MEMORY_LIMIT)' if os.environ.get('IBR_MEMORY_LIMIT') else ''}: import the "
                            "views smaller, or free memory")
    return need


class MvsRun:
    """One multi-view stereo run: its plan (each reference view's sources and depth range, the
    pyramid's depth) made once from the cameras, and its passes as functions of one view each,
    so that they can run anywhere (a Dask task rebuilds the same plan from the scene: the plan
    and the kernels are deterministic). :func:`run_mvs` runs them in turn here."""

    def __init__(self, views, options: MvsOptions | None = None, names: list[str] | None = None,
                 bounds: dict[str, Any] | None = None, background: bool = False):
        self.o = o = options or MvsOptions()
        self.background = background  # run_mvs's: the filter writes +inf outside the views' masks
        self.views = {v.name: v for v in views}
        self.names = list(names) if names is not None else list(self.views)
        if len(self.views) < 2:
            raise BadValueError(f"mvs: multi-view stereo needs at least 2 views with cameras, the scene has "
                                f"{len(self.views)}")
        for v in self.views.values():
            if v.camera.model != PINHOLE:
                raise BadValueError(f"mvs: view {v.name!r} has a {v.camera.model} camera; multi-view stereo needs "
                                    "pinhole")
        check_memory(list(self.views.values()))
        cams = {n: v.camera for n, v in self.views.items()}
        focus = capture_focus(list(cams.values())) if o.depth_range == "auto" else None
        # A capture's own per-view bounds (LLFF's near/far: scene.source["depth_bounds"]) are the
        # "auto" range of their views; an explicit mvs.depth_range overrides them.
        given = bounds if o.depth_range == "auto" and bounds else {}
        self.ranges = {n: (float(given[n][0]), float(given[n][1])) if n in given
                       else depth_range(cams[n], list(cams.values()), o.depth_range, focus) for n in self.names}
        self.sources: dict[str, list[str]] = {}
        for n in self.names:
            sel = select_sources(cams[n], {m: c for m, c in cams.items() if m != n}, o.sources, self.ranges[n])
            if not sel:
                lo, hi = self.ranges[n]
                raise BadValueError(f"mvs: view {n!r} overlaps no other view (no source view sees its depth range "
                                    f"{lo:.4g}..{hi:.4g} with a baseline); give its depth or more views")
            self.sources[n] = [m for m, _ in sel]
        # The image pyramid: level l halves level l - 1 (2 x 2 box; an odd last row or column
        # dropped), as deep as every image allows (a window must not cover much of one).
        self.cameras = [cams]
        for _ in range(o.levels - 1):
            prev = self.cameras[-1]
            if min(min(c.width, c.height) for c in prev.values()) < 4 * (2 * o.window_radius + 1):
                break
            self.cameras.append({n: _half_camera(c) for n, c in prev.items()})
        self._greys: dict[tuple[str, int], np.ndarray] = {}

    def grey(self, name: str, level: int = 0) -> np.ndarray:
        key = (name, level)
        if key not in self._greys:
            self._greys[key] = grey(self.views[name].color) if level == 0 else _half(self.grey(name, level - 1))
        return self._greys[key]

    def _foreground(self, name: str) -> np.ndarray | bool:
        """Where view ``name`` may have depth: its mask (alpha > 1/2 in an RGBA capture: the rest
        is known to be empty, a background, never a surface), else everywhere."""
        v = self.views[name]
        return np.asarray(v.mask, bool) if v.has_mask else True

    def _core_cams(self, names: list[str], level: int) -> list:
        return [self.cameras[level][m].to_core() for m in names]

    def photometric(self, n: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Pass 1 of view ``n``, coarse to fine: (depth, normal, cost, evaluations)."""
        o, src = self.o, self.sources[n]
        init = None
        evals = 0
        top = len(self.cameras) - 1
        for level in range(top, -1, -1):
            cams = self._core_cams([n, *src], level)
            args = (self.grey(n, level), cams[0], [self.grey(m, level) for m in src], cams[1:], None,
                    o.kernel_options(*self.ranges[n], level=level + o.levels - 1 - top, sources=len(src)))
            if init is None:
                d, nrm, c, st = _core.mvs_patchmatch(*args)
            else:
                cam = self.cameras[level][n]
                up = [_upsample(a, cam.height, cam.width) for a in init]
                d, nrm, c, st = _core.mvs_patchmatch(*args, up[0], up[1])
                # A window that is textureless here may not be at the coarser level (a larger part
                # of the scene): such pixels keep the coarser level's plane and cost.
                flat = (d <= 0) & (up[0] > 0)
                d, c = np.where(flat, up[0], d), np.where(flat, up[2], c)
                nrm = np.where(flat[..., None], up[1], nrm)
            evals += st["evaluations"]
            init = (d, nrm, c)
        return d, nrm, c, evals

    def known_depth(self, m: str, result: tuple | None) -> np.ndarray | None:
        """A source's depth for the later passes: this run's result (depth, normal, cost, ...) when
        given (unknown where costly), else its own, else None (a source without depth adds no
        geometric term and no consistency vote)."""
        if result is not None:
            return np.where((result[2] < self.o.max_cost) & self._foreground(m), result[0],
                            np.float32(0)).astype(np.float32)
        v = self.views[m]
        return np.ascontiguousarray(v.depth, np.float32) if v.has_depth else None

    def geometric(self, n: str, result: tuple, depths: dict[str, np.ndarray | None]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Pass 2 of view ``n`` from its pass-1 ``result``; ``depths``: the sources' known depth."""
        src = self.sources[n]
        cams = self._core_cams([n, *src], 0)
        d, nrm, c, st = _core.mvs_patchmatch(self.grey(n), cams[0], [self.grey(m) for m in src], cams[1:],
                                             [depths[m] for m in src],
                                             self.o.kernel_options(*self.ranges[n], geometric=True, sources=len(src)),
                                             result[0], result[1])
        return d, nrm, c, st["evaluations"]

    def filter(self, n: str, result: tuple, depths: dict[str, np.ndarray | None]) -> MvsResult:
        """Pass 3 of view ``n``: its final ``result`` kept where the cost is low and enough sources
        (``depths``: their final known depth) agree."""
        o = self.o
        d, nrm, c = result[0], result[1], result[2]
        voters = [m for m in self.sources[n] if depths[m] is not None]
        cams = self._core_cams([n, *voters], 0)
        mine = np.where(c < o.max_cost, d, np.float32(0)).astype(np.float32)
        count = _core.mvs_consistent_views(mine, cams[0], [depths[m] for m in voters], cams[1:], o.consistency_px,
                                           o.consistency_depth, o.min_angle_deg)
        foreground = self._foreground(n)
        keep = (c < o.max_cost) & (d > 0) & (count >= min(o.min_consistent, len(voters))) & foreground
        depth = np.where(keep, d, np.float32(0)).astype(np.float32)
        empty = 0
        if self.background and self.views[n].has_mask:  # outside the mask: the background at infinity
            depth[~foreground] = np.inf
            empty = int((~foreground).sum())
        return MvsResult(depth, np.where(keep[..., None], nrm, np.float32(0)).astype(np.float32),
                         np.where(keep, 1.0 - c / 2.0, 0.0).astype(np.float32), self.sources[n], self.ranges[n],
                         {"kept": float(keep.mean()), "background": empty})

    def finish(self, out: dict[str, MvsResult], timing: dict[str, float], evals: dict[str, int]) -> None:
        """The run's figures in every view's stats."""
        total, secs = sum(evals.values()), timing.get("photometric", 0.0) + timing.get("geometric", 0.0)
        for res in out.values():
            res.stats.update({"seconds": {k: round(v, 3) for k, v in timing.items()}, "evaluations": dict(evals),
                              "evaluations_per_second": round(total / secs) if secs > 0 else None})


# run_mvs's ``run_pass``: (pass, views, previous) -> {view: (depth, normal, cost, evaluations)}, with
# previous None for "photometric" and {"results": pass-1 results, "known": sources' known depth}
# for "geometric" (the default runs MvsRun.photometric / MvsRun.geometric here, view by view).
PassRunner = Callable[[str, list[str], dict | None], dict]


def run_mvs(views, options: MvsOptions | None = None, names: list[str] | None = None,
            progress: Callable[[str], None] | None = None, run_pass: PassRunner | None = None,
            bounds: dict[str, Any] | None = None, background: bool = False) -> dict[str, MvsResult]:
    """Multi-view stereo of the views ``names`` (default: every view) of ``views`` (a list of
    :class:`ibrtools.scene.View` with colour and pinhole cameras); every view may be a source.
    Views that have depth of their own serve it to the geometric pass and the filter.
    ``run_pass`` runs a pass over views elsewhere (the stage's Dask workers, which rebuild the
    same :class:`MvsRun` from the scene); the filter always runs here. ``bounds``: {view: (near,
    far)}, the capture's own depth range of those views (used when ``depth_range`` is "auto").
    ``background``: the scene has a uniform background (``shading.background``: an RGBA capture
    composited over a colour), so what a view's mask leaves out is the background at infinity:
    depth +inf there (docs/FORMAT.md "Background"), not unknown."""
    t0 = time.perf_counter()
    run = MvsRun(views, options, names, bounds, background)

    def here(which: str, todo: list[str], previous: dict | None) -> dict:
        out = {}
        for n in todo:
            if progress:
                progress(f"mvs {which} {n}")
            out[n] = (run.photometric(n) if previous is None else
                      run.geometric(n, previous["results"][n], previous["known"]))
        return out

    run_pass = run_pass or here
    timing = {"setup": time.perf_counter() - t0, "photometric": 0.0, "geometric": 0.0, "filter": 0.0}
    evals = {"photometric": 0, "geometric": 0}
    t1 = time.perf_counter()
    results = run_pass("photometric", run.names, None)
    timing["photometric"] = time.perf_counter() - t1
    evals["photometric"] = sum(r[3] for r in results.values())
    involved = set(run.names) | {m for n in run.names for m in run.sources[n]}
    if run.o.geom_iterations > 0:
        first = {m: run.known_depth(m, results.get(m)) for m in involved}
        t1 = time.perf_counter()
        results = run_pass("geometric", run.names, {"results": results, "known": first})
        timing["geometric"] = time.perf_counter() - t1
        evals["geometric"] = sum(r[3] for r in results.values())
    final = {m: run.known_depth(m, results.get(m)) for m in involved}
    t1 = time.perf_counter()
    out = {n: run.filter(n, results[n], final) for n in run.names}
    timing["filter"] = time.perf_counter() - t1
    run.finish(out, timing, evals)
    return out
