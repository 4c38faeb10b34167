"""Middlebury stereo pairs with ground-truth disparity (2003 and 2005 data sets).

Layouts (one scene folder)
  2003 (Teddy, Cones): ``im2.png`` (left), ``im6.png`` (right), ``disp2.png``, ``disp6.png``;
       8-bit disparity = value / 4 at quarter size; optional ``occl.png`` (white = not occluded
       in the left view) and ``occ_and_discont.png`` (0 occluded, 128 discontinuity, 255 other).
  2005 (Art, Books, ...): ``view1.png`` (left), ``view5.png`` (right), ``disp1.png``,
       ``disp5.png``; disparity = value / 3 at third size.
  Disparity 0 = unknown (depth 0).

Convention converted from
  The pair is rectified: a left pixel (x, y) with disparity d appears at (x - d, y) on the right.
  Both cameras get the same pinhole intrinsics fx = fy = ``focal`` (pixels; default the image
  width), cx = W/2, cy = H/2 (any common principal point is exact for a rectified pair). The
  left camera is at the origin with identity rotation; the right camera is translated by
  +``baseline`` along x (OpenCV x right): cam_from_world = [I | (-B, 0, 0)]. Depth is
  z = focal * baseline / d **with the same focal as the cameras**, so that a left point at
  (x, z) projects to x - f B / z = x - d in the right view, exactly.
  Units: with the default baseline (1) the geometry is in baseline units, reported as
  "disparity" (depth scales with 1/d); give ``baseline`` (metres) and ``focal`` to get "m".

The occlusion masks are not view masks (occluded pixels are still scene content): their paths
are recorded in ``scene.source["masks"]`` for evaluation; ``nonoccluded_mask(scene)`` reads them.

Options
  focal=<W>        focal length in pixels of both cameras (default: image width)
  baseline=1       distance between the camera centres
  disp_scale=4|3   stored value per pixel of disparity (default 4 for im2/im6, 3 for view1/view5)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import DtypeError, FormatError, MissingFileError, ShapeError
from ibrtools.imageio import read_pixels, read_image
from ibrtools.scene import Scene, View
from ibrtools.formats._common import document_errors, FileLoader, check_options, check_same_size, image_size, named, opt_float

NAME = "middlebury"
DESCRIPTION = "Middlebury stereo pair with disparity (im2/im6 + disp2/disp6, or view1/view5 + disp1/disp5)"
OPTIONS = {"focal": "focal length in pixels (default image width)", "baseline": "camera distance (default 1)",
           "disp_scale": "stored value per pixel of disparity (default 4 or 3)"}
# (left image, right image, left disparity, right disparity, default disparity scale)
LAYOUTS = (("im2.png", "im6.png", "disp2.png", "disp6.png", 4.0),
           ("view1.png", "view5.png", "disp1.png", "disp5.png", 3.0))


def _layout(path: Path):
    for lay in LAYOUTS:
        if (path / lay[0]).is_file() and (path / lay[1]).is_file() and (path / lay[2]).is_file():
            return lay
    return None


def detect(path: Path) -> bool:
    path = Path(path)
    return path.is_dir() and _layout(path) is not None


def _load_depth(path: Path, disp_scale: float, focal: float, baseline: float, shape: tuple[int, int]) -> np.ndarray:
    arr, fmt = read_pixels(path, (shape[1], shape[0]))  # another size is refused from the header
    if fmt not in ("uint8", "uint16"):
        raise DtypeError(f"{path}: expected an 8- or 16-bit disparity PNG, got {fmt}")
    if arr.shape[:2] != shape:
        raise ShapeError(f"{path}: disparity is {arr.shape[1]}x{arr.shape[0]}, expected {shape[1]}x{shape[0]}")
    disp = arr[..., 0].astype(np.float64) / disp_scale
    with np.errstate(divide="ignore"):
        z = np.where(disp > 0, focal * baseline / np.where(disp > 0, disp, 1.0), 0.0)
    return np.ascontiguousarray(z.astype(np.float32))


@document_errors
def load(path: Path, options: dict) -> Scene:
    path = Path(path)
    options = check_options(options, OPTIONS, NAME)
    if not path.is_dir():
        raise MissingFileError(f"{path}: not a directory")
    lay = _layout(path)
    if lay is None:
        raise FormatError(f"{path}: no Middlebury pair (expected im2.png, im6.png, disp2.png or "
                          "view1.png, view5.png, disp1.png)")
    left, right, dleft, dright, scale_default = (path / f if isinstance(f, str) else f for f in lay)
    w, h = image_size(left)
    check_same_size(right, (w, h), "right image", f"size of {left.name}")
    focal = opt_float(options, "focal", float(w), positive=True)
    baseline = opt_float(options, "baseline", 1.0, positive=True)
    disp_scale = opt_float(options, "disp_scale", scale_default, positive=True)
    views = []
    for name, img, disp, tx in (("left", left, dleft, 0.0), ("right", right, dright, -baseline)):
        pose = np.eye(4)
        pose[0, 3] = tx
        with named(f"{img} (options focal, baseline)"):
            cam = Camera.pinhole(w, h, focal, focal, w / 2, h / 2, pose)
        depth = None
        if disp.is_file():
            check_same_size(disp, (w, h), "disparity image", f"size of {img.name}")
            depth = FileLoader(disp, _load_depth, disp, disp_scale, focal, baseline, (h, w))
        views.append(View.create(name, cam, color=FileLoader(img, read_image, img, size=(w, h)), depth=depth))
    masks = {k: str(path / f) for k, f in (("left_nonoccluded", "occl.png"),
                                            ("left_nonoccluded_nondiscontinuity", "occ_and_discont.png"))
             if (path / f).is_file()}
    units = "disparity" if "baseline" not in options else "m"
    return Scene(views=views, units=units,
                 source={"format": NAME, "path": str(path), "masks": masks,
                         "notes": f"depth = {focal:g} px * {baseline:g} / (value / {disp_scale:g}); "
                                  "disparity 0 = unknown; right camera at +baseline along x"},
                 root=path)


def nonoccluded_mask(scene: Scene, which: str = "left_nonoccluded") -> np.ndarray | None:
    """Boolean mask of the left view from the occlusion image (True = visible in both views,
    and for ``left_nonoccluded_nondiscontinuity`` also away from depth edges), or None."""
    f = scene.source.get("masks", {}).get(which)
    if f is None:
        return None
    left = scene.views[0].camera if scene.views else None
    arr, _ = read_pixels(f, (left.width, left.height) if left is not None else None)
    return np.ascontiguousarray(arr[..., 0] == arr[..., 0].max()) if arr.max() > 0 else arr[..., 0] > 0
