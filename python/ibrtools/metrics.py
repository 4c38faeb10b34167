"""Image quality metrics: PSNR, SSIM, coverage, FLIP, and :func:`compare` for reports.

Which values are compared
-------------------------
:func:`psnr`, :func:`mse` and :func:`ssim` compare the arrays they are given, as they are
(like scikit-image). :func:`compare` and :func:`flip` take *linear* RGB images (the engine's
colour, ``View.color``) and compare their **sRGB encodings in [0, 1]**
(:func:`ibrtools.imageio.linear_to_srgb`: clipped to [0, 1], then encoded). That is what the
field and the papers compare: 8-bit sRGB images (PSNR with a peak of 1 = 255). We do not
quantise to 8 bits: the 8-bit rounding would add up to 0.5/255 of noise to both images.

Definitions
-----------
* ``mse``: mean over pixels and channels of (a - b)^2, accumulated in float64.
* ``psnr`` = 10 log10(data_range^2 / mse); identical images (mse = 0) give ``math.inf``
  (scikit-image's ``peak_signal_noise_ratio`` does the same). ``json.dump`` writes it as
  ``Infinity``, which Python's ``json`` reads back.
* ``ssim``: scikit-image's default ``structural_similarity`` (7x7 box window, K1 = 0.01,
  K2 = 0.03, sample covariance, mean over the image cropped by 3 pixels, colour = mean over
  channels), computed by the C++ kernel ``cpp/kernels/metrics/ssim.cpp`` (multithreaded, float64);
  agrees with scikit-image to better than 1e-5 (tests/test_metrics.py).
* masked variants: PSNR over the pixels of the mask (all channels); SSIM = mean of the
  per-pixel SSIM map over the mask *within the cropped interior* (so that an all-true mask
  gives exactly :func:`ssim`).
* ``coverage``: fraction of pixels a renderer produced (not holes).
* ``flip``: NVIDIA's FLIP (LDR mode) from the optional ``flip-evaluator`` package
  (``pip install 'ibrtools[flip]'``); :func:`flip` raises :class:`NotBuiltError` when it is
  absent and :func:`compare` then leaves the ``"flip"`` key out.

No metric is ever NaN: a metric over an empty mask is ``None``.

Which scores a report computes (``ibr-render --metrics``, :func:`parse_scores`): "all" (the
default: PSNR, SSIM and FLIP when installed), "none", or a comma list of psnr, ssim, flip.
On a 1080p frame FLIP costs about 1.4 s, PSNR (with its covered variant) 0.16 s, SSIM 0.07 s
(docs/render.md).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ibrtools.errors import BadValueError, DtypeError, NotBuiltError, ShapeError
from ibrtools.imageio import linear_to_srgb

SSIM_WINDOW = 7
SSIM_CROP = (SSIM_WINDOW - 1) // 2


# --- input checks -------------------------------------------------------------------------
def _image(x: Any, name: str) -> np.ndarray:
    if not isinstance(x, np.ndarray):
        raise DtypeError(f"{name}: expected a numpy array of shape (H, W) or (H, W, C), got {type(x).__name__}")
    if x.dtype == np.bool_ or not (np.issubdtype(x.dtype, np.floating) or np.issubdtype(x.dtype, np.integer)):
        raise DtypeError(f"{name}: expected a float (or integer) image, got {x.dtype}")
    if x.ndim not in (2, 3) or x.shape[0] < 1 or x.shape[1] < 1 or (x.ndim == 3 and x.shape[2] < 1):
        raise ShapeError(f"{name}: expected an image of shape (H, W) or (H, W, C), got {x.shape}")
    return x


def _pair(a: Any, b: Any, names: tuple[str, str] = ("a", "b")) -> tuple[np.ndarray, np.ndarray]:
    a, b = _image(a, names[0]), _image(b, names[1])
    if a.shape != b.shape:
        raise ShapeError(f"{names[0]} and {names[1]}: images of different shapes, "
                         f"{names[0]} {a.shape} and {names[1]} {b.shape}")
    for x, n in ((a, names[0]), (b, names[1])):
        if np.issubdtype(x.dtype, np.floating) and not np.all(np.isfinite(x)):
            raise BadValueError(f"{n}: contains NaN or infinite values")
    return a, b


def _mask(mask: Any, shape: tuple[int, ...], name: str = "mask") -> np.ndarray | None:
    if mask is None:
        return None
    if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_:
        got = mask.dtype if isinstance(mask, np.ndarray) else type(mask).__name__
        raise DtypeError(f"{name}: expected a bool array of shape (H, W), got {got}")
    if mask.shape != tuple(shape[:2]):
        raise ShapeError(f"{name}: expected shape (H, W) = {tuple(shape[:2])} to match the images, got {mask.shape}")
    return mask


def _data_range(data_range: Any) -> float:
    try:
        r = float(data_range)
    except (TypeError, ValueError):
        raise DtypeError(f"data_range: expected a number, got {data_range!r}") from None
    if not (math.isfinite(r) and r > 0):
        raise BadValueError(f"data_range: expected a positive finite number, got {r}")
    return r


# --- metrics ------------------------------------------------------------------------------
def mse(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float | None:
    """Mean squared error over all pixels and channels (or the pixels of ``mask``),
    accumulated in float64; ``None`` for an empty mask."""
    a, b = _pair(a, b)
    mask = _mask(mask, a.shape)
    d = a.astype(np.float64) - b.astype(np.float64)
    if mask is not None:
        if not mask.any():
            return None
        d = d[mask]
    return float(np.mean(d * d))


def psnr(a: np.ndarray, b: np.ndarray, data_range: float = 1.0,
         mask: np.ndarray | None = None) -> float | None:
    """Peak signal-to-noise ratio in dB, 10 log10(data_range^2 / MSE), over all pixels or the
    pixels of ``mask`` (bool (H, W)). Identical images give ``math.inf``; an empty mask gives
    ``None``. Compares the given values as they are (see the module doc)."""
    r = _data_range(data_range)
    e = mse(a, b, mask)
    if e is None:
        return None
    if e == 0.0:
        return math.inf
    return float(10.0 * math.log10(r * r / e))


def ssim(a: np.ndarray, b: np.ndarray, data_range: float = 1.0, mask: np.ndarray | None = None,
         return_map: bool = False):
    """Mean SSIM of two images (H, W) or (H, W, C) at least 7x7, exactly scikit-image's
    default ``structural_similarity(a, b, data_range=..., channel_axis=2)``.

    With ``mask`` (bool (H, W)): the mean of the SSIM map over the mask pixels that are at
    least 3 pixels from the border (``None`` when there are none). ``return_map=True`` returns
    ``(mean, map)`` where ``map`` is float32 (H, W), the per-pixel SSIM averaged over channels
    (the border values use scipy's "reflect" padding, like scikit-image's ``full=True``).
    Inputs are converted to float32 (the kernel's type)."""
    r = _data_range(data_range)
    a, b = _pair(a, b)
    mask = _mask(mask, a.shape)
    if a.shape[0] < SSIM_WINDOW or a.shape[1] < SSIM_WINDOW:
        raise ShapeError(f"a and b: SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels "
                         f"(the window), got shape {a.shape}")
    from ibrtools import _core

    a32 = np.ascontiguousarray(a, dtype=np.float32)
    b32 = np.ascontiguousarray(b, dtype=np.float32)
    mean, smap = _core.ssim(a32, b32, r, return_map or mask is not None)
    if mask is not None:
        c = SSIM_CROP
        inner = mask[c:mask.shape[0] - c, c:mask.shape[1] - c]
        mean = float(smap[c:-c, c:-c][inner].mean(dtype=np.float64)) if inner.any() else None
    else:
        mean = float(mean)
    return (mean, smap) if return_map else mean


def coverage(valid_mask: np.ndarray | None = None, *, hole_mask: np.ndarray | None = None) -> float:
    """Fraction of the image a renderer covered: the mean of ``valid_mask`` (True = rendered)
    or one minus the mean of ``hole_mask`` (True = hole); give exactly one."""
    if (valid_mask is None) == (hole_mask is None):
        raise BadValueError("coverage: give exactly one of valid_mask and hole_mask")
    m = valid_mask if valid_mask is not None else hole_mask
    name = "valid_mask" if valid_mask is not None else "hole_mask"
    if not isinstance(m, np.ndarray) or m.dtype != np.bool_:
        raise DtypeError(f"{name}: expected a bool array of shape (H, W)")
    if m.ndim != 2 or m.size == 0:
        raise ShapeError(f"{name}: expected a non-empty array of shape (H, W), got {m.shape}")
    frac = float(np.count_nonzero(m)) / m.size
    return frac if valid_mask is not None else 1.0 - frac


def flip_available() -> bool:
    """True when the optional ``flip-evaluator`` package is installed."""
    try:
        import flip_evaluator  # noqa: F401
    except ImportError:
        return False
    return True


def flip(rendered: np.ndarray, reference: np.ndarray, return_map: bool = False):
    """Mean LDR-FLIP error (0 = identical, lower is better) of two *linear* RGB images
    (H, W, 3), compared as sRGB (clipped to [0, 1] and encoded; FLIP's LDR mode expects sRGB)
    at FLIP's default 67 pixels per degree. ``return_map=True`` returns ``(mean, map (H, W))``.
    Raises :class:`NotBuiltError` when ``flip-evaluator`` is not installed."""
    rendered, reference = _pair(rendered, reference, ("rendered", "reference"))
    if rendered.ndim != 3 or rendered.shape[2] != 3:
        raise ShapeError(f"rendered and reference: FLIP needs RGB images (H, W, 3), got {rendered.shape}")
    try:
        import flip_evaluator
    except ImportError:
        raise NotBuiltError("flip: the optional package flip-evaluator is not installed "
                            "(pip install 'ibrtools[flip]' or pip install flip-evaluator)") from None

    ref = np.ascontiguousarray(linear_to_srgb(reference))
    test = np.ascontiguousarray(linear_to_srgb(rendered))
    fmap, mean, _ = flip_evaluator.evaluate(ref, test, "LDR", inputsRGB=True, applyMagma=False)
    mean = float(mean)
    return (mean, np.ascontiguousarray(fmap[..., 0])) if return_map else mean


SCORES = ("psnr", "ssim", "flip")
DEFAULT_SCORES = "all"


def parse_scores(spec: Any) -> tuple[str, ...]:
    """The scores a ``--metrics`` value asks for: "all" (every score, FLIP when installed),
    "none" (no score), or a comma list of psnr, ssim, flip (FLIP named while it is not
    installed: NotBuiltError). A sequence of names is accepted from Python."""
    if isinstance(spec, str):
        text = spec.strip().lower()
        if text == "all":
            return SCORES
        if text == "none":
            return ()
        names = [t.strip() for t in text.split(",")]
    elif isinstance(spec, (list, tuple)) and all(isinstance(t, str) for t in spec):
        names = [t.strip().lower() for t in spec]
    else:
        raise DtypeError.about("metrics", f"expected all, none or a comma list of {', '.join(SCORES)}, "
                                           f"got {spec!r}")
    bad = [t for t in names if t not in SCORES]
    if bad or not names:
        raise BadValueError.about("metrics", f"expected all, none or a comma list of {', '.join(SCORES)}, "
                                        f"got {spec!r}")
    if "flip" in names and not flip_available():
        raise NotBuiltError.about("metrics", "the optional package flip-evaluator is not installed "
                                        "(pip install 'ibrtools[flip]' or pip install flip-evaluator)", "flip")
    return tuple(t for t in SCORES if t in names)


def compare(rendered: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None,
            hole_mask: np.ndarray | None = None, scores: tuple[str, ...] = SCORES) -> dict:
    """Metrics of a rendered frame against its ground truth, for ``report.json`` "metrics".

    ``rendered`` and ``reference`` are *linear* RGB float images (H, W, 3), compared as sRGB
    in [0, 1] (see the module doc). ``mask`` (bool (H, W), True = pixel to score, e.g. where
    the ground truth has content) and ``hole_mask`` (True = the renderer left a hole) are
    optional. Returns::

        {"psnr", "ssim"}               over the whole image (holes count as black, as written);
        "coverage"                     1 - fraction of holes (1.0 without a hole mask: the
                                       renderer reported no hole);
        {"psnr_covered", "ssim_covered"} over mask AND NOT hole (the whole image when both are
                                       absent); None when that region is empty;
        "flip"                         mean LDR-FLIP, only when flip-evaluator is installed.

    ``scores`` (:func:`parse_scores`) limits it to those scores (and their covered variants);
    "coverage" is always there.
    """
    rendered, reference = _pair(rendered, reference, ("rendered", "reference"))
    if rendered.ndim != 3 or rendered.shape[2] != 3:
        raise ShapeError(f"rendered and reference: expected RGB images (H, W, 3), got {rendered.shape}")
    mask = _mask(mask, rendered.shape, "mask")
    hole_mask = _mask(hole_mask, rendered.shape, "hole_mask")

    a = linear_to_srgb(rendered)
    b = linear_to_srgb(reference)
    region = np.ones(a.shape[:2], bool) if mask is None else mask.copy()
    if hole_mask is not None:
        region &= ~hole_mask
    out: dict[str, Any] = {}
    if "psnr" in scores:
        out["psnr"] = psnr(a, b, 1.0)
    if "ssim" in scores:
        s_mean, s_map = ssim(a, b, 1.0, return_map=True)
        c = SSIM_CROP
        inner = region[c:region.shape[0] - c, c:region.shape[1] - c]
        out["ssim"] = s_mean
    out["coverage"] = 1.0 if hole_mask is None else coverage(hole_mask=hole_mask)
    if "psnr" in scores:
        out["psnr_covered"] = psnr(a, b, 1.0, mask=region)
    if "ssim" in scores:
        out["ssim_covered"] = float(s_map[c:-c, c:-c][inner].mean(dtype=np.float64)) if inner.any() else None
    if "flip" in scores and flip_available():
        out["flip"] = flip(rendered, reference)
    return out
