"""LLFF captures: ``poses_bounds.npy`` + images (Mildenhall et al. 2019, *Local Light Field
Fusion*; the NeRF "real forward-facing" scenes).

Convention converted from (LLFF's ``imgs2poses.py``, ``llff/poses/pose_utils.py``)
  ``poses_bounds.npy`` is float (N, 17), one row per image in the sorted order of the image file
  names. Each row is a 3x5 matrix (row-major, the first 15 values) and two bounds:
  ``[R | t | hwf]`` where R, t is **camera-to-world** and hwf = (height, width, focal) of the images
  the poses were computed from (COLMAP's first camera: one shared focal, the principal point at
  the centre). LLFF stores R's columns as the camera's (down, right, back) axes: it took COLMAP's
  camera-to-world columns (right, down, forward) = (x, y, z) of OpenCV and wrote (y, x, -z). So
  the OpenCV camera-to-world rotation is ``[R[:, 1], R[:, 0], -R[:, 2]]``, inverted to
  ``cam_from_world``. The world frame and scale are kept as they are (no recentring, no
  ``bd_factor`` rescaling as NeRF's loader does): units "unknown".
  Intrinsics: fx = fy = focal, principal point (w/2, h/2) — the image centre in COLMAP's (and our)
  pixel-centre-at-+0.5 convention. Images of another size than hwf (``images_4``, ``images_8``)
  scale the focal by their width ratio; the aspect ratio must agree to a pixel.
  Bounds: (near, far), the 0.1 and 99.9 percentiles of the z-depth of the sparse points the view
  sees. They are kept as ``source["depth_bounds"]`` {view: [near, far]}: the depth range the
  multi-view stereo stage searches for that view (``mvs.depth_range=auto``; docs/mvs.md).

Layout
  ``poses_bounds.npy`` beside ``images/`` (or the single ``images_*/`` when there is no
  ``images/``); image files ``.jpg .jpeg .png`` (any case), sorted by name as LLFF sorts them.

Options
  images=DIR    the image folder, relative to the input (e.g. images_4)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, FormatError, MissingFileError
from ibrtools.imageio import read_image
from ibrtools.scene import Scene, View
from ibrtools.formats._common import FileLoader, check_options, document_errors, image_size, invert_rigid, named, rigid_from_matrix

NAME = "llff"
DESCRIPTION = "LLFF capture: poses_bounds.npy (N x 17, camera-to-world in down/right/back axes) + images/"
OPTIONS = {"images": "image folder relative to the input (default images/, else the single images_*/)"}
POSES_FILE = "poses_bounds.npy"
IMAGE_EXTS = {".jpg", ".jpeg", ".png"}
# LLFF's (down, right, back) camera axes -> OpenCV's (right, down, forward): columns (1, 0, -2).
DRB_TO_CV = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def detect(path: Path) -> bool:
    path = Path(path)
    return path.is_dir() and (path / POSES_FILE).is_file()


def _image_dir(path: Path, options: dict) -> Path:
    if "images" in options:
        d = path / str(options["images"])
        if not d.is_dir():
            raise MissingFileError(f"{d}: no such directory (option images=)")
        return d
    if (path / "images").is_dir():
        return path / "images"
    cands = sorted(d for d in path.glob("images_*") if d.is_dir())
    if len(cands) != 1:
        raise FormatError(f"{path}: no image folder (expected images/ or a single images_*/, found "
                          f"{[d.name for d in cands] or 'none'}; give the importer option images=DIR)")
    return cands[0]


def read_poses_bounds(f: Path) -> np.ndarray:
    """``poses_bounds.npy`` as float64 (N, 17), checked (no pickles, finite values)."""
    if not f.is_file():
        raise MissingFileError(f"{f}: no such file")
    try:
        arr = np.load(f, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise FormatError(f"{f}: not a numpy array file ({e})") from None
    if arr.ndim != 2 or arr.shape[1] != 17 or arr.shape[0] == 0 or not np.issubdtype(arr.dtype, np.number):
        raise FormatError(f"{f}: expected a numeric (N, 17) array (3x5 pose + near, far per image), got "
                          f"{arr.dtype} {arr.shape}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise BadValueError(f"{f}: contains NaN or infinity")
    return arr


@document_errors
def load(path: Path, options: dict) -> Scene:
    path = Path(path)
    options = check_options(options, OPTIONS, NAME)
    if not path.is_dir():
        raise MissingFileError(f"{path}: not a directory (expected {POSES_FILE} and images/)")
    pf = path / POSES_FILE
    arr = read_poses_bounds(pf)
    images_dir = _image_dir(path, options)
    files = sorted(p for p in images_dir.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS)
    if len(files) != len(arr):
        raise FormatError(f"{pf}: {len(arr)} poses for {len(files)} images in {images_dir} (expected one row per "
                          "image, in the sorted order of the file names)")
    views, bounds = [], {}
    for i, (img, row) in enumerate(zip(files, arr)):
        where = f"{pf} row {i} ({img.name})"
        p = row[:15].reshape(3, 5)
        h, w, focal = p[:, 4]
        near, far = row[15], row[16]
        if not (focal > 0 and h >= 1 and w >= 1):
            raise BadValueError(f"{where}: hwf = ({h:g}, {w:g}, {focal:g}); expected a positive height, width "
                                "and focal length")
        if not 0 < near < far:
            raise BadValueError(f"{where}: bounds ({near:g}, {far:g}); expected 0 < near < far")
        c2w = np.eye(4)
        c2w[:3, :3] = p[:, :3] @ DRB_TO_CV
        c2w[:3, 3] = p[:, 3]
        c2w = rigid_from_matrix(c2w, f"{where} pose")
        wi, hi = image_size(img)
        s = wi / w
        if abs(h * s - hi) > 1.0:
            raise FormatError(f"{img}: image is {wi}x{hi} but {pf} row {i} gives {w:g}x{h:g}: different aspect "
                              "ratio, cannot scale")
        with named(where):
            cam = Camera.pinhole(wi, hi, focal * s, focal * s, wi / 2, hi / 2, invert_rigid(c2w))
        views.append(View.create(img.stem, cam, color=FileLoader(img, read_image, img, size=(wi, hi))))
        bounds[img.stem] = [float(near), float(far)]
    if len({v.name for v in views}) != len(views):
        raise FormatError(f"{images_dir}: two images share a name stem")
    hwf = arr[0, :15].reshape(3, 5)[:, 4]
    notes = (f"poses camera-to-world in LLFF's down/right/back axes, converted to OpenCV; the capture's own frame "
             f"and scale; focal {hwf[2]:g} px at {hwf[1]:g}x{hwf[0]:g}"
             + (f", scaled to the images ({views[0].camera.width}x{views[0].camera.height})"
                if views[0].camera.width != int(round(hwf[1])) else ""))
    return Scene(views=views, units="unknown",
                 source={"format": NAME, "path": str(path), "images": str(images_dir), "notes": notes,
                         "depth_bounds": bounds},
                 root=path)
