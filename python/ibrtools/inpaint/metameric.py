"""Metameric inpainting (dos Anjos et al., *Metameric Inpainting for Image Warping*, sec. 3.2-3.4;
Walton et al. 2021, *Beyond Blur*, sec. 3; docs/inpaint.md, "Metameric").

Holes are filled with content whose local statistics (per steerable band: mean and variance)
match the surrounding background, instead of the smooth colour of push-pull:

0. RGB is synthesised on display values: the sRGB encoding of the linear input (Walton et al.
   sec. 6: "all methods operate on non-linear color (subject to display gamma) as they are
   concerned with perceived contrasts, not with preserving energy"; the variance of a band is a
   contrast, and a noise of the surroundings' linear variance is far too strong, in display terms,
   next to dark content). The fill is decoded back to linear at the end (clamped at 0).
1. pre-fill the holes by push-pull (our deviation from "holes zero", see :func:`metameric`) and
   analyse the image into the small-filter steerable pyramid (:mod:`ibrtools.metamers.steerable`, YCbCr
   for RGB);
2. per level, the hole mask down-sampled to the level and dilated by the filter radius (2 px for
   the 5x5 band filters; sec. 3.2) marks the band samples to replace;
3. per level, push-pull X and X^2 of every band (depth-aware, Alg. 1, when a depth is given, with
   the depth sampled at the level's pixel centres; classic otherwise) inside that mask:
   variance = max(0, pp(X^2) - pp(X)^2) (sec. 3.3.1);
4. the mean of the fill, the paper's mu_l + sum mu_ij, is the pyramid of the pre-fill itself: its
   low-pass residual and its band coefficients inside the masks (the push-pull of the colours, a
   convex operator as sec. 3.2 asks for the low-pass, run at full resolution with the exact hole
   mask and depth). The paper's per-band pp(X) and a push-pull of the low-pass at level L are
   the same kind of local mean but at the level's resolution, where a sample is a hole when any
   pixel of its 2^L x 2^L block is and the band mask is dilated: they draw on samples up to
   2^l (2 + 1) pixels away, across the depth edge beside a disocclusion, and moved the fill's mean
   colour off the background (docs/inpaint_quality.md, findings: the measured "bleed");
5. synthesise each band's change inside its mask as sigma * noise, where the noise is white noise
   analysed by the same pyramid (so filtered by the same band filter) and normalised to unit
   variance per band and channel (sec. 3.4: "shaped to fit the distribution described by mu,
   sigma"); collapse the pyramid of changes (the low-pass unchanged) and add it to the pre-fill
   inside the holes only: outside the holes the output is the input bit for bit. Collapsing the
   changes rather than the whole pyramid also keeps the 5x5 filters' reconstruction error
   (docs/steerable.md) out of the holes: with no texture around (sigma = 0) the fill is exactly
   the push-pull.

The noise pyramid depends only on (size, channels, levels, orientations, seed), so it is built
once and cached (Walton et al.: "this random pattern is held constant over time"); ``flow``
moves it with the scene (sec. 3.4.1): the noise at pixel x is read at x + flow(x) (nearest
sample of each level, wrapping at the borders). All per-pixel work is C++: display encoding,
steerable analysis / synthesis, push-pull (of the colours, and of each level's moments fused with
the sigma * noise composite of cpp/kernels/inpaint/metameric.h), the decode-and-copy into the holes;
numpy builds the masks.
"""
from __future__ import annotations

import functools
from typing import Any

import numpy as np

from ibrtools.errors import BadValueError, DtypeError, ShapeError
from ibrtools.inpaint.pushpull import DEPTH_THRESHOLD, GAMMA, check_arrays, dilate, pushpull
from ibrtools.metamers.steerable import ORIENTATIONS, SteerablePyramid, analyse, max_levels, synthesise

FILTER_RADIUS = 2  # the 5x5 taps of cpp/kernels/metamers/steerable_taps.h


def _any_down(mask: np.ndarray) -> np.ndarray:
    """Next level's mask: a sample is a hole when any pixel of its 2x2 block is (ceil sizes, as
    the pyramid's levels)."""
    h, w = mask.shape
    pad = np.zeros((h + (h & 1), w + (w & 1)), bool)
    pad[:h, :w] = mask
    return pad[0::2, 0::2] | pad[1::2, 0::2] | pad[0::2, 1::2] | pad[1::2, 1::2]


def level_masks(hole: np.ndarray, levels: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Per-level masks of the samples synthesis replaces (sec. 3.2).

    Returns (band_masks, lowpass_mask). band_masks[l] (h_l, w_l): the hole mask down-sampled to
    level l (a sample is a hole when any full-resolution pixel of its 2^l x 2^l block is)
    dilated by the filter radius (2 px for 5x5): band samples whose filter reads a hole sample
    of the level. Level 0's mask also serves the high-pass residual (``levels`` = 0: only that).
    lowpass_mask (h_L, w_L): the hole mask down-sampled to level L and dilated by 2 as well: the
    low-pass samples whose up-sampling (5x5 L1 taps) reaches a hole. :func:`metameric` does not
    replace the low-pass (module docstring, step 4: it keeps the pre-fill's); the mask says which
    low-pass samples a hole pixel's synthesis reads."""
    if levels == 0:
        return [dilate(hole, FILTER_RADIUS)], dilate(hole, FILTER_RADIUS)
    m, bands = hole, []
    for _ in range(levels):
        bands.append(dilate(m, FILTER_RADIUS))
        m = _any_down(m)
    return bands, dilate(m, FILTER_RADIUS)


def _block_all(hole: np.ndarray, scale: int, shape: tuple[int, int]) -> np.ndarray:
    """Level mask where a sample is a hole only if its whole scale x scale block is."""
    h, w = shape
    pad = np.ones((h * scale, w * scale), bool)
    pad[:hole.shape[0], :hole.shape[1]] = hole
    return pad.reshape(h, scale, w, scale).all(axis=(1, 3))


@functools.lru_cache(maxsize=2)
def _noise_pyramid_cached(height: int, width: int, channels: int, levels: int, orientations: int,
                          seed: int) -> tuple[np.ndarray, tuple, np.ndarray]:
    rng = np.random.default_rng(seed)
    white = rng.standard_normal((height, width, channels), dtype=np.float32)
    pyr = analyse(white, levels, orientations, ycbcr=False)

    def unit(b: np.ndarray) -> np.ndarray:
        # Unit variance per channel over the whole band (the reflect border changes it a little).
        sd = b.reshape(-1, b.shape[2]).std(axis=0, dtype=np.float64)
        b = (b / np.where(sd > 0, sd, 1.0).astype(np.float32)).astype(np.float32)
        b.setflags(write=False)
        return b

    return unit(pyr.highpass), tuple(tuple(unit(b) for b in lvl) for lvl in pyr.bands), pyr.lowpass


def _sample_positions(ys: np.ndarray, xs: np.ndarray, scale: int, shape: tuple[int, int],
                      flow: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Noise sample positions of level samples (ys, xs): themselves without flow, else the nearest
    level sample to (y, x) + flow / scale, flow read at the level sample's full-res pixel
    (y * scale, x * scale); wrapped into the level (the noise is a texture, not an image)."""
    if flow is None:
        return ys, xs
    f = flow[ys * scale, xs * scale]
    yy = np.rint(ys + f[:, 1] / scale).astype(np.int64) % shape[0]
    xx = np.rint(xs + f[:, 0] / scale).astype(np.int64) % shape[1]
    return yy, xx


def noise_pyramid(height: int, width: int, channels: int = 3, levels: int = 4, orientations: int = 2,
                  seed: int = 0, flow: np.ndarray | None = None):
    """The unit-variance band noise metameric synthesis uses, as a SteerablePyramid (highpass and
    bands; lowpass is the analysed white noise, unused by :func:`metameric`), sampled at the
    motion-compensated positions x + flow(x) when ``flow`` (float32 (H, W, 2), (dx, dy) in
    pixels) is given. For inspection and tests; :func:`metameric` samples only inside holes."""
    levels, orientations, seed = _check_options(levels, orientations, seed, height, width)
    flow = _check_flow(flow, height, width)
    hp, bands, lo = _noise_pyramid_cached(int(height), int(width), int(channels), levels, orientations, seed)

    def moved(n: np.ndarray, scale: int) -> np.ndarray:
        if flow is None:
            return n.copy()
        ys, xs = np.indices(n.shape[:2]).reshape(2, -1)
        yy, xx = _sample_positions(ys, xs, scale, n.shape[:2], flow)
        return n[yy, xx].reshape(n.shape)

    return SteerablePyramid(moved(hp, 1), [[moved(b, 1 << l) for b in lvl] for l, lvl in enumerate(bands)],
                            lo.copy(), ycbcr=False)


def _check_options(levels: Any, orientations: Any, seed: Any, h: int, w: int) -> tuple[int, int, int]:
    for name, v in (("levels", levels), ("orientations", orientations), ("seed", seed)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise BadValueError(f"{name}: expected an integer, got {v!r}")
    if int(orientations) not in ORIENTATIONS:
        raise BadValueError(f"orientations: expected one of {', '.join(map(str, ORIENTATIONS))}, got {orientations!r}")
    if h < 3 or w < 3:
        raise ShapeError(f"image: expected at least 3x3 pixels for the steerable pyramid, got {h}x{w}")
    top = max_levels(h, w)
    if not 0 <= int(levels) <= top:
        raise BadValueError(f"levels: expected 0..{top} for a {h}x{w} image, got {levels!r}")
    if int(seed) < 0:
        raise BadValueError(f"seed: expected an integer >= 0, got {seed!r}")
    return int(levels), int(orientations), int(seed)


def _check_flow(flow: Any, h: int, w: int) -> np.ndarray | None:
    if flow is None:
        return None
    if not isinstance(flow, np.ndarray):
        raise DtypeError(f"flow: expected a float32 numpy array of shape (H, W, 2), got {type(flow).__name__}")
    if flow.dtype not in (np.float32, np.float64):
        raise DtypeError(f"flow: expected a float32 array of shape (H, W, 2) = ({h}, {w}, 2), got {flow.dtype}")
    if flow.shape != (h, w, 2):
        raise ShapeError(f"flow: expected shape (H, W, 2) = ({h}, {w}, 2), got {flow.shape}")
    if not np.isfinite(flow).all():
        raise BadValueError("flow: contains NaN or infinite values")
    return flow


def local_moments(x: np.ndarray, hole: np.ndarray, depth: np.ndarray | None = None,
                  **pushpull_options: Any) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of ``x`` (float32 (H, W, C) or (H, W)) inside ``hole`` from push-pull of
    X and X^2 (dos Anjos et al. sec. 3.3.1; depth-aware with ``depth``): (pp(X),
    max(0, pp(X^2) - pp(X)^2)); outside the holes (X, 0) up to rounding. What :func:`metameric`
    computes per band (there only on the masked samples)."""
    if not isinstance(x, np.ndarray) or x.dtype != np.float32:
        raise DtypeError(f"x: expected a float32 numpy array, got {getattr(x, 'dtype', type(x).__name__)}")
    x3 = x[..., None] if x.ndim == 2 else x
    c = x3.shape[-1] if x3.ndim == 3 else 0
    m = pushpull(np.concatenate([x3, x3 * x3], axis=2) if x3.ndim == 3 else x, hole, depth, **pushpull_options)
    mean, sq = m[..., :c], m[..., c:]
    var = np.maximum(sq - mean * mean, np.float32(0))
    return (mean[..., 0], var[..., 0]) if x.ndim == 2 else (mean, var)


def _level_mask(mask: np.ndarray, hole: np.ndarray, scale: int) -> np.ndarray:
    """``mask``, unless it covers the whole level (a level too coarse for its holes: push-pull
    would have nothing to fill from); then the samples whose whole scale x scale block is hole
    (never all True when any pixel is valid): the pre-filled samples count as data there."""
    return _block_all(hole, scale, mask.shape) if mask.all() else mask


def metameric(image: np.ndarray, hole: np.ndarray, depth: np.ndarray | None = None, *, levels: int = 4,
              orientations: int = 2, seed: int = 0, flow: np.ndarray | None = None,
              depth_threshold: float | None = None, gamma: float | None = None,
              display: bool | None = None) -> np.ndarray:
    """Fill the holes of ``image`` with a metamer of their surroundings (module docstring).

    image: float32 (H, W) or (H, W, C), H, W >= 3, finite outside the holes (values in holes are
    never read); RGB (C = 3) is analysed in YCbCr, other channel counts as given. hole: bool or
    uint8 (H, W), non-zero = hole. depth: None (classic push-pull of the moments) or float32 (H, W)
    metric depth including background depth inside holes (depth-aware push-pull, Alg. 1).
    levels (0 .. steerable.max_levels), orientations (2 or 4): the pyramid; seed (>= 0): the noise;
    flow: None or float32 (H, W, 2), per-pixel (dx, dy) offset at which the noise is sampled
    (motion since the frame the noise was anchored to); depth_threshold, gamma: the depth-aware
    push-pull's (:func:`ibrtools.inpaint.pushpull.pushpull` defaults when None). display: synthesise on the
    sRGB encoding of the (linear) values and decode the fill (clamped at 0); None (default) = True
    for RGB (C = 3), False for other channel counts (module docstring, step 0).

    Returns a new float32 array of image's shape: ``image`` bit for bit outside the holes, the
    metamer inside. Deterministic for a given seed (and thread count independent). Raises
    ShapeError/DtypeError for bad arrays, BadValueError for non-finite pixels outside the holes,
    bad options or an all-hole image.
    """
    from ibrtools import _core

    image, hole, depth = check_arrays(image, hole, depth)
    if image.dtype != np.float32:
        raise DtypeError(f"image: expected float32, got {image.dtype}")
    h, w = image.shape[:2]
    if depth is not None and (depth.dtype != np.float32 or depth.shape != (h, w)):
        raise ShapeError(f"depth: expected float32 array of shape (H, W) = ({h}, {w}), got {depth.dtype} {depth.shape}")
    levels, orientations, seed = _check_options(levels, orientations, seed, h, w)
    flow = _check_flow(flow, h, w)
    if display is not None and not isinstance(display, (bool, np.bool_)):
        raise BadValueError(f"display: expected None, True or False, got {display!r}")
    hole = hole.astype(bool, copy=False)
    squeeze = image.ndim == 2
    x = image[..., None] if squeeze else image
    c = x.shape[2]
    if c < 1:
        raise ShapeError(f"image: expected at least 1 channel, got shape {image.shape}")
    if not hole.any():
        if not np.isfinite(x).all():
            raise BadValueError("image: contains NaN or infinite values outside the holes")
        return image.copy()
    if hole.all():
        raise BadValueError("hole: every pixel is a hole; metameric inpainting needs pixels outside the holes")
    display = (c == 3) if display is None else bool(display)
    pp_kw = {}
    if depth is not None:
        pp_kw = {"depth_threshold": DEPTH_THRESHOLD if depth_threshold is None else depth_threshold,
                 "gamma": GAMMA if gamma is None else gamma}

    x = np.ascontiguousarray(x)
    # Step 0: display encoding (Walton et al. sec. 6: perceived contrasts, not energy), into an
    # array of ours that the pre-fill then fills in place.
    xs = _core.metameric_encode(x) if display else x.copy()
    # Deviation (docs/inpaint.md): the holes are pre-filled by push-pull (depth-aware with
    # depth) before the analysis instead of set to zero. With zeros, every sample whose
    # filter chain (L0, L1, ..., band) reaches a hole is wrong, and for a warped frame with 10 %
    # scattered holes that is 72 % of level 2, 98 % of level 3 and 97 % of the low-pass at
    # 1024^2: the local colour would be lost. The smooth pre-fill has no edge at the hole's rim,
    # so the per-level masks of the paper (hole at the level dilated by the filter radius) hold.
    # The pre-fill is also the fill's mean (step 4).
    # (pushpull() with out=xs, holes_only: the same checks and fill, no new array and no copy.)
    pp_args = (float(pp_kw["depth_threshold"]), float(pp_kw["gamma"])) if pp_kw else (0.0, 0.0)
    filled, _ = _core.pushpull(xs, hole, depth, *pp_args, xs, True)
    ycbcr = c == 3
    pyr = analyse(filled, levels, orientations, ycbcr=ycbcr)
    n_hp, n_bands, _ = _noise_pyramid_cached(h, w, c, levels, orientations, seed)
    band_masks, _ = level_masks(hole, levels)

    flow_c = None if flow is None else np.ascontiguousarray(flow)

    def fill(bands: list[np.ndarray], noise: list[np.ndarray], mask: np.ndarray, scale: int) -> None:
        # One push-pull of [X..., X^2...] of every band of the level (sec. 3.3.1), each masked
        # sample's moments turned at once into the band's change sigma * noise (sec. 3.4 with the
        # mean of step 4), 0 outside the mask, written over the bands in place: one C++ pass
        # (cpp/kernels/inpaint/pushpull.h PushPullMomentsChangeKernel; [X, X^2] computed on the fly, no
        # moments image).
        mask = _level_mask(mask, hole, scale)
        d = None if depth is None else np.ascontiguousarray(depth[::scale, ::scale])
        # check_finite only without the display encoding: encoded values are below ~1e16 in
        # magnitude (the curve of float32's largest value), so the analysis of the (finite,
        # checked by push-pull's front) pre-fill cannot overflow; linear values can.
        _core.metameric_pushpull_change(bands, mask.view(np.uint8), d, *pp_args, noise, flow_c, scale, not display)

    # Level 0 also carries the high-pass residual (same resolution, same mask: one push-pull
    # call per level).
    fill([pyr.highpass] + (pyr.bands[0] if levels else []), [n_hp] + (list(n_bands[0]) if levels else []),
         band_masks[0], 1)
    for l in range(1, levels):
        fill(pyr.bands[l], list(n_bands[l]), band_masks[l], 1 << l)
    # The pyramid now holds the change of every band and no change of the low-pass: its collapse
    # is the noise image, added to the pre-fill inside the holes (step 5).
    pyr.lowpass[...] = 0.0
    change = synthesise(SteerablePyramid(pyr.highpass, pyr.bands, pyr.lowpass, ycbcr=ycbcr))
    # Written over `change` (ours, already in memory: a fresh output array would be page-faulted).
    out = _core.metameric_fill_holes(x, hole, filled, change, display, change)
    return out[..., 0] if squeeze else out
