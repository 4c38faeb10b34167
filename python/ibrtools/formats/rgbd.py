"""RGB-D sequences: ICL-NUIM, TUM RGB-D and 7-Scenes layouts (colour + 16-bit depth PNG + poses).

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
  fx, fy, cx, cy        intrinsics in the data set's convention (integer pixel centres).
                        Defaults: ICL-NUIM 481.2, -480.0, 319.5, 239.5 (pose_format=icl);
                        TUM/ROS default 525.0, 525.0, 319.5, 239.5 (pose_format=tum)
                        7-Scenes 585, 585, 319.5, 239.5 (its documented principal point (320, 240)
                        is the image centre, i.e. 319.5, 239.5 in integer pixel indices)
  depth_scale=          metres per depth unit (ICL-NUIM and TUM: 1/5000; 7-Scenes: 1/1000)
  invalid_depth=V       a stored depth value meaning unknown, beside 0 which always does
                        (7-Scenes default 65535; others: none)
  max_depth=M           depth beyond M metres is marked unknown (0); default: none
  pose_format=icl|tum|7scenes   (default: icl when color/ exists, tum when rgb/ exists, 7scenes
                        when the folder holds ``*.pose.txt`` files)
  max_dt=0.02           TUM: largest timestamp difference accepted, seconds
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, FormatError, MissingFileError
from ibrtools.imageio import read_depth, read_image
from ibrtools.scene import Scene, View
from ibrtools.imageio import F32_MAX
from ibrtools.formats._common import document_errors, FileLoader, check_options, check_same_size, image_size, invert_rigid, named, \
    opt_choice, opt_float, quat_to_rotation, record_summary, rigid_from_matrix

NAME = "rgbd"
DESCRIPTION = ("RGB-D sequence: ICL-NUIM (color/, depth/, pose.txt), TUM (rgb/, depth/, groundtruth.txt) or "
               "7-Scenes (frame-N.color.png, .depth.png, .pose.txt)")
OPTIONS = {"fx": "focal x (px)", "fy": "focal y (px; negative = flipped y)", "cx": "principal x",
           "cy": "principal y", "depth_scale": "metres per depth unit (default 1/5000; 7scenes 1/1000)",
           "invalid_depth": "stored depth value meaning unknown (0 always is; 7scenes default 65535)",
           "max_depth": "depth beyond this (metres) is marked unknown",
           "pose_format": "icl|tum|7scenes", "max_dt": "TUM timestamp tolerance (s)"}
ICL_INTRINSICS = (481.2, -480.0, 319.5, 239.5)
TUM_INTRINSICS = (525.0, 525.0, 319.5, 239.5)
SEVEN_SCENES_INTRINSICS = (585.0, 585.0, 319.5, 239.5)
# Per layout: (intrinsics, metres per depth unit, the stored value meaning unknown besides 0).
LAYOUT_DEFAULTS = {"icl": (ICL_INTRINSICS, 1 / 5000, None), "tum": (TUM_INTRINSICS, 1 / 5000, None),
                   "7scenes": (SEVEN_SCENES_INTRINSICS, 1 / 1000, 65535)}
SEVEN_SCENES_COLOR = (".color.png", ".color.jpg")
POSE_FILES = ("pose.txt", "poses.txt", "groundtruth.txt")
IMAGE_EXTS = {".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff"}


def _layout(path: Path) -> str | None:
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


def _icl_frames(path: Path) -> list[tuple[str, Path, Path, np.ndarray]]:
    colors = sorted((p for p in (path / "color").iterdir() if p.suffix.lower() in IMAGE_EXTS), key=_numeric_key)
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
        frames.append((c.stem, c, d, _pose(row[-7:] if len(row) == 8 else row, f"{pose_file} line {i + 1}")))
    return frames


def _seven_scenes_frames(path: Path) -> list[tuple[str, Path, Path, np.ndarray]]:
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
        try:
            m = np.array([[float(x) for x in ln.split()] for ln in pf.read_text().splitlines() if ln.strip()])
        except ValueError:
            raise FormatError(f"{pf}: expected a 4x4 matrix of numbers (camera-to-world)") from None
        if m.shape != (4, 4):
            raise FormatError(f"{pf}: expected a 4x4 matrix (camera-to-world), got shape {m.shape}")
        frames.append((stem, c, d, rigid_from_matrix(m, f"{pf}: pose")))
    return frames


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


def _nearest(times: np.ndarray, t: float) -> int:
    i = int(np.searchsorted(times, t))
    cands = [j for j in (i - 1, i) if 0 <= j < len(times)]
    return min(cands, key=lambda j: abs(times[j] - t))


def _tum_frames(path: Path, max_dt: float) -> list[tuple[str, Path, Path, np.ndarray]]:
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
        frames.append((c.stem, c, d, _pose(gt[j][1:8], f"{gt_file} t={gt_t[j]}")))
    if not frames:
        raise FormatError(f"{path}: no colour frame has a depth image and a pose within {max_dt} s")
    return frames


@document_errors
def load(path: Path, options: dict) -> Scene:
    path = Path(path)
    options = check_options(options, OPTIONS, NAME)
    if not path.is_dir():
        raise MissingFileError(f"{path}: not a directory (expected color/ or rgb/, depth/ and poses)")
    lay = _layout(path)
    fmt = opt_choice(options, "pose_format", lay or "icl", tuple(LAYOUT_DEFAULTS))
    defaults, default_scale, default_invalid = LAYOUT_DEFAULTS[fmt]
    fx, fy, cx, cy = (opt_float(options, k, d) for k, d in zip(("fx", "fy", "cx", "cy"), defaults))
    for k, v in (("fx", fx), ("fy", fy)):
        if v == 0:
            raise BadValueError(f"option {k}: focal length must not be zero")
    depth_scale = opt_float(options, "depth_scale", default_scale, positive=True)
    invalid = opt_float(options, "invalid_depth", default_invalid, positive=True)
    max_depth = opt_float(options, "max_depth", None, positive=True)
    if depth_scale * 65535 > F32_MAX:
        # the largest 16-bit value would be infinite depth (float32): refused here, by name
        raise BadValueError(f"option depth_scale: {depth_scale:g} times 65535 (the largest 16-bit depth value) "
                            f"overflows float32 (largest {F32_MAX:.3g}); expected metres per depth unit")
    max_dt = opt_float(options, "max_dt", 0.02, positive=True)
    if fmt == "icl":
        if not (path / "color").is_dir():
            raise MissingFileError(f"{path / 'color'}: no such directory (pose_format=icl)")
        frames = _icl_frames(path)
    elif fmt == "7scenes":
        frames = _seven_scenes_frames(path)
    else:
        frames = _tum_frames(path, max_dt)

    s = np.diag([np.sign(fx), np.sign(fy), 1.0, 1.0])  # data set camera axes -> OpenCV
    mirror = np.linalg.det(s[:3, :3]) < 0
    m = s if mirror else np.eye(4)  # world -> imported world
    views = []
    size = None
    for name, color, depth, world_from_cam_ds in frames:
        for f in (color, depth):
            if not f.is_file():
                raise MissingFileError(f"{f}: no such file")
        if size is None:
            size = image_size(color)
        else:
            check_same_size(color, size, "colour image", f"size of {frames[0][1].name}")
        check_same_size(depth, size, "depth image", f"size of its colour image {color.name}")
        # world'_from_cam_cv = M T S (S = S^-1); rigid by construction (see the docstring).
        world_from_cam = m @ world_from_cam_ds @ s
        with named(f"{color} (options fx, fy, cx, cy and its pose)"):
            cam = Camera.pinhole(size[0], size[1], abs(fx), abs(fy), cx + 0.5, cy + 0.5,
                                 invert_rigid(world_from_cam))
        if invalid is None and max_depth is None:  # as stored
            depth_loader = FileLoader(depth, read_depth, depth, scale=depth_scale, size=size)
        else:
            depth_loader = FileLoader(depth, _load_depth, depth, depth_scale, invalid, max_depth, size=size)
        views.append(View.create(name, cam, color=FileLoader(color, read_image, color, size=size),
                                 depth=depth_loader))
    adapted = []
    if invalid is not None:
        how = "invalid_depth" if "invalid_depth" in options else f"invalid_depth, the {fmt} default"
        adapted.append(f"depth value {invalid:g} marked unknown ({how})")
    if max_depth is not None:
        adapted.append(f"depth beyond {max_depth:g} m marked unknown (max_depth)")
    notes = f"depth z = value * {depth_scale:g} m; poses camera-to-world ({fmt})"
    if mirror:
        notes += (f"; negative focal ({'fx' if fx < 0 else 'fy'}): world mirrored by "
                  f"diag{tuple(int(v) for v in np.diag(s)[:3])} to keep poses rigid")
    source = {"format": NAME, "path": str(path), "layout": fmt, "notes": notes,
              "world_mirror": np.diag(m)[:3].tolist()}
    record_summary(source, adapted=adapted)
    return Scene(views=views, units="m", source=source, root=path)
