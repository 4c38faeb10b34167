"""Small-filter steerable pyramid (Walton et al. 2021, *Beyond Blur*, sec. 3.2; docs/steerable.md).

* :func:`analyse` — image → :class:`SteerablePyramid`: a high-pass residual (H0), per level K
  oriented band-pass images (K = 2 by default, 4 as an option) and a low-pass residual; each
  level halves the size (ceil). Optionally in YCbCr (BT.601 full range, Cb/Cr centred on 0, so
  the transform stays linear).
* :func:`synthesise` — collapse the pyramid back into an image (the adjoint filters, as
  pyrtools' ``SteerablePyramidSpace.recon_pyr``).
* :func:`reconstruction_error` — analysis → synthesis error of an image, interior and border.

The filters are the fitted 5x5 taps of ``cpp/kernels/metamers/steerable_taps.h`` (fit and fit error:
``tools/fit_steerable_filters.py``); the C++ kernel is ``cpp/kernels/metamers/steerable.{h,cpp}``. The
small filters do not reconstruct exactly: analysis → synthesis of a natural image in [0, 1] has
an error of ~0.02 rms (~0.1 max) in the interior, larger within a few pixels of the border
(reflect1 borders), see docs/steerable.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ibrtools.errors import BadValueError, DtypeError, ShapeError

ORIENTATIONS = (2, 4)
BORDER = 16  # pixels from an edge counted as "border" in reconstruction_error (as the fit script)


@dataclass
class SteerablePyramid:
    """highpass (H, W, C); bands[level][orientation] (h_l, w_l, C) with h_0 = H, h_{l+1} =
    ceil(h_l / 2); lowpass (h_L, w_L, C); all float32. Orientation 0 responds to vertical edges
    (a d/dx-like filter), orientation 1 (of 2) to horizontal ones; with 4 orientations the
    filters are 0°, 45°, 90°, 135° as pyrtools' sp3. ``ycbcr`` says the channels are Y, Cb, Cr
    (synthesis converts back to RGB); ``squeeze`` that the input was (H, W)."""

    highpass: np.ndarray
    bands: list[list[np.ndarray]]
    lowpass: np.ndarray
    ycbcr: bool = True
    squeeze: bool = False

    @property
    def levels(self) -> int:
        return len(self.bands)

    @property
    def orientations(self) -> int:
        return len(self.bands[0]) if self.bands else 2


def max_levels(height: int, width: int) -> int:
    """The largest ``levels`` for an image of this size (every level's input at least 3x3)."""
    from ibrtools import _core

    return int(_core.steerable_max_levels(int(height), int(width)))


def _check_int(name: str, value, allowed=None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise BadValueError(f"{name}: expected an integer, got {value!r}")
    if allowed is not None and int(value) not in allowed:
        raise BadValueError(f"{name}: expected one of {', '.join(map(str, allowed))}, got {value!r}")
    return int(value)


def analyse(image: np.ndarray, levels: int = 4, orientations: int = 2, ycbcr: bool = True) -> SteerablePyramid:
    """Analyse ``image`` (float32 (H, W, C) or (H, W), finite, H, W >= 3) into a pyramid.

    ``levels`` (0 .. :func:`max_levels`) band-pass levels of ``orientations`` (2 or 4) bands.
    ``ycbcr`` (default True) converts RGB (C = 3) to YCbCr first; False filters the channels as
    given (any C). Raises ShapeError/DtypeError for bad arrays, BadValueError for non-finite
    pixels, unsupported orientations or too many levels for the image size.
    """
    from ibrtools import _core

    if not isinstance(image, np.ndarray):
        raise DtypeError(f"image: expected a float32 numpy array of shape (H, W, C) or (H, W), got {type(image).__name__}")
    if image.ndim not in (2, 3):
        raise ShapeError(f"image: expected shape (H, W, C) or (H, W), got {image.shape}")
    levels = _check_int("levels", levels)
    orientations = _check_int("orientations", orientations, ORIENTATIONS)
    squeeze = image.ndim == 2
    x = image[..., None] if squeeze else image
    hi, bands, lo = _core.steerable_analyse(x, levels, orientations, bool(ycbcr))
    return SteerablePyramid(hi, [list(b) for b in bands], lo, bool(ycbcr), squeeze)


def synthesise(pyr: SteerablePyramid) -> np.ndarray:
    """Collapse ``pyr`` into an image float32 (H, W, C) (or (H, W) when analysed from (H, W));
    RGB when ``pyr.ycbcr``. Raises ShapeError/DtypeError when a level has the wrong shape or
    dtype, BadValueError for non-finite values."""
    from ibrtools import _core

    if not isinstance(pyr, SteerablePyramid):
        raise DtypeError(f"pyr: expected a SteerablePyramid, got {type(pyr).__name__}")
    if not isinstance(pyr.bands, (list, tuple)):
        raise ShapeError(f"pyr.bands: expected a list of levels, got {type(pyr.bands).__name__}")
    k = len(pyr.bands[0]) if pyr.bands else 2
    out = _core.steerable_synthesise(pyr.highpass, pyr.bands, pyr.lowpass, k, bool(pyr.ycbcr))
    return out[..., 0] if pyr.squeeze else out


def reconstruction_error(image: np.ndarray, levels: int = 4, orientations: int = 2, ycbcr: bool = True,
                         border: int = BORDER) -> dict[str, float]:
    """Analysis → synthesis error of ``image``: max and rms of |image - synthesise(analyse(image))|
    over the interior (farther than ``border`` pixels from every edge) and over the border band
    (the reflect1 border dominates the error there), in the image's units and colour space; each
    figure is the largest over the channels (as tools/fit_steerable_filters.py reports it)."""
    rec = synthesise(analyse(image, levels, orientations, ycbcr))
    d = np.abs(rec.astype(np.float64) - image)
    if d.ndim == 2:
        d = d[..., None]
    h, w = d.shape[:2]
    border = int(border)
    if border < 0 or 2 * border >= min(h, w):
        raise BadValueError(f"border: expected 0 <= border < {min(h, w) / 2} for a {h}x{w} image, got {border}")
    mask = np.ones((h, w), bool)
    mask[border:h - border, border:w - border] = False
    rms = lambda a: float(np.sqrt(np.mean(a ** 2))) if a.size else 0.0  # noqa: E731
    per = [(d[~mask, c], d[mask, c]) for c in range(d.shape[2])]
    return {"interior_max": max(float(i.max()) for i, _ in per), "interior_rms": max(rms(i) for i, _ in per),
            "border_max": max(float(e.max()) if e.size else 0.0 for _, e in per),
            "border_rms": max(rms(e) for _, e in per)}
