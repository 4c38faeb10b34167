"""RGB-D sequences: ICL-NUIM, TUM RGB-D, 7-Scenes, Redwood / Open3D and ScanNet layouts (colour +
16-bit depth PNG + poses).

Layouts
  icl  ``color/<k>.png``, ``depth/<k>.png`` (same names), ``pose.txt`` (or ``poses.txt``,
       ``groundtruth.txt``) with one line per frame in the numeric order of the file names:
       ``tx ty tz qx qy qz qw``, **camera-to-world**.
  tum  ``rgb/`` and ``depth/`` listed with timestamps in ``rgb.txt``/``depth.txt`` (or an
       associations file ``associations.txt``/``associate.txt``: ``t_rgb rgb/x.png t_depth
       depth/y.png``), ``groundtruth.txt``: ``timestamp tx ty tz qx qy qz qw`` (camera-to-world);
       each colour frame takes the depth and the pose with the nearest timestamp (within
       ``max_dt`` seconds, else the frame is skipped).
  7scenes  one folder of per-frame files as Microsoft 7-Scenes (and ScanNet-style exports) ship
       them: ``frame-000000.color.png`` (or ``.jpg``), ``frame-000000.depth.png`` (uint16
       millimetres, 65535 = invalid), ``frame-000000.pose.txt`` (4x4 **camera-to-world**, camera
       axes x right, y down, z forward: OpenCV's). Frames are matched by the prefix before
       ``.color``; a frame without its depth or pose is an error naming the file.
  redwood  the Redwood RGB-D scans and Open3D's RGBD data sets (``o3d.data.SampleRedwoodRGBDImages``,
       the reconstruction system's input): ``color/`` (or ``image/``, ``rgb/``) and ``depth/``
       (uint16 millimetres), paired in file-name order; a camera trajectory ``trajectory.log``
       (or ``odometry.log``, or ``option trajectory=FILE``): blocks of a header line of three
       integers and a 4x4 **camera-to-world** matrix, one block per image in file-name order,
       OpenCV camera axes; or an Open3D ``PinholeCameraTrajectory`` JSON (``trajectory.json``:
       per frame a column-major world-to-camera ``extrinsic`` and an ``intrinsic``). Intrinsics
       from ``camera_intrinsic.json`` (Open3D's ``PinholeCameraIntrinsic``: ``width``,
       ``height``, column-major ``intrinsic_matrix``) when the folder has one, else the
       trajectory JSON's, else Open3D's PrimeSense default.
  scannet  a ScanNet SensReader export: ``color/<i>.jpg``, ``depth/<i>.png`` (uint16 millimetres),
       ``pose/<i>.txt`` (4x4 **camera-to-world**, OpenCV axes), ``intrinsic/intrinsic_depth.txt``
       and ``intrinsic_color.txt`` (4x4). The views are the depth camera (its intrinsics, the
       pose); where the colour image has another size (ScanNet: 1296x968 beside 640x480), it is
       resampled into the depth camera by the area average of each depth pixel's footprint in
       the colour image (same pose: a scale and an offset per axis from the two intrinsics).
       Frames whose pose is not finite (ScanNet writes -inf where tracking was lost) are skipped,
       counted in one warning.

Convention converted from
  Depth is z (metres = value * depth_scale, 0 = unknown). A pixel (u, v) with depth z is the
  point X = (u - cx) z / fx, Y = (v - cy) z / fy, Z = z of the data set's camera frame, mapped
  to the world by the pose. ``u, v`` are integer pixel indices here, whereas our pixel centres
  are at +0.5: our principal point is ``cx + 0.5, cy + 0.5``.

  A **negative focal length** (ICL-NUIM: fy = -480) means the data set's camera y axis points
  up: its camera frame (x right, y up, z forward) is left-handed. An OpenCV camera needs
  fy > 0, so its y axis is the data set's -Y: ``p_cv = S p_ds`` with S = diag(sign fx, sign fy, 1).
  When det S = -1 (one focal negative), ``world_from_cam = T S`` has det -1 and is no rotation;
  no rigid pose can reproduce the data set's projections in the data set's world. We therefore
  import the scene **mirrored**: world' = S world (y -> -y for ICL), which gives the rigid
  ``world'_from_cam = S T S``. Images, depth, and every distance and angle between cameras are
  unchanged, so warping between views is exact; only a mesh or point given in the data set's
  world coordinates would need the same mirror (``source["world_mirror"]`` records S). With both
  focals negative (det S = +1) the world is kept as it is.

  Checked on ICL-NUIM frames (docs/importers.md): the depth is z, not ray distance, and this
  convention is the most consistent of every axis-sign / pose-inversion variant; the residual
  0.4-1.2 degree disagreement between those frames' poses and their depth maps is in the data.

Options
  intrinsics=FILE       intrinsics file (any layout; relative to the data set folder): an Open3D
                        ``PinholeCameraIntrinsic`` JSON, or a text file of a 3x3 or 4x4 matrix
                        ``fx 0 cx / 0 fy cy / 0 0 1`` (row by row, as ScanNet's
                        ``intrinsic_depth.txt`` or a ``K.txt``), integer pixel centres
  fx, fy, cx, cy        intrinsics in the data set's convention (integer pixel centres); each given
                        one replaces that value of the intrinsics file or the default.
                        Defaults: ICL-NUIM 481.2, -480.0, 319.5, 239.5 (pose_format=icl);
                        TUM/ROS default 525.0, 525.0, 319.5, 239.5 (pose_format=tum)
                        7-Scenes 585, 585, 319.5, 239.5 (its documented principal point (320, 240)
                        is the image centre, i.e. 319.5, 239.5 in integer pixel indices);
                        Redwood / Open3D's PrimeSense default 525, 525, 319.5, 239.5;
                        ScanNet: none (its intrinsic/intrinsic_depth.txt, or all four options)
  depth_scale=          metres per depth unit (ICL-NUIM and TUM: 1/5000; 7-Scenes, Redwood, ScanNet:
                        1/1000)
  invalid_depth=V       a stored depth value meaning unknown, beside 0 which always does
                        (7-Scenes default 65535; others: none)
  max_depth=M           depth beyond M metres is marked unknown (0); default: none
  pose_format=icl|tum|7scenes|redwood|scannet   (default: scannet when color/, depth/ and pose/
                        are folders; redwood when the folder has a Redwood trajectory and none
                        of the ICL/TUM pose files, or when trajectory= is given; else icl when
                        color/ exists, tum when rgb/ exists, 7scenes when the folder holds
                        ``*.pose.txt`` files)
  trajectory=FILE       redwood: the camera trajectory (.log or Open3D .json; default
                        ``trajectory.log``, ``trajectory.json`` or ``odometry.log``)
  max_dt=0.02           TUM: largest timestamp difference accepted, seconds
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, FormatError, MissingFileError, ShapeError
from ibrtools.imageio import read_depth, read_image
from ibrtools.scene import Scene, View
from ibrtools.formats.resize import area_resample
from ibrtools.imageio import F32_MAX
from ibrtools.formats._common import document_errors, FileLoader, check_options, check_same_size, image_size, invert_rigid, named, \
    opt_choice, opt_float, quat_to_rotation, read_json, record_summary, rigid_from_matrix

NAME = "rgbd"
DESCRIPTION = ("RGB-D sequence: ICL-NUIM (color/, depth/, pose.txt), TUM (rgb/, depth/, groundtruth.txt), "
               "7-Scenes (frame-N.color.png, .depth.png, .pose.txt), Redwood / Open3D "
               "(color/, depth/, trajectory.log, camera_intrinsic.json) or a ScanNet export "
               "(color/, depth/, pose/, intrinsic/)")
OPTIONS = {"fx": "focal x (px)", "fy": "focal y (px; negative = flipped y)", "cx": "principal x",
           "cy": "principal y", "intrinsics": "intrinsics file (Open3D JSON, or a 3x3/4x4 matrix as text)",
           "depth_scale": "metres per depth unit (default 1/5000; 7scenes, redwood, scannet 1/1000)",
           "invalid_depth": "stored depth value meaning unknown (0 always is; 7scenes default 65535)",
           "max_depth": "depth beyond this (metres) is marked unknown",
           "pose_format": "icl|tum|7scenes|redwood|scannet", "max_dt": "TUM timestamp tolerance (s)",
           "trajectory": "redwood camera trajectory (.log or Open3D .json)"}
ICL_INTRINSICS = (481.2, -480.0, 319.5, 239.5)
TUM_INTRINSICS = (525.0, 525.0, 319.5, 239.5)
SEVEN_SCENES_INTRINSICS = (585.0, 585.0, 319.5, 239.5)
PRIMESENSE_INTRINSICS = (525.0, 525.0, 319.5, 239.5)  # Open3D's PrimeSenseDefault
# Per layout: (intrinsics, metres per depth unit, the stored value meaning unknown besides 0).
LAYOUT_DEFAULTS = {"icl": (ICL_INTRINSICS, 1 / 5000, None), "tum": (TUM_INTRINSICS, 1 / 5000, None),
                   "7scenes": (SEVEN_SCENES_INTRINSICS, 1 / 1000, 65535),
                   "redwood": (PRIMESENSE_INTRINSICS, 1 / 1000, None),
                   "scannet": (None, 1 / 1000, None)}  # ScanNet's intrinsics are per scene, in its files
SEVEN_SCENES_COLOR = (".color.png", ".color.jpg")
POSE_FILES = ("pose.txt", "poses.txt", "groundtruth.txt")
REDWOOD_COLOR_DIRS = ("color", "image", "rgb")
REDWOOD_TRAJECTORIES = ("trajectory.log", "trajectory.json", "odometry.log")
REDWOOD_INTRINSICS = ("camera_intrinsic.json", "intrinsic.json")
SCANNET_INTRINSICS = "intrinsic/intrinsic_depth.txt"  # the camera of the depth images, which the views take
SCANNET_COLOR_INTRINSICS = "intrinsic/intrinsic_color.txt"
IMAGE_EXTS = {".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff"}


class _Frame(NamedTuple):
    name: str
    color: Path
    depth: Path
    pose: np.ndarray  # world_from_cam, the data set's camera axes
    intrinsics: "_Intrinsics | None" = None  # per-frame intrinsics the layout stores


class _Intrinsics(NamedTuple):
    """Intrinsics in the data set's convention (integer pixel centres), with the image size the
    file states (None when it states none) and the file they came from."""
    fx: float
    fy: float
    cx: float
    cy: float
    size: tuple[int, int] | None
    source: str


def _redwood_dirs(path: Path) -> tuple[Path, Path] | None:
    """(colour folder, depth folder) of a Redwood / Open3D layout, or None."""
    if not (path / "depth").is_dir():
        return None
    color = next((path / d for d in REDWOOD_COLOR_DIRS if (path / d).is_dir()), None)
    return None if color is None else (color, path / "depth")


def _layout(path: Path) -> str | None:
    if all((path / d).is_dir() for d in ("color", "depth", "pose")):
        return "scannet"
    has_pose_file = any((path / f).is_file() for f in POSE_FILES)
    if (not has_pose_file and _redwood_dirs(path) is not None
            and any((path / f).is_file() for f in REDWOOD_TRAJECTORIES)):
        return "redwood"
    if (path / "color").is_dir() and (path / "depth").is_dir():
        return "icl"
    if (path / "rgb").is_dir() and (path / "depth").is_dir():
        return "tum"
    if next(path.glob("*.pose.txt"), None) is not None:
        return "7scenes"
    return None


def detect(path: Path) -> bool:
    path = Path(path)
    if not path.is_dir():
        return False
    lay = _layout(path)
    if lay == "redwood":
        return True
    if lay == "scannet":
        return next((path / "pose").glob("*.txt"), None) is not None
    if lay == "icl":
        return any((path / f).is_file() for f in POSE_FILES)
    if lay == "tum":
        return (path / "groundtruth.txt").is_file()
    if lay == "7scenes":
        return any(next(path.glob("*" + s), None) is not None for s in SEVEN_SCENES_COLOR)
    return False


def _numeric_key(p: Path):
    m = re.findall(r"\d+(?:\.\d+)?", p.stem)
    return (float(m[-1]) if m else float("inf"), p.name)


def _listed(folder: Path, key: Callable[[Path], Any] | None = None) -> list[Path]:
    """The images of ``folder`` (by extension), sorted by ``key`` (default: the file name)."""
    return sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTS), key=key)


def _read_table(path: Path, ncols: int) -> list[list[str]]:
    if not path.is_file():
        raise MissingFileError(f"{path}: no such file")
    rows = []
    for i, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) < ncols:
            raise FormatError(f"{path}:{i}: expected {ncols} columns, got {len(parts)} ({line[:60]!r})")
        rows.append(parts)
    return rows


def _pose(values: list[str], where: str) -> np.ndarray:
    """world_from_cam (data set's camera axes) of ``tx ty tz qx qy qz qw``."""
    try:
        tx, ty, tz, qx, qy, qz, qw = (float(v) for v in values[:7])
    except ValueError:
        raise FormatError(f"{where}: expected 7 numbers 'tx ty tz qx qy qz qw', got {' '.join(values)!r}") from None
    m = np.eye(4)
    m[:3, :3] = quat_to_rotation(qw, qx, qy, qz, where)
    m[:3, 3] = (tx, ty, tz)
    if not np.all(np.isfinite(m)):
        raise BadValueError(f"{where}: pose contains NaN or infinity")
    return m


def _icl_frames(path: Path) -> list[_Frame]:
    colors = _listed(path / "color", key=_numeric_key)
    if not colors:
        raise FormatError(f"{path / 'color'}: no images")
    pose_file = next((path / f for f in POSE_FILES if (path / f).is_file()), None)
    if pose_file is None:
        raise MissingFileError(f"{path}: no pose file ({', '.join(POSE_FILES)})")
    rows = _read_table(pose_file, 7)
    if len(rows) != len(colors):
        raise FormatError(f"{pose_file}: {len(rows)} poses for {len(colors)} images in {path / 'color'} "
                          "(expected one line per image, in the numeric order of the file names)")
    frames = []
    for i, (c, row) in enumerate(zip(colors, rows)):
        d = path / "depth" / c.name
        if not d.is_file():
            raise MissingFileError(f"{d}: depth image of {c} not found")
        frames.append(_Frame(c.stem, c, d, _pose(row[-7:] if len(row) == 8 else row, f"{pose_file} line {i + 1}")))
    return frames


def _seven_scenes_frames(path: Path) -> list[_Frame]:
    colors = sorted(p for s in SEVEN_SCENES_COLOR for p in path.glob("*" + s))
    if not colors:
        raise FormatError(f"{path}: no colour frames (*{' or *'.join(SEVEN_SCENES_COLOR)})")
    frames = []
    for c in colors:
        stem = c.name[: -len(".color") - len(c.suffix)]
        d, pf = path / f"{stem}.depth.png", path / f"{stem}.pose.txt"
        if not d.is_file():
            raise MissingFileError(f"{d}: depth image of {c.name} not found")
        if not pf.is_file():
            raise MissingFileError(f"{pf}: pose of {c.name} not found")
        frames.append(_Frame(stem, c, d, rigid_from_matrix(_pose_matrix(pf), f"{pf}: pose")))
    return frames


def _pose_matrix(pf: Path) -> np.ndarray:
    """The 4x4 camera-to-world matrix of a pose file (4 rows of numbers; not checked further)."""
    try:
        m = np.array([[float(x) for x in ln.split()] for ln in pf.read_text().splitlines() if ln.strip()])
    except ValueError:
        raise FormatError(f"{pf}: expected a 4x4 matrix of numbers (camera-to-world)") from None
    if m.shape != (4, 4):
        raise FormatError(f"{pf}: expected a 4x4 matrix (camera-to-world), got shape {m.shape}")
    return m


def _scannet_frames(path: Path) -> tuple[list[_Frame], list[str]]:
    """Frames of a ScanNet SensReader export, and the pose files of the frames skipped because
    their pose is not finite (ScanNet marks lost tracking with -inf)."""
    colors = _listed(path / "color", key=_numeric_key)
    if not colors:
        raise FormatError(f"{path / 'color'}: no images")
    frames, skipped = [], []
    for c in colors:
        d, pf = path / "depth" / f"{c.stem}.png", path / "pose" / f"{c.stem}.txt"
        if not d.is_file():
            raise MissingFileError(f"{d}: depth image of {c.name} not found")
        if not pf.is_file():
            raise MissingFileError(f"{pf}: pose of {c.name} not found")
        m = _pose_matrix(pf)
        if not np.all(np.isfinite(m)):
            skipped.append(f"pose/{pf.name}")
            continue
        frames.append(_Frame(c.stem, c, d, rigid_from_matrix(m, f"{pf}: pose")))
    if not frames:
        raise FormatError(f"{path / 'pose'}: no frame has a finite pose ({len(skipped)} of {len(colors)} are -inf "
                          "or NaN: tracking lost)")
    return frames, skipped


def _numbers(text: str, where: str) -> list[float]:
    try:
        return [float(x) for x in text.replace(",", " ").split()]
    except ValueError:
        raise FormatError(f"{where}: expected numbers, got {text.strip()[:60]!r}") from None


def _read_log(path: Path) -> list[np.ndarray]:
    """Poses (camera-to-world) of a Redwood ``.log`` trajectory, in file order: blocks of a header
    line of three integers, then the 4 rows of the matrix (Open3D reads it the same way)."""
    if not path.is_file():
        raise MissingFileError(f"{path}: no such file (camera trajectory)")
    lines = [(i, ln) for i, ln in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1)
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines or len(lines) % 5:
        raise FormatError(f"{path}: {len(lines)} lines; expected blocks of 5 (a header of 3 integers, then a "
                          "4x4 camera-to-world matrix), one per frame")
    poses = []
    for b in range(0, len(lines), 5):
        head_no, head = lines[b]
        if len(head.split()) != 3 or not all(re.fullmatch(r"[+-]?\d+", x) for x in head.split()):
            raise FormatError(f"{path}:{head_no}: expected a frame header of 3 integers, got {head.strip()[:60]!r}")
        rows = [_numbers(ln, f"{path}:{no}") for no, ln in lines[b + 1:b + 5]]
        if any(len(r) != 4 for r in rows):
            raise FormatError(f"{path}:{head_no + 1}: expected 4 rows of 4 numbers (camera-to-world) after the header")
        poses.append(rigid_from_matrix(np.array(rows), f"{path}:{head_no + 1}: pose"))
    return poses


def _column_major(values: Any, n: int, where: str) -> np.ndarray:
    """An n x n matrix of Open3D's JSON (Eigen's column-major order)."""
    if not isinstance(values, list) or len(values) != n * n or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        raise FormatError(f"{where}: expected a list of {n * n} numbers (column-major {n}x{n} matrix)")
    return np.array(values, dtype=np.float64).reshape(n, n).T


def _intrinsics_of_matrix(k: np.ndarray, size: tuple[int, int] | None, where: str) -> _Intrinsics:
    if k.shape == (4, 4):
        k = k[:3, :3]
    if k.shape != (3, 3):
        raise FormatError(f"{where}: expected a 3x3 (or 4x4) intrinsic matrix, got shape {k.shape}")
    if not np.all(np.isfinite(k)):
        raise BadValueError(f"{where}: intrinsic matrix contains NaN or infinity")
    if abs(k[0, 1]) > 1e-9 or np.abs(k[1, 0]) > 1e-9 or np.abs(k[2] - (0, 0, 1)).max() > 1e-9:
        raise FormatError(f"{where}: expected a pinhole matrix [[fx 0 cx] [0 fy cy] [0 0 1]] "
                          f"(no skew), got {np.round(k, 4).tolist()}")
    if k[0, 0] == 0 or k[1, 1] == 0:
        raise BadValueError(f"{where}: focal length must not be zero")
    return _Intrinsics(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]), size, where)


def _o3d_intrinsic(obj: Any, where: str) -> _Intrinsics | None:
    """Intrinsics of an Open3D ``PinholeCameraIntrinsic`` JSON object (None when it is the
    'not set' value, width or height -1)."""
    if not isinstance(obj, dict) or "intrinsic_matrix" not in obj:
        raise FormatError(f"{where}: expected an Open3D PinholeCameraIntrinsic "
                          "(width, height, intrinsic_matrix)")
    w, h = obj.get("width"), obj.get("height")
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in (w, h)):
        raise FormatError(f"{where}: width and height must be integers, got {w!r} x {h!r}")
    if w <= 0 or h <= 0:
        return None
    return _intrinsics_of_matrix(_column_major(obj["intrinsic_matrix"], 3, where + ": intrinsic_matrix"),
                                 (w, h), where)


def _read_intrinsics(path: Path) -> _Intrinsics:
    """Intrinsics of a file: an Open3D ``PinholeCameraIntrinsic`` JSON, or text holding a 3x3 or
    4x4 matrix row by row."""
    if not path.is_file():
        raise MissingFileError(f"{path}: no such file (intrinsics)")
    if path.suffix.lower() == ".json":
        k = _o3d_intrinsic(read_json(path), str(path))
        if k is None:
            raise BadValueError(f"{path}: width and height are not set (-1); expected the images' size")
        return k
    text = path.read_text(encoding="utf-8", errors="replace")
    rows = [_numbers(ln, str(path)) for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows or len({len(r) for r in rows}) != 1:
        raise FormatError(f"{path}: expected a 3x3 or 4x4 matrix, one row per line")
    return _intrinsics_of_matrix(np.array(rows), None, str(path))


def _read_o3d_trajectory(path: Path) -> list[tuple[np.ndarray, _Intrinsics | None]]:
    """(camera-to-world, intrinsics or None) per frame of an Open3D ``PinholeCameraTrajectory``."""
    data = read_json(path)
    params = data.get("parameters") if isinstance(data, dict) else None
    if not isinstance(params, list) or not params:
        raise FormatError(f"{path}: expected an Open3D PinholeCameraTrajectory (a non-empty 'parameters' list)")
    out = []
    for i, p in enumerate(params):
        where = f"{path}: parameters[{i}]"
        if not isinstance(p, dict) or "extrinsic" not in p:
            raise FormatError(f"{where}: expected an object with 'extrinsic' (and 'intrinsic')")
        cam_from_world = rigid_from_matrix(_column_major(p["extrinsic"], 4, where + ": extrinsic"),
                                           where + ": extrinsic")
        k = _o3d_intrinsic(p["intrinsic"], where + ": intrinsic") if "intrinsic" in p else None
        out.append((invert_rigid(cam_from_world), k))
    return out




def _redwood_frames(path: Path, trajectory: Path | None) -> list[_Frame]:
    dirs = _redwood_dirs(path)
    if dirs is None:
        raise MissingFileError(f"{path}: expected color/ (or image/, rgb/) and depth/ folders (pose_format=redwood)")
    color_dir, depth_dir = dirs
    colors, depths = _listed(color_dir), _listed(depth_dir)
    if not colors:
        raise FormatError(f"{color_dir}: no images")
    if len(depths) != len(colors):
        raise FormatError(f"{depth_dir}: {len(depths)} depth images for {len(colors)} colour images in "
                          f"{color_dir} (paired in file-name order)")
    if trajectory is None:
        raise MissingFileError(f"{path}: no camera trajectory ({', '.join(REDWOOD_TRAJECTORIES)}; "
                               "or the importer option trajectory=FILE)")
    if trajectory.suffix.lower() == ".json":
        entries = _read_o3d_trajectory(trajectory)
    else:
        entries = [(m, None) for m in _read_log(trajectory)]
    if len(entries) != len(colors):
        raise FormatError(f"{trajectory}: {len(entries)} poses for {len(colors)} images in {color_dir} "
                          "(expected one per image, in file-name order)")
    return [_Frame(c.stem, c, d, pose, k) for c, d, (pose, k) in zip(colors, depths, entries)]


def _option_file(path: Path, options: dict, key: str) -> Path | None:
    if options.get(key) in (None, ""):
        return None
    f = Path(str(options[key])).expanduser()
    return f if f.is_absolute() else path / f


def _load_depth(path: Path, scale: float, invalid: float | None, max_depth: float | None,
                size: tuple[int, int]) -> np.ndarray:
    """Depth in metres of a 16-bit PNG (or float image): ``invalid`` (a stored value) and depth
    beyond ``max_depth`` marked unknown (0)."""
    d = read_depth(path, scale=scale, size=size)
    if invalid is not None:
        # read_depth computes float32(value) * float32(scale): the same product marks the code
        d[d == np.float32(invalid) * np.float32(scale)] = 0.0
    if max_depth is not None:
        d[d > max_depth] = 0.0
    return d


def _color_in_camera(path: Path, k_color: _Intrinsics, k_view: _Intrinsics, out_size: tuple[int, int], *,
                     size: tuple[int, int]) -> np.ndarray:
    """The colour image ``path`` (of ``size``, camera ``k_color``) seen by the camera ``k_view`` of
    ``out_size`` at the same pose: each output pixel is the area average of its footprint (the
    pixel-centre +0.5 convention on both sides; the map is a scale and an offset per axis)."""
    img = read_image(path, size=size)
    w, h = out_size
    xe = (np.arange(w + 1) - (k_view.cx + 0.5)) * abs(k_color.fx / k_view.fx) + (k_color.cx + 0.5)
    ye = (np.arange(h + 1) - (k_view.cy + 0.5)) * abs(k_color.fy / k_view.fy) + (k_color.cy + 0.5)
    return area_resample(img, xe, ye)


def _nearest(times: np.ndarray, t: float) -> int:
    i = int(np.searchsorted(times, t))
    cands = [j for j in (i - 1, i) if 0 <= j < len(times)]
    return min(cands, key=lambda j: abs(times[j] - t))


def _tum_frames(path: Path, max_dt: float) -> list[_Frame]:
    assoc = next((path / f for f in ("associations.txt", "associate.txt") if (path / f).is_file()), None)
    if assoc is not None:
        pairs = [(float(r[0]), path / r[1], path / r[3]) for r in _read_table(assoc, 4)]
    else:
        rgb = [(float(r[0]), path / r[1]) for r in _read_table(path / "rgb.txt", 2)]
        dep = [(float(r[0]), path / r[1]) for r in _read_table(path / "depth.txt", 2)]
        if not dep:
            raise FormatError(f"{path / 'depth.txt'}: no entries")
        dt = np.array([t for t, _ in dep])
        pairs = []
        for t, p in rgb:
            j = _nearest(dt, t)
            if abs(dt[j] - t) <= max_dt:
                pairs.append((t, p, dep[j][1]))
    gt_file = path / "groundtruth.txt"
    gt = _read_table(gt_file, 8)
    if not gt:
        raise FormatError(f"{gt_file}: no poses")
    gt_t = np.array([float(r[0]) for r in gt])
    order = np.argsort(gt_t)
    gt_t, gt = gt_t[order], [gt[i] for i in order]
    frames = []
    for t, c, d in pairs:
        j = _nearest(gt_t, t)
        if abs(gt_t[j] - t) > max_dt:
            continue
        frames.append(_Frame(c.stem, c, d, _pose(gt[j][1:8], f"{gt_file} t={gt_t[j]}")))
    if not frames:
        raise FormatError(f"{path}: no colour frame has a depth image and a pose within {max_dt} s")
    return frames


def _frame_intrinsics(frame: _Frame, base: _Intrinsics | None, default: tuple[float, ...] | None,
                      overrides: dict[str, float]) -> _Intrinsics:
    """The intrinsics of one frame: the intrinsics file, else the frame's own, else the layout's
    default; then each of fx, fy, cx, cy given as an option replaces its value."""
    k = base or frame.intrinsics
    if k is None:
        if default is None:
            if len(overrides) < 4:
                raise MissingFileError(f"{frame.color.parent.parent}: no intrinsics file ({SCANNET_INTRINSICS}); "
                                       "give the importer option intrinsics=FILE or all of fx, fy, cx, cy")
            default = (0.0, 0.0, 0.0, 0.0)
        k = _Intrinsics(*default, None, "options fx, fy, cx, cy")
    return k._replace(**overrides) if overrides else k


@document_errors
def load(path: Path, options: dict) -> Scene:
    path = Path(path)
    options = check_options(options, OPTIONS, NAME)
    if not path.is_dir():
        raise MissingFileError(f"{path}: not a directory (expected color/ or rgb/, depth/ and poses)")
    lay = "redwood" if options.get("trajectory") not in (None, "") else _layout(path)
    fmt = opt_choice(options, "pose_format", lay or "icl", tuple(LAYOUT_DEFAULTS))
    defaults, default_scale, default_invalid = LAYOUT_DEFAULTS[fmt]
    overrides = {k: opt_float(options, k, None) for k in ("fx", "fy", "cx", "cy") if options.get(k) is not None}
    for k in ("fx", "fy"):
        if overrides.get(k) == 0:
            raise BadValueError(f"option {k}: focal length must not be zero")
    intrinsics_file = _option_file(path, options, "intrinsics")
    if intrinsics_file is None and fmt == "redwood":
        intrinsics_file = next((path / f for f in REDWOOD_INTRINSICS if (path / f).is_file()), None)
    if intrinsics_file is None and fmt == "scannet" and (path / SCANNET_INTRINSICS).is_file():
        intrinsics_file = path / SCANNET_INTRINSICS
    color_k = None  # the colour camera, when the layout records it apart from the depth's
    if fmt == "scannet" and (path / SCANNET_COLOR_INTRINSICS).is_file():
        color_k = _read_intrinsics(path / SCANNET_COLOR_INTRINSICS)
    base = _read_intrinsics(intrinsics_file) if intrinsics_file is not None else None
    depth_scale = opt_float(options, "depth_scale", default_scale, positive=True)
    invalid = opt_float(options, "invalid_depth", default_invalid, positive=True)
    max_depth = opt_float(options, "max_depth", None, positive=True)
    if depth_scale * 65535 > F32_MAX:
        # the largest 16-bit value would be infinite depth (float32): refused here, by name
        raise BadValueError(f"option depth_scale: {depth_scale:g} times 65535 (the largest 16-bit depth value) "
                            f"overflows float32 (largest {F32_MAX:.3g}); expected metres per depth unit")
    max_dt = opt_float(options, "max_dt", 0.02, positive=True)
    skipped: list[str] = []
    if fmt == "icl":
        if not (path / "color").is_dir():
            raise MissingFileError(f"{path / 'color'}: no such directory (pose_format=icl)")
        frames = _icl_frames(path)
    elif fmt == "7scenes":
        frames = _seven_scenes_frames(path)
    elif fmt == "scannet":
        for d in ("color", "depth", "pose"):
            if not (path / d).is_dir():
                raise MissingFileError(f"{path / d}: no such directory (pose_format=scannet)")
        frames, skipped = _scannet_frames(path)
    elif fmt == "redwood":
        trajectory = _option_file(path, options, "trajectory") or next(
            (path / f for f in REDWOOD_TRAJECTORIES if (path / f).is_file()), None)
        frames = _redwood_frames(path, trajectory)
    else:
        frames = _tum_frames(path, max_dt)

    first = _frame_intrinsics(frames[0], base, defaults, overrides)
    s = np.diag([np.sign(first.fx), np.sign(first.fy), 1.0, 1.0])  # data set camera axes -> OpenCV
    mirror = np.linalg.det(s[:3, :3]) < 0
    m = s if mirror else np.eye(4)  # world -> imported world
    views = []
    size = None
    resampled = None  # (colour size, view size) of colour images resampled into the depth camera
    for frame in frames:
        name, color, depth, world_from_cam_ds = frame.name, frame.color, frame.depth, frame.pose
        for f in (color, depth):
            if not f.is_file():
                raise MissingFileError(f"{f}: no such file")
        k = _frame_intrinsics(frame, base, defaults, overrides)
        color_size = image_size(color)
        if color_k is None:
            if size is None:
                size = color_size
            else:
                check_same_size(color, size, "colour image", f"size of {frames[0][1].name}")
            check_same_size(depth, size, "depth image", f"size of its colour image {color.name}")
            color_loader = FileLoader(color, read_image, color, size=size)
        else:  # the view is the depth camera; its colour is resampled into it when the sizes differ
            if size is None:
                size = image_size(depth)
            else:
                check_same_size(depth, size, "depth image", f"size of {frames[0].depth.name}")
            if color_size == size:
                color_loader = FileLoader(color, read_image, color, size=size)
            else:
                color_loader = FileLoader(color, _color_in_camera, color, color_k, k, size, size=color_size)
                resampled = (color_size, size)
        if k.size is not None and tuple(k.size) != tuple(size):
            raise ShapeError(f"{k.source}: intrinsics are for {k.size[0]}x{k.size[1]} images, but {color} is "
                             f"{size[0]}x{size[1]}")
        if (np.sign(k.fx), np.sign(k.fy)) != (s[0, 0], s[1, 1]):
            raise BadValueError(f"{k.source}: the focal lengths of {color.name} ({k.fx:g}, {k.fy:g}) have other "
                                f"signs than the first frame's ({first.fx:g}, {first.fy:g})")
        # world'_from_cam_cv = M T S (S = S^-1); rigid by construction (see the docstring).
        world_from_cam = m @ world_from_cam_ds @ s
        with named(f"{color} ({k.source} and its pose)"):
            cam = Camera.pinhole(size[0], size[1], abs(k.fx), abs(k.fy), k.cx + 0.5, k.cy + 0.5,
                                 invert_rigid(world_from_cam))
        if invalid is None and max_depth is None:  # as stored
            depth_loader = FileLoader(depth, read_depth, depth, scale=depth_scale, size=size)
        else:
            depth_loader = FileLoader(depth, _load_depth, depth, depth_scale, invalid, max_depth, size=size)
        views.append(View.create(name, cam, color=color_loader, depth=depth_loader))
    adapted, warnings = [], []
    if skipped:
        adapted.append(f"{len(skipped)} frames skipped (pose not finite)")
        warnings.append(f"{len(skipped)} of {len(skipped) + len(frames)} frames skipped: pose not finite, tracking "
                        f"lost ({', '.join(skipped[:3])}{', ...' if len(skipped) > 3 else ''})")
    if resampled is not None:
        (cw, ch), (w, h) = resampled
        adapted.append(f"colour resampled from {cw}x{ch} ({SCANNET_COLOR_INTRINSICS}) into the depth camera "
                       f"{w}x{h} (area average)")
    if invalid is not None:
        how = "invalid_depth" if "invalid_depth" in options else f"invalid_depth, the {fmt} default"
        adapted.append(f"depth value {invalid:g} marked unknown ({how})")
    if max_depth is not None:
        adapted.append(f"depth beyond {max_depth:g} m marked unknown (max_depth)")
    notes = f"depth z = value * {depth_scale:g} m; poses camera-to-world ({fmt})"
    if base is not None:
        notes += f"; intrinsics from {base.source}"
    elif frames[0].intrinsics is not None:
        notes += "; intrinsics per frame from the trajectory"
    if mirror:
        notes += (f"; negative focal ({'fx' if first.fx < 0 else 'fy'}): world mirrored by "
                  f"diag{tuple(int(v) for v in np.diag(s)[:3])} to keep poses rigid")
    source = {"format": NAME, "path": str(path), "layout": fmt, "notes": notes,
              "world_mirror": np.diag(m)[:3].tolist()}
    record_summary(source, adapted=adapted, warnings=warnings)
    return Scene(views=views, units="m", source=source, root=path)
