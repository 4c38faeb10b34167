"""Pose files: the cameras ``ibr-render --poses FILE`` renders, in one of three conventions,
told apart by the JSON's shape (docs/render.md "Pose files"):

* ours: a JSON list of cameras in the scene.json camera format (docs/FORMAT.md), or an object
  with that list under ``cameras``; each camera optionally with a ``name``;
* nerfstudio ``camera_path.json`` (``ns-render camera-path``; an object with ``camera_path``):
  each entry's ``camera_to_world`` (4x4 or 3x4, nested or flat row-major 16 / 12 numbers) in
  Blender/OpenGL camera axes, converted as the NeRF importer does (``nerf.cam_from_gl``); the
  image ``render_width`` x ``render_height`` (width from ``aspect`` x height when
  ``render_width`` is absent); ``fov`` the vertical field of view in degrees, so
  ``fx = fy = (h / 2) / tan(fov / 2)`` and the principal point at the image centre, as
  nerfstudio's renderer does. Only perspective paths (``camera_type`` absent or
  "perspective"). The matrices are read in the scene's world frame: a path drawn in
  nerfstudio's viewer is in its data parser's normalised frame (dataparser_transforms.json),
  which must be undone first;
* transforms-style (instant-ngp / nerfstudio ``transforms.json``; an object with ``frames``):
  each frame's ``transform_matrix`` with the NeRF importer's intrinsics (``fl_x``/``fl_y``/
  ``cx``/``cy`` or ``camera_angle_x``/``_y``, ``w``/``h``, at top level or per frame:
  ``nerf.frame_camera``); without ``w``/``h`` the size is read from the header of the frame's
  ``file_path`` image when it is there. Lens distortion keys are ignored: the cameras rendered
  are the undistorted pinholes the importer makes of such frames.

Frames are named by their ``name`` (ours), their ``file_path`` stem (transforms), else
``pose_000``, ``pose_001``, ...
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ibrtools.camera import MAX_SIDE, Camera
from ibrtools.errors import FormatError, InputError, MissingFileError
from ibrtools.formats._common import image_size, named, read_json
from ibrtools.formats.nerf import cam_from_gl, frame_camera, frame_size, resolve_image

def load(path: str | Path, argument: str = "poses") -> list[tuple[str, Camera]]:
    """[(name, camera)] of the pose file ``path``; its errors are about the argument ``argument``
    and start with the file ("poses: cams.json[2]: missing 'cam_from_world'")."""
    try:
        return _load(Path(path))
    except InputError as e:
        if e.argument:
            raise
        raise type(e).about(argument, str(e)) from None


def _load(path: Path) -> list[tuple[str, Camera]]:
    where = str(path)
    if not path.is_file():
        raise MissingFileError(f"{where}: no such file")
    doc = read_json(path)
    if isinstance(doc, dict) and "camera_path" in doc:
        return _nerfstudio(doc, where)
    if isinstance(doc, dict) and "frames" in doc:
        return _transforms(doc, path, where)
    if isinstance(doc, dict) and "cameras" in doc:
        doc = doc["cameras"]
    if not isinstance(doc, list) or not doc:
        raise FormatError(f"{where}: expected a non-empty JSON list of cameras (scene.json format), a nerfstudio "
                          "camera_path.json ('camera_path') or a transforms.json ('frames')")
    out = []
    for i, d in enumerate(doc):
        cam = Camera.from_dict(d, f"{path.name}[{i}]")
        out.append((str(d.get("name", f"pose_{i:03d}")), cam))
    return out


def _positive_int(d: dict, key: str, where: str) -> int:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 1 <= v <= MAX_SIDE or not float(v).is_integer():
        raise FormatError(f"{where}: '{key}': expected an integer in [1, {MAX_SIDE}], got {v!r}")
    return int(v)


def _matrix(m: Any, where: str) -> np.ndarray:
    """A 4x4 / 3x4 matrix given nested or flat row-major (16 or 12 numbers)."""
    try:
        a = np.array(m, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise FormatError(f"{where}: expected a 4x4 matrix of numbers") from None
    if a.shape in ((16,), (12,)):
        a = a.reshape(-1, 4)
    if a.shape not in ((4, 4), (3, 4)):
        raise FormatError(f"{where}: expected a 4x4 matrix (nested, or 16 numbers row-major), got shape {a.shape}")
    return a


def _nerfstudio(doc: dict, where: str) -> list[tuple[str, Camera]]:
    path = doc["camera_path"]
    if not isinstance(path, list) or not path:
        raise FormatError(f"{where}: 'camera_path': expected a non-empty list of cameras")
    kind = str(doc.get("camera_type", "perspective")).lower()
    if kind != "perspective":
        raise FormatError(f"{where}: camera_type {doc.get('camera_type')!r}: only perspective camera paths are read")
    h = _positive_int(doc, "render_height", where)
    out = []
    for i, c in enumerate(path):
        at = f"{where}: camera_path[{i}]"
        if not isinstance(c, dict) or "camera_to_world" not in c:
            raise FormatError(f"{at}: missing key 'camera_to_world'")
        if "render_width" in doc:
            w = _positive_int(doc, "render_width", where)
        else:
            aspect = c.get("aspect", doc.get("aspect"))
            if isinstance(aspect, bool) or not isinstance(aspect, (int, float)) or not 0 < aspect < 1e4:
                raise FormatError(f"{where}: missing 'render_width' (or a positive 'aspect'), got aspect {aspect!r}")
            w = max(1, round(h * float(aspect)))
        fov = c.get("fov", doc.get("fov"))
        if isinstance(fov, bool) or not isinstance(fov, (int, float)) or not 0 < fov < 180:
            raise FormatError(f"{at}: 'fov': expected the vertical field of view in degrees in (0, 180), got {fov!r}")
        f = 0.5 * h / math.tan(math.radians(float(fov)) / 2)
        pose = cam_from_gl(_matrix(c["camera_to_world"], f"{at}.camera_to_world"), f"{at}.camera_to_world")
        with named(at):
            out.append((f"pose_{i:03d}", Camera.pinhole(w, h, f, f, w / 2, h / 2, pose)))
    return out


def _transforms(doc: dict, path: Path, where: str) -> list[tuple[str, Camera]]:
    frames = doc["frames"]
    if not isinstance(frames, list) or not frames:
        raise FormatError(f"{where}: 'frames': expected a non-empty list")
    out = []
    for i, fr in enumerate(frames):
        at = f"{where}: frames[{i}]"
        if not isinstance(fr, dict):
            raise FormatError(f"{at}: expected a JSON object")
        size = frame_size({**doc, **fr}, at)
        image = resolve_image(path.parent, str(fr["file_path"])) if "file_path" in fr else None
        if size is None:
            if image is None:
                raise FormatError(f"{at}: missing 'w'/'h' (and no image at its file_path to read the size from)")
            size = image_size(image)
        if "transform_matrix" in fr:
            fr = {**fr, "transform_matrix": _matrix(fr["transform_matrix"], f"{at} transform_matrix")}
        cam = frame_camera(doc, fr, size, at)
        name = Path(str(fr["file_path"])).stem if "file_path" in fr else f"pose_{i:03d}"
        out.append((name, cam))
    return out

