"""Hole filling for rendered frames: push-pull, classic and depth-aware (docs/inpaint.md).

* :func:`pushpull` — the pyramid fill of Gortler et al. 1996 ("classic": the pull averages the
  valid pixels of each 2x2 block weighted by their validity, the push fills the pixels with no
  valid data from the coarser level by bilinear up-sampling) and, when ``depth`` is given, the
  depth-aware variant of dos Anjos et al. (*Metameric Inpainting for Image Warping*, sec. 3.3,
  Alg. 1): samples nearer than the block's background depth by more than ``depth_threshold``
  (a fraction of the image's depth range) get no weight, partial validity is carried through the
  pull, and the push mixes a pixel with the coarser level by ``validity ** gamma``. Where
  Alg. 1 finds no data at any scale (a hole's background depth lies beyond every valid pixel),
  the hole pixel takes the classic fill for the share Alg. 1 leaves empty (our deviation,
  ``pushpull.h``), so the depth-aware fill always completes.
* :func:`nearest_covered` — for every hole pixel, the nearest pixel outside the holes in each of
  the four directions (the background-depth fills of inpaint/complete.py and depthwarp/method.py).
* :func:`dilate` — the square binary dilation of a mask (metameric inpainting's band masks, the
  background pass's clearance).

The C++ kernel is ``cpp/kernels/inpaint/pushpull.{h,cpp}`` (equations, the paper's depth convention and
where we read Alg. 1 differently are written there). Outside the holes the result *is* the input
(copied, bit for bit); an image without holes is returned unchanged (a copy). An image that is
all hole raises :class:`BadValueError` (there is nothing to fill from).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ibrtools.errors import DtypeError, ShapeError

DEPTH_THRESHOLD = 0.04  # authors' Unity code: 0.04 of the normalised depth
GAMMA = 0.5             # paper sec. 3.3.1: "a compromise at gamma = .5"


def check_arrays(image: Any, hole: Any, depth: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    # dtype/shape/contiguity are checked in C++ (cpp/bindings/array.h); only the hole's dtype
    # family is normalised here so that any bool-like mask works.
    if not isinstance(image, np.ndarray):
        raise DtypeError(f"image: expected a float32 numpy array of shape (H, W) or (H, W, C), got {type(image).__name__}")
    if not isinstance(hole, np.ndarray):
        raise DtypeError(f"hole: expected a bool or uint8 numpy array of shape (H, W), got {type(hole).__name__}")
    if hole.dtype not in (np.bool_, np.uint8):
        raise DtypeError(f"hole: expected a bool or uint8 array of shape (H, W), got {hole.dtype}")
    if image.ndim not in (2, 3):
        raise ShapeError(f"image: expected shape (H, W) or (H, W, C), got {image.shape}")
    if hole.shape != image.shape[:2]:
        raise ShapeError(f"hole: expected shape (H, W) = {image.shape[:2]} to match image, got {hole.shape}")
    if depth is not None and not isinstance(depth, np.ndarray):
        raise DtypeError(f"depth: expected a float32 numpy array of shape (H, W), got {type(depth).__name__}")
    return image, np.ascontiguousarray(hole), depth


def pushpull(image: np.ndarray, hole: np.ndarray, depth: np.ndarray | None = None, *,
             depth_threshold: float = DEPTH_THRESHOLD, gamma: float = GAMMA, write: np.ndarray | None = None,
             out: np.ndarray | None = None) -> np.ndarray:
    """Fill the holes of ``image`` by push-pull.

    image: float32 (H, W) or (H, W, C), any number of channels, finite outside the holes (the
    values inside holes are never read). hole: bool or uint8 (H, W), True/non-zero = hole.
    depth: None for the classic fill, or float32 (H, W) metric depth (larger = farther; NaN,
    inf or <= 0 = unknown) *including inside the holes*, where a warper writes the background
    depth (sec. 3.1) — then the depth-aware fill of Alg. 1 is used. ``depth_threshold`` (>= 0,
    fraction of the image's known-depth range) and ``gamma`` (>= 0) only apply to the depth-aware
    fill; classic is gamma = 0 (a pixel with any valid data keeps it).

    write: None, or a bool (H, W) mask of the hole pixels to fill (the other hole pixels are not
    data and keep their values): they are written into ``out`` (default: a copy of ``image``;
    ``out`` may be ``image`` itself, filled in place) and nothing else is.

    Returns a new float32 array of image's shape, equal to ``image`` outside the holes (with
    ``write``: ``out``).
    Raises ShapeError/DtypeError for bad arrays, BadValueError for non-finite pixels outside the
    holes, bad options or an all-hole image. When the depth test leaves a hole with no data at
    any scale, that hole falls back to the classic fill (docs/inpaint.md), it does not raise.
    """
    from ibrtools import _core

    image, hole, depth = check_arrays(image, hole, depth)
    threshold, g = (0.0, 0.0) if depth is None else (float(depth_threshold), float(gamma))
    if write is None:
        filled, _ = _core.pushpull(image, hole, depth, threshold, g)
        return filled
    if not isinstance(write, np.ndarray):
        raise DtypeError(f"write: expected a bool numpy array of shape (H, W), got {type(write).__name__}")
    target = image.copy() if out is None else out
    _core.pushpull(image, hole, depth, threshold, g, out=target, holes_only=True, write=np.ascontiguousarray(write))
    return target


def dilate(mask: np.ndarray, r: int) -> np.ndarray:
    """Square (2r+1)^2 binary dilation of a bool (H, W) mask, separable: 2r shifted ORs per axis
    (nothing outside the image); a new array (``mask`` itself copied for r <= 0)."""
    h = mask.copy()
    for s in range(1, r + 1):
        h[:, s:] |= mask[:, :-s]
        h[:, :-s] |= mask[:, s:]
    v = h.copy()
    for s in range(1, r + 1):
        v[s:] |= h[:-s]
        v[:-s] |= h[s:]
    return v


def nearest_covered(hole: np.ndarray):
    """For the hole pixels (row-major order, as ``np.nonzero(hole)``) and each of the four
    directions (left, right, up, down): (row, col, found) of the nearest pixel that is not a hole
    in that direction. A hole pixel's nearest covered pixels along its row are the two ends of
    the run of holes it lies in, so only the runs are found (np.diff), not a scan of the image."""
    h, w = hole.shape
    ys, xs = np.nonzero(hole)
    r, before, after = _runs(hole)  # rows; columns before / after each pixel's run
    yield r, before, before >= 0
    yield r, after, after < w
    index = np.full(hole.shape, -1, np.int64)
    index[ys, xs] = np.arange(len(ys))
    order = index.T[hole.T]  # the row-major index of each hole pixel in column-major order
    c, above, below = _runs(hole.T)
    up, down = np.empty(len(ys), np.int64), np.empty(len(ys), np.int64)
    up[order], down[order] = above, below
    yield up, xs, up >= 0
    yield down, xs, down < h


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For the True pixels of ``mask`` (row-major order): (row, the column before the run of True
    pixels it lies in (-1 at the left edge), the column after it (W at the right edge))."""
    h, w = mask.shape
    m = np.zeros((h, w + 2), np.int8)
    m[:, 1:-1] = mask
    d = np.diff(m, axis=1)
    rows, start = np.nonzero(d == 1)
    _, end = np.nonzero(d == -1)
    run = np.repeat(np.arange(len(start)), end - start)
    return rows[run], start[run] - 1, end[run]
