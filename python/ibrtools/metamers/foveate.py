"""Foveated ventral metamers (Walton et al. 2021, *Beyond Blur: Real-time Ventral Metamers for
Foveated Rendering*, sec. 3 and 5; docs/foveate.md).

Around a fixation point the image is kept; away from it, every steerable band is replaced by noise
with the band's local statistics (mean and variance) pooled over a region that grows linearly with
eccentricity (Bouma 1970; the paper's sec. 3.1 "Size"):

1. analyse the image into the small-filter steerable pyramid (:mod:`ibrtools.metamers.steerable`, YCbCr
   for RGB);
2. eccentricity per pixel: the angle (degrees) between the pixel's viewing ray and the fixation's,
   for a pinhole display of horizontal field of view ``fov`` (degrees); pooling region edge
   length ``pooling * eccentricity`` (degrees), in pixels with the local pixel density; the MIP
   level of band level l is ``log2(size_px) - l`` (a 2^m x 2^m box of band samples);
3. moment maps (sec. 3.2 "Pooling"): per level, the MIP maps of X and X^2 of every band
   (cpp/kernels/metamers/mip.h, one chain for the stacked [X..., X^2...]) read trilinearly at that level:
   mean = E[X], variance = max(0, E[X^2] - E[X]^2) (:func:`foveate` fuses this step with step 4
   in one C++ pass per level, _core.mip_foveate_level, without storing the moment maps);
4. synthesis (sec. 3.4): band = mean + sigma * noise, the noise being white noise analysed by
   the same pyramid and normalised to unit variance per band (:mod:`ibrtools.inpaint.metameric`'s cached
   noise pyramid, "held constant over time"), written where the pooling region is larger than a
   band sample (:func:`ibrtools.inpaint.metameric`'s C++ composite, cpp/kernels/inpaint/metameric.h);
5. collapse. :func:`foveate` adds the collapsed *change* of the pyramid to the input
   (out = image + synthesise(new - old), exact because analysis/synthesis are linear) instead of
   collapsing the new pyramid, so the 5x5 filters' reconstruction error (docs/steerable.md) never
   shows as a seam; the fovea (pooling region below one pixel) is the input bit for bit.

The low-pass residual is kept (the paper pools "all levels" of the pyramid; the residual is
already at 1/2^levels resolution and carries the local colour). The statistics-only form —
:func:`statistics` then :func:`synthesise_from_statistics` — is the basis of foveated compression
(sec. 5.1): the statistics maps are smooth in the periphery and can be stored coarsely.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.inpaint.metameric import _check_options, _noise_pyramid_cached
from ibrtools.metamers.steerable import SteerablePyramid, analyse, synthesise

# Pooling region size per degree of eccentricity. Walton et al. follow "the slope in the middle of
# the corridor" of Fig. 3 without printing a number; that corridor is centred on Bouma's law
# (1970): critical spacing ~0.5 x eccentricity, which we take as the default.
POOLING = 0.5
_MAX_FUSED_MOMENTS = 256  # cpp/kernels/metamers/mip.h kMipMaxMomentChannels: 2 x bands x channels of the fused path
FOV_DEG = 90.0  # horizontal field of view of the display the image is viewed on (a typical HMD)


@dataclass
class FoveatedStatistics:
    """Pooled statistics of an image (:func:`statistics`).

    mean, variance: SteerablePyramid-shaped (highpass (H, W, C), bands[level][orientation]
    (h_l, w_l, C)); mean.lowpass is the analysed low-pass residual (kept as is), variance.lowpass
    zeros. pooled[l] (h_l, w_l) bool: the samples of level l whose pooling region is larger than a
    sample (elsewhere mean = the band value, variance = 0); level 0 also serves the high-pass.
    fovea (H, W) bool: pixels whose pooling region is below one pixel. fixation, pooling, fov,
    ycbcr, squeeze: what produced them."""

    mean: Any
    variance: Any
    pooled: list
    fovea: np.ndarray
    fixation: tuple[float, float]
    pooling: float
    fov: float


def _check_geometry(fixation: Any, pooling: Any, fov: Any) -> tuple[tuple[float, float], float, float]:
    try:
        fx, fy = (float(v) for v in fixation)
    except (TypeError, ValueError):
        raise BadValueError(f"fixation: expected two numbers (x, y) in [0, 1], got {fixation!r}") from None
    if not (0.0 <= fx <= 1.0 and 0.0 <= fy <= 1.0):
        raise BadValueError(f"fixation: expected (x, y) in [0, 1] x [0, 1] (fractions of width, height), "
                            f"got ({fx}, {fy})")
    if isinstance(pooling, bool) or not isinstance(pooling, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(pooling)) or float(pooling) < 0:
        raise BadValueError(f"pooling: expected a finite number >= 0 (region size per degree of "
                            f"eccentricity), got {pooling!r}")
    if isinstance(fov, bool) or not isinstance(fov, (int, float, np.integer, np.floating)) \
            or not (0.0 < float(fov) < 180.0):
        raise BadValueError(f"fov: expected a horizontal field of view in degrees in (0, 180), got {fov!r}")
    return (fx, fy), float(pooling), float(fov)


def _check_image(image: Any) -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise DtypeError(f"image: expected a float32 numpy array of shape (H, W, C) or (H, W), got "
                         f"{type(image).__name__}")
    if image.dtype != np.float32:
        raise DtypeError(f"image: expected float32, got {image.dtype}")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] < 1):
        raise ShapeError(f"image: expected shape (H, W, C) or (H, W), got {image.shape}")
    if not np.isfinite(image).all():
        raise BadValueError("image: contains NaN or infinite values")
    return image


@functools.lru_cache(maxsize=4)
def _level_map(h: int, w: int, fixation: tuple[float, float], pooling: float, fov: float) -> np.ndarray:
    """log2 of the pooling region edge in pixels, float32 (H, W) (read-only; cached: a fixed
    fixation over a sequence computes it once)."""
    f = 0.5 * w / math.tan(math.radians(fov) / 2)  # focal length in pixels
    ys = ((np.arange(h, dtype=np.float32) + 0.5 - 0.5 * h) / f)[:, None]
    xs = ((np.arange(w, dtype=np.float32) + 0.5 - 0.5 * w) / f)[None, :]
    bx, by = np.float32((fixation[0] * w - 0.5 * w) / f), np.float32((fixation[1] * h - 0.5 * h) / f)
    # Angle between rays a = (x, y, 1) and b = (bx, by, 1): atan2(|a x b|, a . b), stable near 0.
    cx = ys - by                                  # a x b = (y - by, bx - x, x by - y bx)
    cy = bx - xs
    cz = xs * by - ys * bx
    ecc = np.arctan2(np.sqrt(cx * cx + cy * cy + cz * cz), xs * bx + ys * by + np.float32(1 + 0))
    # Local pixel density (pixels per radian) of the pinhole display at the pixel: geometric mean of
    # the radial (f |a|^2) and tangential (f |a|) densities, |a| = 1 / cos(off-axis angle).
    norm2 = xs * xs + ys * ys + np.float32(1)
    size_px = np.float32(pooling * f) * ecc * norm2 ** np.float32(0.75)
    with np.errstate(divide="ignore"):
        lam = np.log2(size_px).astype(np.float32)
    lam = np.maximum(lam, np.float32(-64))  # log2(0) at the fixation pixel itself
    lam.setflags(write=False)
    return lam


@functools.lru_cache(maxsize=4)
def _fovea_index(h: int, w: int, fixation: tuple[float, float], pooling: float,
                 fov: float) -> tuple[bool, tuple[np.ndarray, np.ndarray]]:
    """(every pixel is in the fovea, (rows, cols) of the fovea pixels) for _level_map's arguments
    (cached with it: a fixed fixation finds them once)."""
    fovea = _level_map(h, w, fixation, pooling, fov) <= 0
    ys, xs = np.nonzero(fovea)
    ys.setflags(write=False)
    xs.setflags(write=False)
    return bool(fovea.all()), (ys, xs)


def level_map(shape: tuple[int, int], fixation: tuple[float, float], *, pooling: float = POOLING,
              fov: float = FOV_DEG) -> np.ndarray:
    """log2 of the pooling region edge length in pixels at every pixel of an image of ``shape``
    (H, W): float32 (H, W), <= 0 in the fovea (region below one pixel). See the module docstring."""
    (fixation, pooling, fov) = _check_geometry(fixation, pooling, fov)
    h, w = (int(v) for v in shape)
    if h < 1 or w < 1:
        raise ShapeError(f"shape: expected (H, W) >= 1, got {shape}")
    return _level_map(h, w, fixation, pooling, fov).copy()


def _levels_at(lam0: np.ndarray, levels: int) -> list[np.ndarray]:
    """Per band level l: the MIP level log2(size / 2^l) at the level's samples (the full-res value
    at the sample's first pixel: the map is smooth away from the fixation)."""
    return [np.ascontiguousarray(lam0[::1 << l, ::1 << l]) - np.float32(l) for l in range(max(levels, 1))]


def _moments(bands: list[np.ndarray], lam: np.ndarray) -> np.ndarray:
    """Pooled [E[X]..., E[X^2]...] of the level's bands, float32 (h, w, 2kC) (sec. 3.2)."""
    from ibrtools import _core

    h, w, c = bands[0].shape
    stack = np.empty((h, w, 2 * len(bands) * c), np.float32)
    _core.metameric_stack_moments(bands, stack)
    top = float(lam.max())
    n = min(int(_core.mip_max_levels(h, w)), max(0, math.ceil(top)))
    return _core.mip_lookup([stack] + list(_core.mip_build(stack, n)), lam)


def _prepare(image, fixation, pooling, levels, orientations, seed, fov):
    image = _check_image(image)
    fixation, pooling, fov = _check_geometry(fixation, pooling, fov)
    h, w = image.shape[:2]
    levels, orientations, seed = _check_options(levels, orientations, seed, h, w)
    x = image[..., None] if image.ndim == 2 else image
    lam0 = _level_map(h, w, fixation, pooling, fov)
    pyr = analyse(x, levels, orientations, ycbcr=x.shape[2] == 3)
    groups = [[pyr.highpass] + (pyr.bands[0] if levels else [])] + [pyr.bands[l] for l in range(1, levels)]
    return image, x, (fixation, pooling, fov), (levels, orientations, seed), lam0, pyr, groups


def foveate(image: np.ndarray, fixation: tuple[float, float] = (0.5, 0.5), *, pooling: float = POOLING,
            levels: int = 4, orientations: int = 2, seed: int = 0, fov: float = FOV_DEG) -> np.ndarray:
    """A ventral metamer of ``image`` for a viewer fixating ``fixation`` (module docstring).

    image: float32 (H, W, C) or (H, W), finite, H, W >= 3 (RGB analysed in YCbCr). fixation:
    (x, y) in [0, 1]^2, fractions of the width and height (0, 0 = top-left corner). pooling (>= 0,
    default 0.5, Bouma's law): pooling region edge per degree of eccentricity (0 = no pooling: a
    copy). levels (0 .. steerable.max_levels), orientations (2 or 4): the pyramid; seed (>= 0):
    the noise (the same seed gives the same noise in every frame). fov: horizontal field of view
    in degrees (0, 180) of the pinhole display the image is seen on (default 90).

    Returns a new float32 array of image's shape: the input bit for bit in the fovea (pooling
    region below one pixel), the metamer elsewhere. Deterministic for a seed and thread count
    independent. Raises DtypeError/ShapeError for bad arrays, BadValueError for non-finite pixels
    or bad options.
    """
    from ibrtools import _core

    image, x, geom, (levels, orientations, seed), lam0, pyr, groups = _prepare(
        image, fixation, pooling, levels, orientations, seed, fov)
    all_fovea, fovea = _fovea_index(*lam0.shape, *geom)
    if all_fovea:
        return image.copy()
    h, w, c = x.shape
    n_hp, n_bands, _ = _noise_pyramid_cached(h, w, c, levels, orientations, seed)
    noise = [[n_hp] + (list(n_bands[0]) if levels else [])] + [list(n_bands[l]) for l in range(1, levels)]
    for bands, nz, lam in zip(groups, noise, _levels_at(lam0, levels)):
        top = float(lam.max())
        if not top > 0:
            for b in bands:
                b[...] = 0  # no change at this level
            continue
        h_l, w_l = bands[0].shape[:2]
        n = min(int(_core.mip_max_levels(h_l, w_l)), math.ceil(top))
        if 2 * len(bands) * c <= _MAX_FUSED_MOMENTS:
            # Fused (cpp/kernels/metamers/mip.h MipFoveateChange): the MIP chain of [X, X^2] built from the
            # bands and read trilinearly per sample straight into mean + sigma * noise - band; the
            # moment maps are never materialised. Equals the branch below to float rounding.
            _core.mip_foveate_level(bands, lam, nz, n)
            continue
        moments = _moments(bands, lam)
        new = [b.copy() for b in bands]
        _core.metameric_composite(moments, lam > 0, nz, new)
        for b, nb in zip(bands, new):
            np.subtract(nb, b, out=b)  # the band's change, in place
    pyr.lowpass[...] = 0
    delta = synthesise(SteerablePyramid(pyr.highpass, pyr.bands, pyr.lowpass, ycbcr=pyr.ycbcr))
    out = np.add(x, delta, out=delta)  # one pass, in the fresh (H, W, C) float32 collapse
    out[fovea] = x[fovea]  # the fovea bit for bit (a few pixels, cached indices: no full-frame pass)
    return out[..., 0] if image.ndim == 2 else out


def statistics(image: np.ndarray, fixation: tuple[float, float] = (0.5, 0.5), *, pooling: float = POOLING,
               levels: int = 4, orientations: int = 2, fov: float = FOV_DEG) -> FoveatedStatistics:
    """The pooled statistics of ``image`` for a fixation (steps 1-3 of the module docstring):
    per steerable band, the mean and variance over each sample's pooling region (arguments as
    :func:`foveate`). Raises as :func:`foveate`."""
    image, x, geom, (levels, orientations, _), lam0, pyr, groups = _prepare(
        image, fixation, pooling, levels, orientations, 0, fov)
    means, variances, pooled = [], [], []
    for bands, lam in zip(groups, _levels_at(lam0, levels)):
        k, c = len(bands), bands[0].shape[2]
        m = _moments(bands, lam)
        mean, sq = m[..., :k * c], m[..., k * c:]
        var = np.maximum(sq - mean * mean, np.float32(0))
        means.append([np.ascontiguousarray(mean[..., i * c:(i + 1) * c]) for i in range(k)])
        variances.append([np.ascontiguousarray(var[..., i * c:(i + 1) * c]) for i in range(k)])
        pooled.append(lam > 0)

    def pyramid(groups_, low):
        hp = groups_[0][0]
        bands = ([groups_[0][1:]] if levels else []) + groups_[1:]
        return SteerablePyramid(hp, [list(b) for b in bands], low, ycbcr=pyr.ycbcr, squeeze=image.ndim == 2)

    return FoveatedStatistics(pyramid(means, pyr.lowpass), pyramid(variances, np.zeros_like(pyr.lowpass)),
                              pooled, lam0 <= 0, geom[0], geom[1], geom[2])


def synthesise_from_statistics(stats: FoveatedStatistics, *, seed: int = 0) -> np.ndarray:
    """A metamer from statistics alone (step 4-5 without the input, sec. 5.1 "compression"):
    every pooled band sample becomes mean + sqrt(variance) * noise (the same unit-variance band
    noise as :func:`foveate` for a seed), the others keep their mean (the band value), and the
    pyramid is collapsed. Without the input, the fovea carries the 5x5 filters' reconstruction
    error (docs/steerable.md); otherwise the result differs from :func:`foveate`'s by exactly
    that error (image - synthesise(analyse(image))). Returns float32 (H, W, C) or (H, W)."""
    if not isinstance(stats, FoveatedStatistics):
        raise DtypeError(f"stats: expected FoveatedStatistics (from foveate.statistics), got {type(stats).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise BadValueError(f"seed: expected an integer >= 0, got {seed!r}")
    mean, var = stats.mean, stats.variance
    levels, k = mean.levels, mean.orientations
    if var.levels != levels or len(stats.pooled) != max(levels, 1):
        raise ShapeError(f"stats: mean has {levels} levels, variance {var.levels}, pooled masks "
                         f"{len(stats.pooled)}")
    h, w, c = mean.highpass.shape
    n_hp, n_bands, _ = _noise_pyramid_cached(h, w, c, levels, k, int(seed))

    def draw(m: np.ndarray, v: np.ndarray, n: np.ndarray, mask: np.ndarray) -> np.ndarray:
        if m.shape != v.shape or m.shape != n.shape or mask.shape != m.shape[:2]:
            raise ShapeError(f"stats: a band has mean {m.shape}, variance {v.shape}, pooled {mask.shape}; "
                             f"expected {n.shape}")
        return np.where(mask[..., None], m + np.sqrt(np.maximum(v, np.float32(0))) * n, m).astype(np.float32)

    hp = draw(mean.highpass, var.highpass, n_hp, stats.pooled[0])
    bands = [[draw(mean.bands[l][i], var.bands[l][i], n_bands[l][i], stats.pooled[l]) for i in range(k)]
             for l in range(levels)]
    return synthesise(SteerablePyramid(hp, bands, mean.lowpass, ycbcr=mean.ycbcr, squeeze=mean.squeeze))
