"""Downscaling on import (``ibr-preprocess --downscale N`` / ``--max-size PX``), for every importer.

A scene is downscaled after its importer made it, view by view and lazily (each image is resized
when it is first read, so an import still decodes every file once):

* cameras: :meth:`Camera.scaled` to the new size, ``sx = w' / w`` and ``sy = h' / h``. Output
  pixel i covers the source interval [i / sx, (i + 1) / sx), so its centre (i + 0.5) / sx maps to
  (i + 0.5): the pixel-centre-at-+0.5 convention is kept exactly (cx' = cx sx).
* colour: the exact **area average** (box filter) of the source pixels under each output pixel,
  in linear light, separable, computed from cumulative sums (any factor, integer or not; an
  integer factor that divides the size is a plain block mean). No ringing, no aliasing beyond
  the box filter's.
* depth: the **nearest known depth** (the minimum z, unknown 0 left out) of the source pixels
  under each output pixel. Averaging depth across an edge would invent a surface between
  foreground and background, and nearest-pixel sampling loses thin foreground structures (a
  one-pixel wire vanishes from a 2x smaller image half the time). The minimum keeps every
  foreground surface, never mixes two, and matches the colour of the output pixel, which the area
  average makes partly foreground where a block straddles an edge. +inf (background at infinity)
  stays +inf where the whole block is background; an all-unknown block stays unknown (0).
* masks: true where more than half of the block is true (the area average of the mask > 0.5).

Sizes: ``downscale=N`` (a number >= 1) gives ``round(w / N) x round(h / N)``; ``max_size=PX``
the factor that brings the longer side to at most PX (images already within PX are kept).
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError
from ibrtools.scene import Scene, View, _Lazy, _check_image
from ibrtools.formats._common import record_summary


def scaled_size(width: int, height: int, downscale: float | None = None, max_size: int | None = None
                ) -> tuple[int, int]:
    """The size an image of ``width x height`` is imported at (``downscale``, then ``max_size``)."""
    s = 1.0
    if downscale is not None:
        s = float(downscale)
    if max_size is not None and max(width, height) / s > max_size:
        s = max(width, height) / max_size
    if s == 1.0:
        return width, height
    return max(1, int(round(width / s))), max(1, int(round(height / s)))


def check_factors(downscale: Any, max_size: Any) -> tuple[float | None, int | None]:
    """``downscale`` / ``max_size`` as numbers, or BadValueError naming the argument."""
    if downscale is not None:
        try:
            d = float(downscale)
        except (TypeError, ValueError):
            raise BadValueError.about("downscale", f"expected a number >= 1, got {downscale!r}") from None
        if not (math.isfinite(d) and d >= 1):
            raise BadValueError.about("downscale", f"expected a number >= 1 (1 = full size), got {downscale!r}")
        downscale = d
    if max_size is not None:
        try:
            m = int(max_size)
            ok = float(max_size) == m
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok or isinstance(max_size, bool) or m < 1:
            raise BadValueError.about("max_size", f"expected a whole number of pixels >= 1, got {max_size!r}")
        max_size = m
    return downscale, max_size


def _edges(n_src: int, n_dst: int) -> np.ndarray:
    """Source coordinates of the n_dst + 1 output pixel edges."""
    return np.arange(n_dst + 1, dtype=np.float64) * (n_src / n_dst)


def _area_axis(img: np.ndarray, n_dst: int, axis: int) -> np.ndarray:
    """Area average of ``img`` along ``axis`` onto ``n_dst`` pixels (float64 accumulation)."""
    n_src = img.shape[axis]
    if n_dst == n_src:
        return img
    k = n_src // n_dst
    if k * n_dst == n_src:  # an integer factor: the block mean, k strided slices summed (float32)
        img = np.asarray(img, np.float32)
        step = [slice(None)] * img.ndim
        acc = None
        for o in range(k):
            step[axis] = slice(o, None, k)
            acc = img[tuple(step)].copy() if acc is None else np.add(acc, img[tuple(step)], out=acc)
        return acc * np.float32(1.0 / k)
    moved = np.moveaxis(img, axis, 0).astype(np.float64)
    integral = _integral(moved, _edges(n_src, n_dst))
    out = (integral[1:] - integral[:-1]) / (n_src / n_dst)
    return np.moveaxis(out, 0, axis)


def _integral(moved: np.ndarray, e: np.ndarray) -> np.ndarray:
    """The integral of the piecewise-constant signal ``moved`` (along axis 0) from 0 to each source
    coordinate of ``e`` (within [0, n]): C(e) = S[floor e] + frac(e) img[floor e], float64."""
    cum = np.concatenate([np.zeros((1,) + moved.shape[1:]), np.cumsum(moved, axis=0)], axis=0)
    i = np.minimum(np.floor(e).astype(np.int64), moved.shape[0] - 1)
    frac = (e - i).reshape((-1,) + (1,) * (moved.ndim - 1))
    return cum[i] + frac * moved[i]


def _area_between(img: np.ndarray, e: np.ndarray, axis: int) -> np.ndarray:
    """Mean of ``img`` along ``axis`` over each source interval [e[k], e[k + 1]] (source pixel
    coordinates, increasing; clipped to the image). An interval wholly outside the image takes
    the nearest edge pixel."""
    n_src = img.shape[axis]
    e = np.clip(np.asarray(e, np.float64), 0.0, float(n_src))
    moved = np.moveaxis(img, axis, 0).astype(np.float64)
    integral = _integral(moved, e)
    width = (e[1:] - e[:-1]).reshape((-1,) + (1,) * (moved.ndim - 1))
    out = (integral[1:] - integral[:-1]) / np.maximum(width, 1e-12)
    empty = width.reshape(-1) <= 1e-12
    if empty.any():
        out[empty] = moved[np.minimum(np.floor(e[:-1][empty]).astype(np.int64), n_src - 1)]
    return np.moveaxis(out, 0, axis)


def area_resample(img: np.ndarray, x_edges: np.ndarray, y_edges: np.ndarray) -> np.ndarray:
    """``img`` (H, W[, C]) resampled by an axis-aligned affine map: output pixel (i, j) is the
    area average of the source rectangle [x_edges[j], x_edges[j + 1]] x [y_edges[i],
    y_edges[i + 1]] (source pixel coordinates, edges at integers); float32 out. What
    :func:`area_resize` does for a pure scale, for any scale and offset per axis."""
    out = _area_between(_area_between(img, y_edges, 0), x_edges, 1)
    return np.ascontiguousarray(out, dtype=np.float32)


def area_resize(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """``img`` (H, W[, C]) resized to (height, width[, C]) by the exact area average (module doc);
    float32 out."""
    out = _area_axis(_area_axis(img, height, 0), width, 1)
    return np.ascontiguousarray(out, dtype=np.float32)


def _min_axis(d: np.ndarray, n_dst: int, axis: int) -> np.ndarray:
    """Minimum of ``d`` (NaN = unknown, ignored) over each output pixel's source pixels along ``axis``."""
    n_src = d.shape[axis]
    if n_dst == n_src:
        return d
    e = _edges(n_src, n_dst)
    start = np.minimum(np.floor(e[:-1] + 1e-9).astype(np.int64), n_src - 1)
    stop = np.maximum(np.ceil(e[1:] - 1e-9).astype(np.int64), start + 1)  # exclusive
    moved = np.moveaxis(d, axis, 0)
    out = moved[start]
    for o in range(1, int((stop - start).max())):
        idx = np.minimum(start + o, stop - 1)
        out = np.fmin(out, moved[idx])
    return np.moveaxis(out, 0, axis)


def min_depth_resize(depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """``depth`` (H, W) resized to (height, width) by the nearest known depth of each block (module
    doc): 0 (unknown) is left out, +inf kept; float32 out."""
    d = np.where(depth > 0, depth, np.nan).astype(np.float32)
    out = _min_axis(_min_axis(d, height, 0), width, 1)
    return np.ascontiguousarray(np.nan_to_num(out, nan=0.0, posinf=np.inf), dtype=np.float32)


def mask_resize(mask: np.ndarray, width: int, height: int) -> np.ndarray:
    return np.ascontiguousarray(area_resize(mask.astype(np.float32), width, height) > 0.5)


_RESIZE: dict[str, Callable[[np.ndarray, int, int], np.ndarray]] = {
    "color": area_resize, "depth": min_depth_resize, "depth_stored": min_depth_resize, "mask": mask_resize}


class ResizedLoader:
    """The loader of a view's image followed by the resize: ``source`` and ``probe`` are the
    original loader's (the file's header is checked against the size stored in it). The full-size
    image is checked as the view would check it, resized, and not kept."""

    def __init__(self, lazy: _Lazy, fn: Callable[[np.ndarray, int, int], np.ndarray], camera: Camera,
                 which: str, name: str, size: tuple[int, int]):
        self._loader, self._fn, self._camera, self._which, self._name = lazy._loader, fn, camera, which, name
        self._size = size
        self.source = lazy.source
        self.probe = getattr(lazy._loader, "probe", None)

    def __call__(self) -> np.ndarray:
        what = f"view {self._name!r} {self._which}" + (f" ({self.source})" if self.source else "")
        full = _check_image(self._loader(), what, self._camera, self._which)
        return self._fn(full, *self._size)


def _scaled_view(view: View, camera: Camera) -> View:
    size = (camera.width, camera.height)
    parts = {}
    for which, fn in _RESIZE.items():
        lazy: _Lazy = getattr(view, "_" + which)
        if not lazy.present:
            parts[which] = None
        elif lazy._value is not None:
            parts[which] = fn(lazy._value, *size)
        else:
            parts[which] = ResizedLoader(lazy, fn, view.camera, which, view.name, size)
    return View.create(view.name, camera, **parts)


def downscale_scene(scene: Scene, downscale: float | None = None, max_size: int | None = None) -> Scene:
    """``scene`` with every pinhole view and target resized (module doc) and a line in
    ``source["adapted"]``; the scene itself when no image changes size."""
    downscale, max_size = check_factors(downscale, max_size)
    sizes: dict[tuple[tuple[int, int], tuple[int, int]], int] = {}

    def scale(views: list[View]) -> list[View]:
        out = []
        for v in views:
            c = v.camera
            w, h = scaled_size(c.width, c.height, downscale, max_size)
            if (w, h) == (c.width, c.height):
                out.append(v)
                continue
            key = ((c.width, c.height), (w, h))
            sizes[key] = sizes.get(key, 0) + 1
            out.append(_scaled_view(v, c.scaled(w, h)))
        return out

    views, targets = scale(scene.views), scale(scene.targets)
    if not sizes:
        return scene
    paths = {name: [c.scaled(*scaled_size(c.width, c.height, downscale, max_size)) for c in cams]
             for name, cams in scene.paths.items()}
    source = dict(scene.source)
    how = f"by {downscale:g}" if max_size is None else f"to at most {max_size} px"
    record_summary(source, adapted=[
        f"images downscaled ({how}): {n} views {a[0]}x{a[1]} -> {b[0]}x{b[1]} (colour: area average; "
        "depth: nearest known depth of each block)" for (a, b), n in sorted(sizes.items())])
    from dataclasses import replace

    return replace(scene, views=views, targets=targets, paths=paths, source=source)
