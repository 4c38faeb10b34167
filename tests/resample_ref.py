"""Independent NumPy references of the colour reads at sub-pixel positions (cpp/ibr/resample.h
and the bilinear reads): pixel centres at +0.5, positions and taps clamped to the image."""
from __future__ import annotations

import numpy as np


def _keys(s):
    """The cubic convolution kernel with a = -0.5 (Keys 1981), piecewise in |s|: a different form
    from resample.h's polynomial weights of the fraction."""
    s = np.abs(s)
    return np.where(s < 1, 1.5 * s**3 - 2.5 * s**2 + 1, np.where(s < 2, -0.5 * s**3 + 2.5 * s**2 - 4 * s + 2, 0.0))


def catmull_rom(img, x, y):
    """Catmull-Rom read of (h, w, 3) img at positions x, y (same shape), each channel clamped to the
    range of the 2 x 2 texels a bilinear read uses."""
    h, w = img.shape[:2]
    fx = np.clip(np.asarray(x, np.float64) - 0.5, 0, w - 1)
    fy = np.clip(np.asarray(y, np.float64) - 0.5, 0, h - 1)
    x0, y0 = np.floor(fx).astype(int), np.floor(fy).astype(int)
    out = np.zeros(fx.shape + (3,))
    for j in range(-1, 3):
        for i in range(-1, 3):
            wgt = _keys(fx - (x0 + i)) * _keys(fy - (y0 + j))
            out += wgt[..., None] * img[np.clip(y0 + j, 0, h - 1), np.clip(x0 + i, 0, w - 1)]
    near = np.stack([img[np.clip(y0 + j, 0, h - 1), np.clip(x0 + i, 0, w - 1)] for j in (0, 1) for i in (0, 1)])
    return np.clip(out, near.min(0), near.max(0))


def bilinear(img, x, y):
    """Bilinear read of (h, w, 3) img at positions x, y."""
    h, w = img.shape[:2]
    fx = np.clip(np.asarray(x, np.float64) - 0.5, 0, w - 1)
    fy = np.clip(np.asarray(y, np.float64) - 0.5, 0, h - 1)
    x0, y0 = np.floor(fx).astype(int), np.floor(fy).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    ax, ay = (fx - x0)[..., None], (fy - y0)[..., None]
    top = img[y0, x0] * (1 - ax) + img[y0, x1] * ax
    bot = img[y1, x0] * (1 - ax) + img[y1, x1] * ax
    return top * (1 - ay) + bot * ay
