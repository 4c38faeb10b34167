"""MPEG-I immersive video content: RVS/TMIV camera JSON, RVS synthesis configs, raw YUV / PNG / EXR.

Inputs
  * a **camera parameter file** ``{"cameras": [{"Name", "Position", "Rotation", "Depth_range",
    "Resolution", "Projection", "Focal", "Principle_point" | "Hor_range", "Ver_range",
    "BitDepthColor", "BitDepthDepth", "ColorSpace", "DepthColorSpace", "HasInvalidDepth"}]}``.
    Each camera's files are looked up beside the JSON: a file whose name starts with
    ``<Name>_`` (or is ``<Name>.<ext>``) with extension .yuv/.png/.exr...; one containing
    "depth" is its depth map, the other its colour ("texture"). Cameras with a colour image
    become views; cameras without one become ``scene.targets`` (cameras to render).
  * an **RVS synthesis config** (``InputCameraParameterFile``, ``VirtualCameraParameterFile``,
    ``InputCameraNames``, ``VirtualCameraNames``, ``ViewImageNames``, ``DepthMapNames``,
    ``OutputFiles``, ``StartFrame``, ...): the input cameras with their named images become
    views, the virtual cameras become targets (ground truth from the ``target_images`` option;
    ``OutputFiles`` are RVS's *outputs* and are not read). Relative paths are relative to the
    config's folder.

Convention converted from (OMAF / MPEG CTC, as RVS and TMIV)
  * Axes: x forward, y left, z up; ``Position`` in metres (world axes are kept as they are).
  * ``Rotation`` = (yaw, pitch, roll) in degrees; the camera-to-world rotation in OMAF axes is
    ``Rz(yaw) Ry(pitch) Rx(roll)`` (TMIV's and RVS's EulerAnglesToRotationMatrix). A camera
    point in OpenCV axes maps to OMAF axes by P = [[0,0,1],[-1,0,0],[0,-1,0]] (forward = z_cv,
    left = -x_cv, up = -y_cv), so ``cam_from_world = [P^T R^T | -P^T R^T Position]``.
  * Perspective: ``Focal`` = (fx, fy), ``Principle_point`` = (cx, cy) in pixels, with pixel
    centres at +0.5 (as ours): u = cx - fx * y / x, v = cy - fy * z / x (OMAF camera axes).
  * Equirectangular: OMAF longitude phi grows to the **left** (phi = Hor_range[1] at the left
    edge); ours grows to the right, so lon = -phi and ``lon_range = (-Hor_range[1],
    -Hor_range[0])``; ``lat_range = Ver_range`` (theta up = our latitude).
  * Depth maps store normalised inverse depth: a value v in [0, 2^bits - 1] gives
    ``1/d = v / vmax * (1/near - 1/far) + 1/far`` with ``Depth_range = (near, far)``; far >= 1000
    means infinity (1/far = 0), so v = 0 is then +inf ("at infinity", allowed by our depth
    convention). With ``"HasInvalidDepth": true`` v = 0 is unknown (0). d is z for perspective
    cameras and the ray distance for equirectangular ones, which is exactly our convention.
    EXR depth is read as metric d as it is.
  * Colour: raw YUV 4:2:0 (``ColorSpace`` "YUV420") or 4:0:0 at ``BitDepthColor`` bits (see
    formats/yuv.py: 8-bit uint8, 9..16-bit little-endian uint16; BT.709 limited range by
    default; chroma upsampled); PNG/JPEG/EXR through imageio. Depth YUV files are read for their
    Y plane (``DepthColorSpace`` "YUV420": chroma planes present and ignored; "YUV400": none).
    A YUV file whose size is not a whole number of frames is a FormatError naming the file and
    the byte counts.

Options
  frame=<StartFrame or 0>     frame index in the YUV files
  yuv_matrix=bt709|bt601      Y'CbCr matrix (default bt709)
  yuv_range=limited|full      code range (default limited)
  target_images=a.yuv,b.png   ground-truth images of the virtual cameras, in order (config only)
  depth=auto|none             read depth maps (default auto)
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ibrtools.camera import MAX_TRANSLATION, Camera
from ibrtools.errors import BadValueError, DtypeError, FormatError, MissingFileError, ShapeError
from ibrtools.imageio import read_pixels, read_image
from ibrtools.scene import Scene, View
from ibrtools.formats import yuv
from ibrtools.formats._common import document_errors, FileLoader, check_options, check_same_size, opt_choice, opt_int, read_json

NAME = "mpeg"
DESCRIPTION = "MPEG-I/RVS camera JSON or RVS synthesis config (OMAF axes) + YUV/PNG/EXR"
OPTIONS = {"frame": "frame index in YUV files", "yuv_matrix": "bt709|bt601", "yuv_range": "limited|full",
           "target_images": "comma-separated ground-truth images of the virtual cameras", "depth": "auto|none"}
INFINITE_FAR = 1000.0
MIN_NEAR = 1e-9  # the nearest depth a Depth_range may give (1 / near must stay far from overflow)
IMAGE_EXTS = (".yuv", ".png", ".exr", ".jpg", ".jpeg", ".tif", ".tiff", ".pfm")
# OpenCV camera axes -> OMAF camera axes: p_omaf = P @ p_cv.
CV_TO_OMAF = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _peek_json(path: Path):
    if path.suffix.lower() != ".json" or not path.is_file() or path.stat().st_size > 16 << 20:
        return None
    try:
        return read_json(path)
    except (FormatError, MissingFileError):
        return None


def _kind(doc) -> str | None:
    if isinstance(doc, dict):
        if "InputCameraNames" in doc and "InputCameraParameterFile" in doc:
            return "config"
        cams = doc.get("cameras")
        if isinstance(cams, list) and cams and isinstance(cams[0], dict) and "Projection" in cams[0]:
            return "cameras"
    return None


def _dir_candidates(path: Path) -> list[tuple[str, Path]]:
    out = []
    for f in sorted(path.glob("*.json")):
        k = _kind(_peek_json(f))
        if k:
            out.append((k, f))
    return out


def is_config(path: Path) -> bool:
    """True when ``path`` is an RVS synthesis config file."""
    path = Path(path)
    return path.is_file() and _kind(_peek_json(path)) == "config"


def detect(path: Path) -> bool:
    path = Path(path)
    if path.is_file():
        return _kind(_peek_json(path)) is not None
    if path.is_dir():
        cands = _dir_candidates(path)
        configs = [c for c in cands if c[0] == "config"]
        return len(configs) == 1 or (not configs and len(cands) == 1)
    return False


# --- cameras ------------------------------------------------------------------------------------
def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def cam_from_world(position, rotation_deg) -> np.ndarray:
    """OpenCV ``cam_from_world`` of an OMAF camera at ``position`` with (yaw, pitch, roll)."""
    yaw, pitch, roll = (math.radians(float(v)) for v in rotation_deg)
    world_from_omaf = _rz(yaw) @ _ry(pitch) @ _rx(roll)
    r = CV_TO_OMAF.T @ world_from_omaf.T
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = -r @ np.asarray(position, dtype=np.float64)
    return m


def _vec(c: dict, key: str, n: int, where: str, default=None) -> list[float]:
    if key not in c:
        if default is not None:
            return list(default)
        raise FormatError(f"{where}: missing key {key!r}")
    v = c[key]
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise FormatError(f"{where}: {key!r} must be a list of {n} numbers, got {v!r}")
    try:
        out = [float(x) for x in v]
    except (TypeError, ValueError):
        raise FormatError(f"{where}: {key!r} must be a list of {n} numbers, got {v!r}") from None
    if not all(math.isfinite(x) for x in out):
        raise BadValueError(f"{where}: {key!r} has NaN or infinite values: {v!r}")
    return out


class MpegCamera:
    """One camera record of a camera parameter file, parsed and checked."""

    def __init__(self, c: dict, where: str):
        if not isinstance(c, dict):
            raise FormatError(f"{where}: expected a JSON object, got {type(c).__name__}")
        if "Name" not in c:
            raise FormatError(f"{where}: missing key 'Name'")
        self.name = str(c["Name"])
        where = f"{where} ({self.name})"
        self.where = where
        pos = _vec(c, "Position", 3, where)
        rot = _vec(c, "Rotation", 3, where)
        w, h = (int(round(v)) for v in _vec(c, "Resolution", 2, where))
        proj = str(c.get("Projection", "Perspective"))
        if max(abs(v) for v in pos) > MAX_TRANSLATION:  # before the arithmetic of the pose
            raise BadValueError(f"{where}: 'Position' {pos} is beyond +-{MAX_TRANSLATION:g}")
        pose = cam_from_world(pos, rot)
        try:
            if proj == "Perspective":
                fx, fy = _vec(c, "Focal", 2, where)
                cx, cy = _vec(c, "Principle_point", 2, where)
                if not (fx > 0 and fy > 0):
                    raise BadValueError(f"focal length must be positive, got Focal = {c['Focal']}")
                self.camera = Camera.pinhole(w, h, fx, fy, cx, cy, pose)
            elif proj == "Equirectangular":
                hr = _vec(c, "Hor_range", 2, where)
                vr = _vec(c, "Ver_range", 2, where)
                self.camera = Camera.equirect(w, h, (-hr[1], -hr[0]), tuple(vr), pose)
            else:
                raise FormatError(f"{where}: Projection {proj!r} not supported (Perspective, Equirectangular)")
        except (BadValueError, DtypeError, ShapeError) as e:
            raise type(e)(f"{where}: {e}") from None
        self.projection = proj
        near, far = _vec(c, "Depth_range", 2, where, default=(0.0, 0.0)) if c.get("Depthmap", 1) else (0.0, 0.0)
        self.depth_range = (near, far)
        self.bits_color = int(c.get("BitDepthColor", 8))
        self.bits_depth = int(c.get("BitDepthDepth", 16))
        for k, b in (("BitDepthColor", self.bits_color), ("BitDepthDepth", self.bits_depth)):
            if not 1 <= b <= 16:
                raise BadValueError(f"{where}: {k} must be in 1..16, got {b}")
        self.chroma = {"YUV420": "420", "YUV400": "400"}.get(str(c.get("ColorSpace", "YUV420")).upper())
        self.depth_chroma = {"YUV420": "420", "YUV400": "400"}.get(str(c.get("DepthColorSpace", "YUV420")).upper())
        if self.chroma is None or self.depth_chroma is None:
            raise FormatError(f"{where}: ColorSpace/DepthColorSpace must be YUV420 or YUV400")
        self.invalid_zero = bool(c.get("HasInvalidDepth", False))

    def check_depth_range(self) -> None:
        near, far = self.depth_range
        if not (near > 0 and far > near):
            raise BadValueError(f"{self.where}: Depth_range must be 0 < near < far, got {list(self.depth_range)}")
        if near < MIN_NEAR:  # 1 / near is the decoding's scale: a denormal near makes it infinite
            raise BadValueError(f"{self.where}: Depth_range near {near:g} is below {MIN_NEAR:g}")


@document_errors
def read_camera_file(path: Path) -> dict[str, MpegCamera]:
    doc = read_json(path)
    if not isinstance(doc, dict) or not isinstance(doc.get("cameras"), list):
        raise FormatError(f"{path}: expected a JSON object with a 'cameras' list")
    cams = {}
    for i, c in enumerate(doc["cameras"]):
        mc = MpegCamera(c, f"{path} cameras[{i}]")
        if mc.name in cams:
            raise FormatError(f"{path}: camera name {mc.name!r} appears twice")
        cams[mc.name] = mc
    if not cams:
        raise FormatError(f"{path}: 'cameras' is empty")
    return cams


# --- pixels -------------------------------------------------------------------------------------
def decode_depth(v: np.ndarray, bits: int, near: float, far: float, invalid_zero: bool = False,
                 where: str = "depth") -> np.ndarray:
    """Metric depth (float32) of normalised inverse-depth values (see the module docstring)."""
    vmax = float((1 << bits) - 1)
    v = v.astype(np.float64)
    if v.size and v.max() > vmax:
        raise BadValueError(f"{where}: value {int(v.max())} exceeds the {bits}-bit range (max {int(vmax)})")
    inv_far = 0.0 if far >= INFINITE_FAR else 1.0 / far
    inv = v / vmax * (1.0 / near - inv_far) + inv_far
    with np.errstate(divide="ignore"):
        d = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), np.inf)
    if invalid_zero:
        d = np.where(v == 0, 0.0, d)
    return np.ascontiguousarray(d.astype(np.float32))


def _load_color(path: Path, mc: MpegCamera, frame: int, matrix: str, full: bool) -> np.ndarray:
    if path.suffix.lower() == ".yuv":
        planes = yuv.read_frame(path, mc.camera.width, mc.camera.height, mc.bits_color, frame, mc.chroma)
        return yuv.yuv_to_rgb(planes, mc.bits_color, matrix, full)
    return read_image(path, size=(mc.camera.width, mc.camera.height))


def _load_depth(path: Path, mc: MpegCamera, frame: int) -> np.ndarray:
    near, far = mc.depth_range
    w, h = mc.camera.width, mc.camera.height
    if path.suffix.lower() == ".yuv":
        y = yuv.read_frame(path, w, h, mc.bits_depth, frame, mc.depth_chroma)[0]
        return decode_depth(y, mc.bits_depth, near, far, mc.invalid_zero, str(path))
    arr, fmt = read_pixels(path, (w, h))
    if arr.shape[:2] != (h, w):
        raise ShapeError(f"{path}: depth is {arr.shape[1]}x{arr.shape[0]}, expected {w}x{h} ({mc.name})")
    if fmt in ("uint8", "uint16"):
        return decode_depth(arr[..., 0], mc.bits_depth, near, far, mc.invalid_zero, str(path))
    d = arr[..., 0].astype(np.float32)
    return np.ascontiguousarray(np.where(np.isnan(d), 0, d).astype(np.float32))


def _check_file(path: Path, mc: MpegCamera, what: str, frame: int) -> int | None:
    """Check size cheaply at import time (YUV byte count, image header) and that ``frame`` is in
    the file; the number of frames of a YUV file (None for an image: the same at every frame)."""
    if not path.is_file():
        raise MissingFileError(f"{path}: {what} of camera {mc.name!r} not found")
    w, h = mc.camera.width, mc.camera.height
    if path.suffix.lower() != ".yuv":
        check_same_size(path, (w, h), what, f"Resolution of camera {mc.name!r}")
        return None
    if what == "colour":
        n = yuv.frame_count(path, w, h, mc.bits_color, mc.chroma)
    else:
        n = yuv.frame_count(path, w, h, mc.bits_depth, mc.depth_chroma)
    if frame >= n:
        raise BadValueError(f"{path}: frame {frame} asked for, the file has {n} frame(s) (0..{n - 1})")
    return n


def _view(mc: MpegCamera, color: Path | None, depth: Path | None, frame: int, matrix: str, full: bool,
          use_depth: bool, counts: list[int]) -> View:
    """The view of camera ``mc`` at ``frame``; the frame counts of its YUV files go to ``counts``."""
    col = dep = None
    if color is not None:
        counts.append(_check_file(color, mc, "colour", frame))
        col = FileLoader(color, _load_color, color, mc, frame, matrix, full)
    if depth is not None and use_depth:
        counts.append(_check_file(depth, mc, "depth map", frame))
        mc.check_depth_range()
        dep = FileLoader(depth, _load_depth, depth, mc, frame)
    return View.create(mc.name, mc.camera, color=col, depth=dep)


def _find_files(folder: Path, name: str) -> tuple[Path | None, Path | None]:
    cands = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS
             and (p.stem == name or p.name.startswith(name + "_"))]
    depth = [p for p in cands if "depth" in p.name.lower()]
    color = [p for p in cands if p not in depth]
    for lst, what in ((color, "colour"), (depth, "depth")):
        if len(lst) > 1:
            raise FormatError(f"{folder}: several {what} files for camera {name!r}: "
                              f"{', '.join(sorted(p.name for p in lst))}; use an RVS config to name them")
    return (color[0] if color else None), (depth[0] if depth else None)


@document_errors
def load(path: Path, options: dict) -> Scene:
    return _load(path, options)[0]


@document_errors
def frame_range(path: Path, options: dict) -> tuple[int, range]:
    """The video frames of the data set: (how many frames every YUV file of its views holds,
    the frames an RVS config renders: ``StartFrame`` and ``NumberOfFrames``, else the ``frame``
    option's or 0 alone). Images (PNG, EXR) are the same at every frame."""
    scene, counts, default = _load(path, options)
    known = [n for n in counts if n is not None]
    return (min(known) if known else 1), default


def _load(path: Path, options: dict) -> tuple[Scene, list[int | None], range]:
    """load(), with the frame counts of the files read and the config's frames (frame_range)."""
    path = Path(path)
    options = check_options(options, OPTIONS, NAME)
    counts: list[int | None] = []
    matrix = opt_choice(options, "yuv_matrix", "bt709", tuple(yuv.MATRICES))
    full = opt_choice(options, "yuv_range", "limited", ("limited", "full")) == "full"
    use_depth = opt_choice(options, "depth", "auto", ("auto", "none")) == "auto"
    if path.is_dir():
        cands = _dir_candidates(path)
        configs = [f for k, f in cands if k == "config"]
        if len(configs) == 1:
            path = configs[0]
        elif len(cands) == 1:
            path = cands[0][1]
        else:
            raise FormatError(f"{path}: expected one RVS config or camera JSON, found "
                              f"{[f.name for _, f in cands] or 'none'}")
    doc = read_json(path)
    kind = _kind(doc)
    notes = [f"YUV {matrix} {'full' if full else 'limited'} range, sRGB-decoded"]
    if kind == "config":
        base = path.parent
        frame = opt_int(options, "frame", _config_int(doc, "StartFrame", 0, path), minimum=0)
        default = range(frame, frame + _config_int(doc, "NumberOfFrames", 1, path))

        def listing(key: str, required: bool = True) -> list[str]:
            v = doc.get(key, [] if not required else None)
            if v is None:
                raise FormatError(f"{path}: missing key {key!r}")
            if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
                raise FormatError(f"{path}: {key!r} must be a list of strings")
            return v

        for key in ("InputCameraParameterFile",):
            if not isinstance(doc.get(key), str):
                raise FormatError(f"{path}: missing key {key!r}")
        in_cams = read_camera_file(base / doc["InputCameraParameterFile"])
        names, images = listing("InputCameraNames"), listing("ViewImageNames")
        depths = listing("DepthMapNames", required=False)
        if len(images) != len(names) or (depths and len(depths) != len(names)):
            raise FormatError(f"{path}: InputCameraNames ({len(names)}), ViewImageNames ({len(images)}) and "
                              f"DepthMapNames ({len(depths)}) must have the same length")
        views = []
        for i, n in enumerate(names):
            if n not in in_cams:
                raise FormatError(f"{path}: input camera {n!r} is not in {doc['InputCameraParameterFile']}")
            views.append(_view(in_cams[n], base / images[i], base / depths[i] if depths else None, frame,
                               matrix, full, use_depth, counts))
        targets = []
        vnames = listing("VirtualCameraNames", required=False)
        if vnames:
            vfile = doc.get("VirtualCameraParameterFile", doc["InputCameraParameterFile"])
            v_cams = read_camera_file(base / vfile)
            gt = [s.strip() for s in str(options.get("target_images", "")).split(",") if s.strip()]
            if gt and len(gt) != len(vnames):
                raise BadValueError(f"option target_images: {len(gt)} files for {len(vnames)} virtual cameras")
            for i, n in enumerate(vnames):
                if n not in v_cams:
                    raise FormatError(f"{path}: virtual camera {n!r} is not in {vfile}")
                gt_file = None
                if gt:
                    gt_file = Path(gt[i]) if Path(gt[i]).is_absolute() else base / gt[i]
                targets.append(_view(v_cams[n], gt_file, None, frame, matrix, full, False, counts))
        elif "target_images" in options:
            raise BadValueError("option target_images: the config has no VirtualCameraNames")
        notes.append(f"RVS config, frame {frame}")
    elif kind == "cameras":
        if "target_images" in options:
            raise BadValueError("option target_images: only for RVS configs")
        frame = opt_int(options, "frame", 0, minimum=0)
        default = range(frame, frame + 1)
        cams = read_camera_file(path)
        views, targets = [], []
        for n, mc in cams.items():
            color, depth = _find_files(path.parent, n)
            if color is None:
                targets.append(View.create(n, mc.camera))
            else:
                views.append(_view(mc, color, depth, frame, matrix, full, use_depth, counts))
        notes.append(f"camera file, frame {frame}; cameras without images are targets")
    else:
        raise FormatError(f"{path}: neither an MPEG camera file ('cameras' list with 'Projection') nor "
                          "an RVS config ('InputCameraNames', 'InputCameraParameterFile')")
    return Scene(views=views, targets=targets, units="m",
                 source={"format": NAME, "path": str(path), "notes": "; ".join(notes)},
                 root=path.parent), counts, default


def _config_int(doc: dict, key: str, default: int, path: Path) -> int:
    """An RVS config's frame key (``StartFrame`` >= 0, ``NumberOfFrames`` >= 1)."""
    v = doc.get(key, default)
    low = 1 if key == "NumberOfFrames" else 0
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v != int(v) or v < low:
        raise FormatError(f"{path}: {key!r} must be an integer >= {low}, got {v!r}")
    return int(v)


# RVS config keys that ask for what rendering an RVS config does not do (yet): refused by name.
UNSUPPORTED_CONFIG_KEYS = {"VirtualPoseTraceName": "a pose trace for the virtual cameras",
                           "NumberOfOutputFrames": "more output frames than input frames"}


@document_errors
def config_outputs(path: Path) -> dict:
    """What an RVS synthesis config asks RVS to write, for rendering it as RVS would:
    ``{"files": {virtual camera: (OutputFiles entry, its camera's BitDepthColor)}, "frames":
    range (StartFrame, NumberOfFrames), "blending_factor": BlendingFactor or None,
    "ignored": [output keys not written: MaskedOutputFiles, DepthOutputFiles, ...]}``.
    A config without VirtualCameraNames / OutputFiles, or with a key of UNSUPPORTED_CONFIG_KEYS,
    is a FormatError naming the file and the key."""
    path = Path(path)
    doc = read_json(path)
    if _kind(doc) != "config":
        raise FormatError(f"{path}: not an RVS synthesis config ('InputCameraNames', 'InputCameraParameterFile')")
    for key, what in UNSUPPORTED_CONFIG_KEYS.items():
        if key in doc and not (key == "NumberOfOutputFrames" and doc[key] == doc.get("NumberOfFrames", 1)):
            raise FormatError(f"{path}: {key!r} ({what}) is not built yet")
    names, outputs = doc.get("VirtualCameraNames"), doc.get("OutputFiles")
    for key, v in (("VirtualCameraNames", names), ("OutputFiles", outputs)):
        if not isinstance(v, list) or not v or not all(isinstance(x, str) and x for x in v):
            raise FormatError(f"{path}: {key!r}: expected a non-empty list of names (what RVS renders and writes)")
    if len(outputs) != len(names):
        raise FormatError(f"{path}: OutputFiles ({len(outputs)}) and VirtualCameraNames ({len(names)}) "
                          "must have the same length")
    vfile = doc.get("VirtualCameraParameterFile", doc["InputCameraParameterFile"])
    if not isinstance(vfile, str):
        raise FormatError(f"{path}: 'VirtualCameraParameterFile': expected a file name")
    cams = read_camera_file(path.parent / vfile)
    missing = [n for n in names if n not in cams]
    if missing:
        raise FormatError(f"{path}: virtual camera {missing[0]!r} is not in {vfile}")
    factor = doc.get("BlendingFactor")
    if factor is not None and (isinstance(factor, bool) or not isinstance(factor, (int, float))
                               or not math.isfinite(factor) or factor <= 0):
        raise FormatError(f"{path}: 'BlendingFactor': expected a positive number, got {factor!r}")
    start = _config_int(doc, "StartFrame", 0, path)
    ignored = [k for k in ("MaskedOutputFiles", "OutputMasks", "DepthOutputFiles", "MaskedDepthOutputFiles")
               if doc.get(k)]
    return {"files": {n: (o, cams[n].bits_color) for n, o in zip(names, outputs)},
            "frames": range(start, start + _config_int(doc, "NumberOfFrames", 1, path)),
            "blending_factor": None if factor is None else float(factor), "ignored": ignored}
