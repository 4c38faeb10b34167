"""View selection for multi-view DIBR (Bonatto et al. 2021, section III-B4).

The similarity of an input camera i and the target camera C is (Eq. 4 and 6)

    S_i = (n_i . n_C) * V(F_i ∩ F_C)

where n is a camera's viewing direction and V the volume of the intersection of the two
frusta, each bounded by a depth range [near, far]. The volume is estimated by Monte Carlo
(Eq. 5). Where the paper draws points in a box bounding both frusta, we draw them uniformly
*inside the target frustum* (its volume V_C is known in closed form), so that

    V(F_i ∩ F_C) ≈ V_C * (1/n) * sum_k 1[p_k in F_i],   p_k ~ U(F_C).

It is the same estimator with a tighter sampling domain (no sample is wasted outside F_C,
which the indicator would zero anyway), so fewer samples give the same variance.

Frusta
  pinhole   the pyramid of the image rectangle [0, W] x [0, H], z in [near, far]
            (uniform samples: uniform image point, z with density ∝ z², i.e. z³ uniform);
  equirect  the spherical shell sector lon in lon_range, lat in lat_range, ray distance in
            [near, far] (uniform samples: lon uniform, sin(lat) uniform, r³ uniform).

Depth ranges
  Input view i: min/max of its valid depth (finite, > 0), widened by 1 % — z for pinhole, ray distance for
  equirect, as the depth maps store them. The target has no depth: its range is the union
  of the inputs' ranges (the scene's depth range seen from the cameras). A target z-range
  is used as is for a pinhole target and as a ray-distance range for an equirect target;
  the two differ by at most the ray's obliquity, which only enlarges or shrinks the
  sampled shell slightly and does not change which views overlap.

Viewing direction
  n is the camera's +z axis for pinhole cameras and for equirect cameras whose longitude
  span is at most 180° (the direction of the middle of the span); a wider equirect camera
  has no meaningful viewing direction and its agreement factor is 1 (the volume alone
  decides, as the paper does implicitly for 360° inputs).

Selection (Eq. 7)
  The k views of largest S among those with S > 0. Views with V = 0 (no overlap) or
  n_i . n_C <= 0 (facing away from the target: what they see of the overlap is the back of
  the surfaces the target sees) are never warped; :class:`Selection` counts them.

Deterministic: the samples come from ``numpy.random.default_rng(seed)`` and depend only on
the seed, N and the target camera. Cost: one (M, N, 3) matrix product for M inputs
(vectorised numpy; ~N·M point tests, e.g. 4000 x 40 in a few ms), not per pixel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ibrtools.camera import EQUIRECT, PINHOLE, Camera
from ibrtools.checks import check_int
from ibrtools.errors import BadValueError, InputError

DEFAULT_SAMPLES = 4000
DEFAULT_SEED = 0
DEFAULT_K = 4
RANGE_MARGIN = 0.01
# Depth outliers left out of a view's range (depth_range): values beyond OUTLIER_FACTOR times the
# OUTLIER_QUANTILE / 1 - OUTLIER_QUANTILE quantiles.
OUTLIER_QUANTILE = 0.01
OUTLIER_FACTOR = 2.0


@dataclass(frozen=True)
class DepthRange:
    near: float
    far: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.near) and math.isfinite(self.far) and 0 < self.near <= self.far):
            raise BadValueError(f"depth range: expected 0 < near <= far (finite), got "
                                f"[{self.near}, {self.far}]")


def _order_stats(depth: np.ndarray) -> tuple[int, float, float, tuple[float, float]]:
    """(count, min, max, (1st, 99th percentile)) of the valid values (finite, > 0) of ``depth``
    (any shape): the percentiles as ``np.quantile(valid, [q, 1 - q])`` (linear method) gives them,
    bit for bit, from the exact order statistics of the C++ kernel (cpp/kernels/dibr/depth_stats.h,
    a radix select on the float bits: ~6 ms for a 1080p map where the partition took ~25)."""
    from ibrtools import _core

    d = np.ascontiguousarray(depth, np.float32)
    d = d.reshape(1, -1) if d.ndim != 2 else d
    q = np.array([OUTLIER_QUANTILE, 1.0 - OUTLIER_QUANTILE])
    n, vmin, vmax, _, values = _core.valid_depth_order_stats(d, q.tolist())
    if n == 0:
        return 0, 0.0, 0.0, (math.nan, math.nan)
    # numpy's _quantile and _lerp, in its dtypes: float64 virtual ranks and weights, float32 values.
    virtual = (n - 1) * q
    previous = np.where(virtual >= n - 1, -1.0, np.floor(virtual))
    gamma = virtual - previous
    a, b = np.array(values[0::2], np.float32), np.array(values[1::2], np.float32)
    diff = b - a
    lerp = np.where(gamma >= 0.5, b - diff * (1 - gamma), a + diff * gamma)
    return int(n), float(vmin), float(vmax), (float(lerp[0]), float(lerp[1]))


def outlier_limits(valid: np.ndarray) -> tuple[float, float]:
    """(low, high) of the valid depth values ``valid`` (finite, > 0; 1-D): values below low (half
    the 1st percentile) or above high (twice the 99th) are outliers. :func:`depth_range` leaves
    them out; the import stage warns about far ones (pipeline/importing.py ``depth_outlier_warning``)."""
    lo, hi = _order_stats(valid)[3]
    return lo / OUTLIER_FACTOR, hi * OUTLIER_FACTOR


def depth_range(depth: np.ndarray, name: str = "depth") -> DepthRange:
    """[near, far] of the valid (finite, > 0) values of a depth map, outliers left out: the
    values below half the 1st percentile or above twice the 99th (a few 65.5 m pixels of a
    sensor's invalid code in a 3 m room would make the frustum 20 times deeper and its overlap
    with every target 20 times smaller); on depth without such outliers, [min, max].
    InputError when no pixel is valid."""
    d = np.asarray(depth)
    n, near, far, (lo, hi) = _order_stats(d)
    if n == 0:
        raise InputError(f"{name}: no valid depth (every pixel is 0, NaN or infinite)")
    low, high = lo / OUTLIER_FACTOR, hi * OUTLIER_FACTOR
    if near < low or far > high:  # outliers: the extremes of the values between the limits
        v = d[np.isfinite(d) & (d > 0)]
        if near < low:
            near = float(v[v >= low].min())
        if far > high:
            far = float(v[v <= high].max())
    # Widened by RANGE_MARGIN on each side: a view of one plane (near = far) still bounds a
    # frustum with a volume, and samples exactly on the surface are not lost to rounding.
    return DepthRange(near * (1 - RANGE_MARGIN), far * (1 + RANGE_MARGIN))


def union(ranges: list[DepthRange]) -> DepthRange:
    if not ranges:
        raise BadValueError("depth ranges: empty list")
    return DepthRange(min(r.near for r in ranges), max(r.far for r in ranges))


def frustum_volume(camera: Camera, rng_: DepthRange) -> float:
    """Closed-form volume of a camera's frustum between near and far."""
    shell = (rng_.far ** 3 - rng_.near ** 3) / 3.0
    if camera.model == PINHOLE:
        return camera.width * camera.height / (camera.fx * camera.fy) * shell
    lon0, lon1 = camera.lon_range
    lat0, lat1 = camera.lat_range
    return (lon1 - lon0) * (math.sin(lat1) - math.sin(lat0)) * shell


def sample_frustum(camera: Camera, rng_: DepthRange, n: int, seed: int = DEFAULT_SEED) -> np.ndarray:
    """``n`` points (n, 3) in world coordinates, uniform in the camera's frustum."""
    n = check_int(n, "samples", 1)
    g = np.random.default_rng(seed)
    u = g.random((n, 3))
    r3 = rng_.near ** 3 + u[:, 2] * (rng_.far ** 3 - rng_.near ** 3)
    dist = np.cbrt(r3)  # z for pinhole, ray distance for equirect; density ∝ dist²
    if camera.model == PINHOLE:
        x = u[:, 0] * camera.width
        y = u[:, 1] * camera.height
        p_cam = camera.rays_in_cam(x, y) * dist[:, None]
    else:
        lon0, lon1 = camera.lon_range
        lat0, lat1 = camera.lat_range
        lon = lon0 + u[:, 0] * (lon1 - lon0)
        lat = np.arcsin(math.sin(lat0) + u[:, 1] * (math.sin(lat1) - math.sin(lat0)))
        cl = np.cos(lat)
        p_cam = np.stack([cl * np.sin(lon), -np.sin(lat), cl * np.cos(lon)], -1) * dist[:, None]
    wfc = camera.world_from_cam
    return p_cam @ wfc[:3, :3].T + wfc[:3, 3]


def in_frustum(camera: Camera, rng_: DepthRange, points_world: np.ndarray) -> np.ndarray:
    """Bool (...,) whether world points lie inside the camera's frustum."""
    p = np.asarray(points_world, dtype=np.float64)
    pc = p @ camera.cam_from_world[:3, :3].T + camera.cam_from_world[:3, 3]
    return _in_frustum_cam(camera, rng_, pc)


def _in_frustum_cam(camera: Camera, rng_: DepthRange, pc: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        if camera.model == PINHOLE:
            z = pc[..., 2]
            x = camera.fx * pc[..., 0] / z + camera.cx
            y = camera.fy * pc[..., 1] / z + camera.cy
            return ((z >= rng_.near) & (z <= rng_.far) & (x >= 0) & (x <= camera.width)
                    & (y >= 0) & (y <= camera.height))
        r = np.linalg.norm(pc, axis=-1)
        lon = np.arctan2(pc[..., 0], pc[..., 2])
        lat = np.arcsin(np.clip(-pc[..., 1] / np.where(r > 0, r, 1.0), -1.0, 1.0))
        lon0, lon1 = camera.lon_range
        # longitude relative to the left edge, wrapped into [0, 2π)
        rel = np.mod(lon - lon0, 2 * math.pi)
        span = lon1 - lon0
        ok_lon = (rel <= span) | (span >= 2 * math.pi - 1e-9)
        return ((r >= rng_.near) & (r <= rng_.far) & ok_lon
                & (lat >= camera.lat_range[0]) & (lat <= camera.lat_range[1]))


def viewing_direction(camera: Camera) -> np.ndarray | None:
    """Unit viewing direction in world coordinates, or None for wide equirect cameras."""
    if camera.model == PINHOLE:
        d_cam = np.array([0.0, 0.0, 1.0])
    else:
        lon0, lon1 = camera.lon_range
        if lon1 - lon0 > math.pi + 1e-9:
            return None
        lat = 0.5 * (camera.lat_range[0] + camera.lat_range[1])
        lon = 0.5 * (lon0 + lon1)
        d_cam = np.array([math.cos(lat) * math.sin(lon), -math.sin(lat), math.cos(lat) * math.cos(lon)])
    return camera.cam_from_world[:3, :3].T @ d_cam


def direction_agreement(a: Camera, b: Camera) -> float:
    """n_a . n_b (Eq. 4), 1 when either camera has no viewing direction."""
    na, nb = viewing_direction(a), viewing_direction(b)
    if na is None or nb is None:
        return 1.0
    return float(np.dot(na, nb))


@dataclass
class Selection:
    """The outcome of :func:`select_views` for one target."""

    indices: list[int]                 # selected inputs, best first
    scores: np.ndarray                 # S_i for every input (Eq. 6)
    volumes: np.ndarray                # estimated V(F_i ∩ F_C) for every input
    agreement: np.ndarray              # n_i . n_C for every input
    skipped: int = 0                   # candidates never warped (no overlap, or facing away)
    candidates: list[int] = field(default_factory=list)  # inputs considered (all, or the asked list)


def similarities(target: Camera, target_range: DepthRange, cameras: list[Camera],
                 ranges: list[DepthRange], *, samples: int = DEFAULT_SAMPLES,
                 seed: int = DEFAULT_SEED) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S, V, agreement) for every input camera against ``target`` (Eq. 4-6)."""
    if len(cameras) != len(ranges):
        raise BadValueError(f"similarities: {len(cameras)} cameras but {len(ranges)} depth ranges")
    pts = sample_frustum(target, target_range, samples, seed)
    vol_c = frustum_volume(target, target_range)
    m = len(cameras)
    vols = np.zeros(m)
    agree = np.array([direction_agreement(c, target) for c in cameras], dtype=np.float64)
    # Group the tests by camera model: one batched (M, N, 3) transform per model.
    for model in (PINHOLE, EQUIRECT):
        idx = [i for i, c in enumerate(cameras) if c.model == model]
        if not idx:
            continue
        rot = np.stack([cameras[i].cam_from_world[:3, :3] for i in idx])     # (m, 3, 3)
        t = np.stack([cameras[i].cam_from_world[:3, 3] for i in idx])        # (m, 3)
        pc = np.einsum("mij,nj->mni", rot, pts) + t[:, None, :]              # (m, N, 3)
        for j, i in enumerate(idx):
            vols[i] = vol_c * _in_frustum_cam(cameras[i], ranges[i], pc[j]).mean()
    return agree * vols, vols, agree


def select_views(target: Camera, target_range: DepthRange, cameras: list[Camera],
                 ranges: list[DepthRange], k: int = DEFAULT_K, *, candidates: list[int] | None = None,
                 samples: int = DEFAULT_SAMPLES, seed: int = DEFAULT_SEED) -> Selection:
    """The ``k`` best inputs for ``target`` by Eq. 6 among ``candidates`` (default all);
    candidates with S <= 0 are skipped (never warped), so fewer than k may be returned."""
    k = check_int(k, "k", 1)
    scores, vols, agree = similarities(target, target_range, cameras, ranges, samples=samples, seed=seed)
    cand = list(range(len(cameras))) if candidates is None else list(candidates)
    usable = [i for i in cand if scores[i] > 0]
    # Stable: ties keep input order, so the choice is deterministic.
    usable.sort(key=lambda i: -scores[i])
    chosen = usable[:k]
    return Selection(chosen, scores, vols, agree, skipped=len(cand) - len(usable), candidates=cand)


@dataclass
class ViewSet:
    """The input views of a method, ready for selection: cameras, each view's depth range and
    their union (the target's range). Building it reads every depth map once, which is also
    what checks them."""

    cameras: list[Camera]
    ranges: list[DepthRange]
    target_range: DepthRange

    @classmethod
    def of(cls, views) -> "ViewSet":
        ranges = [depth_range(v.depth, f"view {v.name!r} depth") for v in views]
        return cls([v.camera for v in views], ranges, union(ranges))

    def select(self, target: Camera, k: int, *, candidates: list[int] | None = None,
               samples: int = DEFAULT_SAMPLES, seed: int = DEFAULT_SEED) -> Selection:
        return select_views(target, self.target_range, self.cameras, self.ranges, k,
                            candidates=candidates, samples=samples, seed=seed)
