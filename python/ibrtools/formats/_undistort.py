"""Lens distortion of the importers (COLMAP's models) and undistortion on load.

Every model is given in COLMAP's parameter layout (https://colmap.github.io/cameras.html):
  SIMPLE_RADIAL  f, cx, cy, k                  RADIAL  f, cx, cy, k1, k2
  OPENCV         fx, fy, cx, cy, k1, k2, p1, p2
  FULL_OPENCV    fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6  (rational radial term)
  OPENCV_FISHEYE fx, fy, cx, cy, k1, k2, k3, k4  (equidistant: theta_d = theta (1 + k1 theta^2 + ...))
The COLMAP importer reads them from cameras.bin/txt; the NeRF importer maps nerfstudio's
``camera_model`` OPENCV / OPENCV_FISHEYE and instant-ngp's ``k1 k2 p1 p2`` onto them.

Undistortion is to a pinhole camera with the same fx, fy, cx, cy and size: each output pixel
centre's normalised coordinate is distorted with the model (exact; no iteration is needed in
this direction) and the source image sampled there, bilinearly for colour, nearest for depth
(depth must not be blended across an edge). Pixels that map outside the source are black and out
of the view's mask. A wide fisheye loses what falls outside the pinhole's field of view.
"""
from __future__ import annotations

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import FormatError

# The models undistort_map knows (COLMAP names).
DISTORTION_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV",
                     "OPENCV_FISHEYE")


def _distort(model: str, params: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's distortion of normalised image coordinates (x, y) -> distorted (x, y)."""
    if model in ("SIMPLE_PINHOLE", "PINHOLE"):
        return x, y
    r2 = x * x + y * y
    if model == "SIMPLE_RADIAL":
        f = 1 + params[3] * r2
        return x * f, y * f
    if model == "RADIAL":
        f = 1 + params[3] * r2 + params[4] * r2 * r2
        return x * f, y * f
    if model in ("OPENCV", "FULL_OPENCV"):
        k1, k2, p1, p2 = params[4:8]
        f = 1 + k1 * r2 + k2 * r2 * r2
        if model == "FULL_OPENCV":
            k3, k4, k5, k6 = params[8:12]
            r6 = r2 * r2 * r2
            f = (f + k3 * r6) / (1 + k4 * r2 + k5 * r2 * r2 + k6 * r6)
        xy = x * y
        return x * f + 2 * p1 * xy + p2 * (r2 + 2 * x * x), y * f + p1 * (r2 + 2 * y * y) + 2 * p2 * xy
    if model == "OPENCV_FISHEYE":
        k1, k2, k3, k4 = params[4:8]
        r = np.sqrt(r2)
        theta = np.arctan(r)
        t2 = theta * theta
        theta_d = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(r > 1e-12, theta_d / np.where(r > 1e-12, r, 1.0), 1.0)
        return x * f, y * f
    raise FormatError(f"camera model {model}: not supported")


def is_distorted(model: str, params: np.ndarray) -> bool:
    if model in ("SIMPLE_PINHOLE", "PINHOLE"):
        return False
    extra = params[3:] if model in ("SIMPLE_RADIAL", "RADIAL") else params[4:]
    return bool(np.any(extra != 0))


def undistort_map(cam: Camera, model: str, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Continuous source coordinates (H, W) each, of every pixel centre of the undistorted
    pinhole ``cam`` (same fx, fy, cx, cy as the distorted camera)."""
    u, v = cam.pixel_grid()
    x, y = (u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy
    xd, yd = _distort(model, params, x, y)
    return xd * cam.fx + cam.cx, yd * cam.fy + cam.cy


def remap_bilinear(img: np.ndarray, sx: np.ndarray, sy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample ``img`` (H, W[, C]) at continuous coordinates (pixel centres at +0.5); returns the
    samples and a bool map of those inside the image (outside: 0)."""
    h, w = img.shape[:2]
    fx, fy = sx - 0.5, sy - 0.5
    inside = (fx >= -0.5) & (fx <= w - 0.5) & (fy >= -0.5) & (fy <= h - 0.5)
    fx, fy = np.clip(fx, 0, w - 1), np.clip(fy, 0, h - 1)
    x0 = np.minimum(np.floor(fx).astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(fy).astype(np.int64), h - 2 if h > 1 else 0)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    ax, ay = (fx - x0), (fy - y0)
    if img.ndim == 3:
        ax, ay = ax[..., None], ay[..., None]
    top = img[y0, x0] * (1 - ax) + img[y0, x1] * ax
    bot = img[y1, x0] * (1 - ax) + img[y1, x1] * ax
    out = (top * (1 - ay) + bot * ay).astype(img.dtype)
    out[~inside] = 0
    return np.ascontiguousarray(out), inside


def remap_nearest(img: np.ndarray, sx: np.ndarray, sy: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    xi, yi = np.floor(sx).astype(np.int64), np.floor(sy).astype(np.int64)
    inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    out = img[np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1)]
    out[~inside] = 0
    return np.ascontiguousarray(out)


class Undistorter:
    """The undistortion map of one camera, computed once and shared between that camera's views:
    ``bilinear`` for colour, ``nearest`` for depth and masks, ``inside`` for the pixels whose
    source lies in the distorted image."""

    def __init__(self, cam: Camera, model: str, params: np.ndarray):
        self.cam, self.model, self.params, self._map = cam, model, np.asarray(params, np.float64), None

    def map(self):
        if self._map is None:
            self._map = undistort_map(self.cam, self.model, self.params)
        return self._map

    def bilinear(self, img: np.ndarray) -> np.ndarray:
        return remap_bilinear(img, *self.map())[0]

    def nearest(self, img: np.ndarray) -> np.ndarray:
        return remap_nearest(img, *self.map())

    def inside(self) -> np.ndarray:
        sx, sy = self.map()
        w, h = self.cam.width, self.cam.height
        return np.ascontiguousarray((sx >= 0) & (sx <= w) & (sy >= 0) & (sy <= h))
