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
import time
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from .. import _core
from ..camera import PINHOLE, Camera
from ..checks import check_float, check_int
from ..errors import BadValueError

_K = _core.PatchMatchOptions()  # the kernel's defaults, defined once (cpp/kernels/mvs/patchmatch.h)


def _f(v: float) -> float:
    return float(f"{v:.6g}")  # float32 defaults as the decimal they were written as


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
    refine_only: bool = True          # finer levels and the geometric pass: near neighbours and
                                      #   perturbations only (no random planes, no far neighbours)
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
        parse_range(self.depth_range)
        o = self.kernel_options(1.0, 2.0)
        o.check()

    def kernel_options(self, min_depth: float, max_depth: float, geometric: bool = False, level: int = 0):
        """The kernel's options for a pass: photometric at pyramid ``level`` (0 = full resolution;
        the coarsest level runs ``iterations`` from random planes, each finer one
        ``fine_iterations`` from the coarser result, continuing its refinement schedule), or
        geometric (at full resolution, after them)."""
        o = _core.PatchMatchOptions()
        for k in ("window_radius", "window_step", "sigma_color", "sigma_spatial", "best_k", "seed", "min_variance",
                  "geom_max_error"):
            setattr(o, k, getattr(self, k))
        steps = self.levels - 1 - level  # levels between the coarsest and this one
        o.refine_only = bool(self.refine_only) and (geometric or steps > 0)
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
    from ..imageio import linear_to_srgb

    c = np.asarray(color, np.float32)
    y = c[..., 0] * np.float32(0.2126) + c[..., 1] * np.float32(0.7152) + c[..., 2] * np.float32(0.0722)
    return np.ascontiguousarray(linear_to_srgb(y), np.float32)


def _centre(cam: Camera) -> np.ndarray:
    r, t = cam.cam_from_world[:3, :3], cam.cam_from_world[:3, 3]
    return -r.T @ t


def _axis(cam: Camera) -> np.ndarray:
    return cam.cam_from_world[2, :3].astype(np.float64)  # the camera's z axis in world axes


def depth_range(cam: Camera, cameras: list[Camera], option: str = "auto") -> tuple[float, float]:
    """The depth (z) range searched in view ``cam``: ``option`` "MIN,MAX", else "auto": the point
    nearest to every camera's optical axis (least squares; the object a capture circles or faces)
    at depth z_c in the view, and [z_c / 4, 4 z_c]. Cameras whose axes are (nearly) parallel have
    no such point: then z_c is 20 x the median distance between neighbouring camera centres."""
    given = parse_range(option)
    if given is not None:
        return given
    centres = np.array([_centre(c) for c in cameras])
    axes = np.array([_axis(c) for c in cameras])
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for c, d in zip(centres, axes):
        p = np.eye(3) - np.outer(d, d)
        a += p
        b += p @ c
    w = np.linalg.eigvalsh(a)
    zc = None
    if len(cameras) >= 2 and w[0] > 1e-3 * len(cameras):
        x = np.linalg.solve(a, b)
        zc = float((cam.cam_from_world[:3, :3] @ x + cam.cam_from_world[:3, 3])[2])
    if zc is None or not zc > 0:
        gaps = [np.min(np.linalg.norm(np.delete(centres, i, 0) - c, axis=1)) for i, c in enumerate(centres)]
        gap = float(np.median(gaps)) if len(centres) > 1 else 0.0
        if not gap > 0:
            raise BadValueError("mvs: cannot find a depth range (the cameras share one centre); "
                                "give it with --set mvs.depth_range=MIN,MAX")
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


def run_mvs(views, options: MvsOptions | None = None, names: list[str] | None = None,
            progress: Callable[[str], None] | None = None) -> dict[str, MvsResult]:
    """Multi-view stereo of the views ``names`` (default: every view) of ``views`` (a list of
    :class:`ibrtools.scene.View` with colour and pinhole cameras); every view may be a source.
    Views that have depth of their own serve it to the geometric pass and the filter."""
    o = options or MvsOptions()
    views = list(views)
    by_name = {v.name: v for v in views}
    names = list(names) if names is not None else [v.name for v in views]
    if len(views) < 2:
        raise BadValueError(f"mvs: multi-view stereo needs at least 2 views with cameras, the scene has {len(views)}")
    for v in views:
        if v.camera.model != PINHOLE:
            raise BadValueError(f"mvs: view {v.name!r} has a {v.camera.model} camera; multi-view stereo needs pinhole")
    cams = {v.name: v.camera for v in views}
    t0 = time.perf_counter()
    greys = {n: grey(by_name[n].color) for n in by_name}
    core = {n: c.to_core() for n, c in cams.items()}
    ranges = {n: depth_range(cams[n], list(cams.values()), o.depth_range) for n in names}
    chosen: dict[str, list[str]] = {}
    for n in names:
        sel = select_sources(cams[n], {m: c for m, c in cams.items() if m != n}, o.sources, ranges[n])
        if not sel:
            raise BadValueError(f"mvs: view {n!r} overlaps no other view (no source view sees its depth range "
                                f"{ranges[n][0]:.4g}..{ranges[n][1]:.4g} with a baseline); give its depth or more views")
        chosen[n] = [m for m, _ in sel]
    timing = {"setup": time.perf_counter() - t0, "photometric": 0.0, "geometric": 0.0, "filter": 0.0}
    evals = {"photometric": 0, "geometric": 0}
    # The image pyramid: level l halves level l - 1 (2 x 2 box; an odd last row or column dropped).
    pyramid = [(greys, cams)]
    for _ in range(o.levels - 1):
        g_prev, c_prev = pyramid[-1]
        if min(min(c.width, c.height) for c in c_prev.values()) < 4 * (2 * o.window_radius + 1):
            break  # a window would cover much of the image: no coarser level
        pyramid.append(({n: _half(g) for n, g in g_prev.items()}, {n: _half_camera(c) for n, c in c_prev.items()}))
    results: dict[str, dict] = {}
    for n in names:
        if progress:
            progress(f"mvs photometric {n}")
        t1 = time.perf_counter()
        init = None
        for level in range(len(pyramid) - 1, -1, -1):
            g_l, c_l = pyramid[level]
            lc = {m: c_l[m].to_core() for m in [n, *chosen[n]]}
            args = (g_l[n], lc[n], [g_l[m] for m in chosen[n]], [lc[m] for m in chosen[n]], None,
                    o.kernel_options(*ranges[n], level=level + o.levels - len(pyramid)))
            if init is None:
                d, nrm, c, st = _core.mvs_patchmatch(*args)
            else:
                up = [_upsample(a, c_l[n].height, c_l[n].width) for a in init]
                d, nrm, c, st = _core.mvs_patchmatch(*args, up[0], up[1])
                # A window that is textureless here may not be at the coarser level (a larger part
                # of the scene): such pixels keep the coarser level's plane and cost.
                flat = (d <= 0) & (up[0] > 0)
                d, c = np.where(flat, up[0], d), np.where(flat, up[2], c)
                nrm = np.where(flat[..., None], up[1], nrm)
            evals["photometric"] += st["evaluations"]
            init = (d, nrm, c)
        timing["photometric"] += time.perf_counter() - t1
        results[n] = {"depth": d, "normal": nrm, "cost": c, "textureless": int(np.sum(d <= 0))}

    def known(n: str) -> np.ndarray | None:
        """A source's depth for the later passes: this run's (unknown where costly), else its own,
        else None (a source without depth adds no geometric term and no consistency vote)."""
        if n in results:
            r = results[n]
            return np.where(r["cost"] < o.max_cost, r["depth"], np.float32(0)).astype(np.float32)
        return np.ascontiguousarray(by_name[n].depth, np.float32) if by_name[n].has_depth else None

    if o.geom_iterations > 0:
        first = {n: known(n) for n in set(results) | {m for n in names for m in chosen[n]}}
        for n in names:
            if progress:
                progress(f"mvs geometric {n}")
            t1 = time.perf_counter()
            r = results[n]
            d, nrm, c, st = _core.mvs_patchmatch(
                greys[n], core[n], [greys[m] for m in chosen[n]], [core[m] for m in chosen[n]],
                [first[m] for m in chosen[n]], o.kernel_options(*ranges[n], geometric=True), r["depth"], r["normal"])
            timing["geometric"] += time.perf_counter() - t1
            evals["geometric"] += st["evaluations"]
            r["geometric"] = (d, nrm, c)
        for n in names:
            r = results[n]
            r["depth"], r["normal"], r["cost"] = r.pop("geometric")
    out: dict[str, MvsResult] = {}
    final = {n: known(n) for n in set(results) | {m for n in names for m in chosen[n]}}
    for n in names:
        t1 = time.perf_counter()
        r = results[n]
        voters = [m for m in chosen[n] if final[m] is not None]
        count = _core.mvs_consistent_views(final[n], core[n], [final[m] for m in voters], [core[m] for m in voters],
                                           o.consistency_px, o.consistency_depth, o.min_angle_deg)
        need = min(o.min_consistent, len(voters))
        keep = (r["cost"] < o.max_cost) & (r["depth"] > 0) & (count >= need)
        depth = np.where(keep, r["depth"], np.float32(0)).astype(np.float32)
        conf = np.where(keep, 1.0 - r["cost"] / 2.0, 0.0).astype(np.float32)
        normal = np.where(keep[..., None], r["normal"], np.float32(0)).astype(np.float32)
        timing["filter"] += time.perf_counter() - t1
        out[n] = MvsResult(depth, normal, conf, chosen[n], ranges[n],
                           {"kept": float(keep.mean()), "textureless": int(r["textureless"])})
    total = sum(evals.values())
    secs = timing["photometric"] + timing["geometric"]
    for res in out.values():
        res.stats.update({"seconds": {k: round(v, 3) for k, v in timing.items()}, "evaluations": evals,
                          "evaluations_per_second": round(total / secs) if secs > 0 else None})
    return out
