"""NeRF / instant-ngp ``transforms*.json`` (Blender synthetic scenes, colmap2nerf output).

Convention converted from
  * ``transform_matrix`` (4x4) is **camera-to-world** with Blender/OpenGL camera axes: x right,
    y up, the camera looks along -z. We convert to OpenCV axes (x right, y down, z forward)
    by flipping the camera's y and z: ``world_from_cam_cv = transform_matrix @ diag(1, -1, -1, 1)``,
    then invert to ``cam_from_world``. The world frame is kept as it is (units "unknown").
  * Intrinsics: ``fl_x``/``fl_y`` when present (instant-ngp), else
    ``fx = w / 2 / tan(camera_angle_x / 2)`` and ``fy`` from ``camera_angle_y`` or ``= fx``;
    ``cx``/``cy`` when present, else ``w/2``, ``h/2`` (the image centre in our pixel-centre-at-
    +0.5 convention, which is where Blender puts it). ``w``/``h`` when present, else read
    from the image header. Any of these keys may also appear per frame (overrides).
  * Lens distortion (instant-ngp, nerfstudio): ``camera_model`` OPENCV (``k1 k2 k3 p1 p2``,
    OpenCV's radial-tangential model) or OPENCV_FISHEYE (``k1 k2 k3 k4``, equidistant), or
    instant-ngp's ``k1 k2 p1 p2`` without ``camera_model`` (``is_fisheye: true``: fisheye), at top
    level or per frame. Images are undistorted on load to a pinhole with the same fx, fy, cx, cy
    (``_undistort.py``, the COLMAP importer's code: bilinear colour, nearest depth, pixels whose
    source is outside the image out of the mask). PINHOLE with non-zero coefficients, k4 without
    OPENCV_FISHEYE, p1/p2 with OPENCV_FISHEYE and other models are refused (FormatError).
  * Images: ``file_path`` relative to the JSON's folder, with or without extension (".png"
    is tried first). Frames whose image is not there are skipped, counted in one warning
    (``source["warnings"]``; instant-ngp's ``fox`` lists 67 frames and ships 50); an error only
    when no frame has its image. RGBA images are composited over the ``background`` colour **on the
    stored sRGB values** (``rgb * a + bg * (1 - a)``, then decoded to linear) — exactly what the
    NeRF papers' evaluation images are — and ``alpha > 0.5`` becomes the view's mask.
  * Depth (Blender synthetic sets, e.g. lego ``r_N_depth_0001.png``): an 8- or 16-bit image,
    channel 0 = v, read with *straight* alpha (the PNGs carry an alpha channel; OpenImageIO
    would otherwise premultiply v by it); v = 0 is the transparent background: depth +inf, the background at infinity
    (docs/FORMAT.md "Background"), in the compositing colour; v = vmax is unknown (0); otherwise the
    **distance along the ray** is ``depth_scale * (1 - v / vmax)``, converted to z-depth for the
    pinhole camera (``Camera.depth_ray_to_z``). Looked up as ``<stem>_depth_0001.png``,
    ``<stem>_depth.png``. A free two-parameter fit ``a - b v/255`` of the lego depth maps to each
    other gives a = 7.97, b = 7.94, i.e. this encoding with scale 8.
  * Metric depth (nerfstudio): a frame's ``depth_file_path`` (relative to the JSON's folder) is a
    z-depth image: 16-bit values times ``depth_unit`` (default 0.001, nerfstudio's millimetres;
    give the factor that brings them to the poses' units), float images (EXR) as stored; 0 =
    unknown. It replaces the Blender depth lookup for that frame; missing file: MissingFileError.
  * Depth de-quantisation (option ``depth_dequantize=auto|N``, default auto): a smooth surface
    stored in integer codes is a staircase of flat terraces one code apart. N rounds of
    bin-constrained smoothing (``dequantize_codes``) turn the terraces into ramps while every
    value stays inside its quantisation bin (it still rounds to the stored code) and nothing is
    smoothed across a step of two codes or more (depth edges). The principle of ``auto``: undo
    the quantisation where it is coarse enough to misregister a warp, leave it where it is not.
    A warp between views a baseline b apart moves a pixel by f·b·Δ/z² for a depth error Δ.
    8-bit codes (lego: steps of depth_scale/255 = 0.031 units, ~0.8 % of the depth — the data
    README's "coarse" warning) misregister by up to ~1 px at the lego views' baselines
    (1111 px · 0.9 · 0.016 / 4² ≈ 1 px for half a step), on one-pixel textures: ``auto`` = 5
    rounds (chosen on validation views, docs/dibr_accuracy.md "Accuracy"). 16-bit codes are 257× finer
    (steps of 0.00012 units, 0.003 % of the depth, < 0.01 px at any such baseline): their
    terraces are invisible to a warp and smoothing could only round off depth edges (the same
    smoothing of Middlebury's fine quarter-pixel codes loses 0.1 dB), so ``auto`` = 0 there.
    An explicit N overrides ``auto`` for every depth file (0 = the stored codes as they are).
    Where the codes are de-quantised the view also keeps the depth as stored
    (``View.depth_stored``): the global mesh's TSDF fusion reads that (``View.fusion_depth``),
    every warp and blend the de-quantised depth.

A path may be a ``transforms*.json`` file or a folder holding ``transforms_{train,val,test}.json``
and/or ``transforms.json``. Every split found becomes views named by the image stem
("r_0"); when stems collide across splits the views are named "split/stem" ("test/r_0").

Options
  split=all|train|val|test   which split files to import (default all that exist)
  background=black|white     compositing colour for RGBA images (default black)
  depth_scale=8              ray distance encoded by v = 0 (default 8)
  depth=auto|none            read depth PNGs when present (default auto)
  depth_unit=0.001           scene units per stored unit of ``depth_file_path`` 16-bit images
  depth_dequantize=auto|N    rounds of bin-constrained smoothing of the depth codes (default auto:
                             5 for 8-bit depth PNGs, 0 for 16-bit)
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

import numpy as np

from ibrtools.camera import MAX_SIDE, Camera
from ibrtools.errors import BadValueError, DtypeError, FormatError, MissingFileError, ShapeError
from ibrtools.imageio import F32_MAX, read_depth, read_pixels, srgb_to_linear
from ibrtools.scene import Scene, View
from ibrtools.formats._common import (document_errors, FileLoader, check_options, check_same_size, image_header, image_size, invert_rigid,
                      named, opt_choice, opt_float, opt_int, read_json, record_summary, rigid_from_matrix)
from ibrtools.formats._undistort import Undistorter, is_distorted

NAME = "nerf"
DESCRIPTION = "NeRF/instant-ngp transforms*.json (Blender/OpenGL camera-to-world)"

SPLITS = ("train", "val", "test")
OPTIONS = {
    "split": "all|train|val|test",
    "background": "black|white: compositing colour of RGBA images",
    "depth_scale": "ray distance encoded by v = 0 (default 8)",
    "depth": "auto|none",
    "depth_unit": "scene units per stored unit of depth_file_path 16-bit images (default 0.001: millimetres, "
                  "nerfstudio's convention)",
    "depth_dequantize": "auto|N: rounds of bin-constrained smoothing of the depth codes "
                        "(default auto = 5 for 8-bit depth PNGs, 0 for 16-bit; 0 = off)",
}
IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", "")
# depth_dequantize=auto: rounds by the depth PNG's sample format (module doc: coarse 8-bit codes are
# de-quantised, fine 16-bit codes are not). 5 = the best of 0/2/5/10 on the lego validation views
# (benchmarks/bench_dibr_accuracy.py, LEGO_VALIDATION; never the test views).
AUTO_DEQUANTIZE = {"uint8": 5, "uint16": 0}
# nerfstudio's camera_model values read (others, e.g. EQUIRECTANGULAR, are refused).
CAMERA_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "OPENCV_FISHEYE")
# Blender/OpenGL camera axes (x right, y up, looking along -z) -> OpenCV (x right, y down, z fwd).
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def _json_files(path: Path) -> list[tuple[str, Path]]:
    """(split, file) pairs found at ``path``."""
    if path.is_file():
        stem = path.stem
        split = stem[len("transforms_"):] if stem.startswith("transforms_") else ""
        return [(split, path)]
    found = [(s, path / f"transforms_{s}.json") for s in SPLITS if (path / f"transforms_{s}.json").is_file()]
    if (path / "transforms.json").is_file():
        found.append(("", path / "transforms.json"))
    return found


def detect(path: Path) -> bool:
    path = Path(path)
    if path.is_file():
        return path.suffix.lower() == ".json" and path.name.startswith("transforms")
    return path.is_dir() and bool(_json_files(path))


def resolve_image(base: Path, file_path: str) -> Path | None:
    """The image of ``file_path`` (with or without extension), or None when it is not there."""
    rel = Path(file_path)
    for ext in IMAGE_EXTS:
        cand = base / (str(rel) + ext) if ext else base / rel
        try:
            if cand.is_file():
                return cand
        except OSError:  # a name the file system cannot hold (too long): not there
            continue
    return None


def _depth_file(image: Path) -> Path | None:
    for name in (f"{image.stem}_depth_0001.png", f"{image.stem}_depth.png"):
        if (image.parent / name).is_file():
            return image.parent / name
    return None


def _focal(m: dict, axis: str, size: int, where: str) -> float | None:
    """Focal length along ``axis`` ("x" or "y") in pixels from fl_<axis> or camera_angle_<axis>
    (full field of view, radians); None when neither key is present."""
    if f"fl_{axis}" in m:
        return _number(m, f"fl_{axis}", where)
    key = f"camera_angle_{axis}"
    if key not in m:
        return None
    angle = _number(m, key, where)
    if not 0 < angle < math.pi:
        raise BadValueError(f"{where}: {key} = {angle} rad is not in (0, pi)")
    return 0.5 * size / math.tan(0.5 * angle)


def _number(d: dict, key: str, where: str) -> float:
    try:
        v = float(d[key])
    except (TypeError, ValueError, OverflowError):
        raise FormatError(f"{where}: '{key}' is not a number ({d[key]!r})") from None
    if not math.isfinite(v):
        raise BadValueError(f"{where}: '{key}' is not finite ({d[key]!r})")
    return v


def _load_color(path: Path, background: float, size: tuple[int, int] | None = None) -> np.ndarray:
    arr, fmt = read_pixels(path, size)
    c = arr.shape[2]
    if fmt in ("uint8", "uint16"):
        v = arr.astype(np.float32) / (255.0 if fmt == "uint8" else 65535.0)
        rgb = v[..., :3] if c >= 3 else np.repeat(v[..., :1], 3, axis=2)
        if c in (2, 4):
            a = v[..., -1:]
            rgb = rgb * a + np.float32(background) * (1 - a)  # on stored sRGB values (NeRF practice)
        return np.ascontiguousarray(srgb_to_linear(rgb))
    v = arr.astype(np.float32)
    rgb = v[..., :3] if c >= 3 else np.repeat(v[..., :1], 3, axis=2)
    if c in (2, 4):  # float images are linear: composite in linear light
        a = np.clip(v[..., -1:], 0, 1)
        rgb = rgb * a + np.float32(background) * (1 - a)
    if not np.all(np.isfinite(rgb)):
        raise BadValueError(f"{path}: colour contains NaN or infinity")
    return np.ascontiguousarray(rgb)


def _load_mask(path: Path, size: tuple[int, int] | None = None) -> np.ndarray:
    arr, fmt = read_pixels(path, size)
    full = {"uint8": 255.0, "uint16": 65535.0}.get(fmt, 1.0)
    if arr.shape[2] not in (2, 4):
        raise FormatError(f"{path}: no alpha channel for the mask")
    return np.ascontiguousarray(arr[..., -1] > full / 2)


def decode_depth(v: np.ndarray, vmax: float, depth_scale: float) -> np.ndarray:
    """Ray distance of the Blender depth encoding ``scale * (1 - v / vmax)``; v = 0 (no surface:
    the transparent background) -> +inf, the background at infinity; v = vmax (distance 0) is
    unknown (0)."""
    v = v.astype(np.float64)
    ray = depth_scale * (1.0 - v / vmax)
    return np.where(v <= 0, np.inf, np.where(ray > 0, ray, 0.0))


# The 8 neighbours of a pixel, as (dy, dx).
_NEIGHBOURS = tuple((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0))


def dequantize_codes(v: np.ndarray, vmax: float, iterations: int) -> np.ndarray:
    """Real-valued depth codes (float32) from integer codes ``v`` (H, W): ``iterations`` rounds
    of bin-constrained smoothing. Each round replaces every valid code by the mean of itself and
    those of its 8 neighbours that lie on the same surface (valid, stored code at most one step
    from its own), then clamps it back into its rounding bin [v - 1/2, v + 1/2], so the result
    never leaves the bin of the stored code. Terraces one code apart become ramps; steps of two codes
    or more (depth edges) are never smoothed across. Codes 0 and ``vmax`` (unknown depth) are
    returned as they are and never used. Vectorised over the image (no per-pixel Python)."""
    if v.ndim != 2:
        raise ShapeError(f"depth codes: expected an (H, W) array, got shape {v.shape}")
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 0:
        raise BadValueError(f"depth_dequantize: expected a whole number of rounds >= 0, got {iterations!r}")
    code = v.astype(np.float32)
    if iterations == 0 or code.size == 0:
        return code
    h, w = code.shape
    valid = (code > 0) & (code < vmax)
    pv, pm = np.pad(code, 1), np.pad(valid, 1)
    weights = []
    for dy, dx in _NEIGHBOURS:
        nb = pv[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
        same = pm[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] & valid & (np.abs(nb - code) <= 1.0)
        weights.append(same.astype(np.float32))
    total = np.float32(1.0) + np.sum(weights, axis=0, dtype=np.float32)
    lo, hi = code - np.float32(0.5), code + np.float32(0.5)
    x = code.copy()
    padded = np.zeros((h + 2, w + 2), np.float32)
    acc, term = np.empty_like(x), np.empty_like(x)
    for _ in range(int(iterations)):
        padded[1:-1, 1:-1] = x
        acc[...] = x
        for (dy, dx), wgt in zip(_NEIGHBOURS, weights):
            np.multiply(wgt, padded[1 + dy:1 + dy + h, 1 + dx:1 + dx + w], out=term)
            acc += term
        np.divide(acc, total, out=x)
        np.clip(x, lo, hi, out=x)
    return np.where(valid, x, code).astype(np.float32)


def dequantize_rounds(option: int | None, fmt: str) -> int:
    """Rounds of ``dequantize_codes`` for a depth PNG of sample format ``fmt`` ("uint8" or
    "uint16"): ``option`` when given (an explicit ``depth_dequantize=N``), else (``auto``,
    None) by the coarseness of the codes, ``AUTO_DEQUANTIZE``."""
    if option is not None:
        return option
    if fmt not in AUTO_DEQUANTIZE:
        raise DtypeError(f"depth_dequantize=auto: no rule for {fmt} depth codes (8- or 16-bit only)")
    return AUTO_DEQUANTIZE[fmt]


def _dequantize_option(options: dict) -> int | None:
    """The ``depth_dequantize`` option: None for ``auto`` (the default: rounds by the bit depth
    of each depth PNG), else the explicit number of rounds (an integer >= 0)."""
    raw = options.get("depth_dequantize", "auto")
    if isinstance(raw, str) and raw.strip().lower() == "auto":
        return None
    if isinstance(raw, bool) or raw is None:
        raise DtypeError(f"option depth_dequantize: expected auto or an integer >= 0, got {raw!r}")
    try:
        return opt_int(options, "depth_dequantize", None, minimum=0)
    except DtypeError:
        raise DtypeError(f"option depth_dequantize: expected auto or an integer >= 0, got {raw!r}") from None


def _load_depth(path: Path, camera: Camera, depth_scale: float, dequantize: int | None = None) -> np.ndarray:
    # the depth PNGs have an alpha channel: never premultiply v; refused from the header if not
    # of the camera's size
    arr, fmt = read_pixels(path, (camera.width, camera.height))
    if fmt not in ("uint8", "uint16"):
        raise DtypeError(f"{path}: expected an 8- or 16-bit depth PNG (Blender encoding), got {fmt}")
    if arr.shape[:2] != (camera.height, camera.width):
        raise ShapeError(f"{path}: depth is {arr.shape[1]}x{arr.shape[0]}, expected "
                         f"{camera.width}x{camera.height} (its colour image)")
    vmax = 255.0 if fmt == "uint8" else 65535.0
    ray = decode_depth(dequantize_codes(arr[..., 0], vmax, dequantize_rounds(dequantize, fmt)), vmax, depth_scale)
    return np.ascontiguousarray(camera.depth_ray_to_z(ray).astype(np.float32))


def _has_alpha(path: Path) -> bool:
    return image_header(path)[2] in (2, 4)


def _filters_depth(path: Path, dequantize: int | None) -> bool:
    """Whether loading the depth PNG ``path`` de-quantises its codes (then the view also keeps
    the depth as stored, ``View.depth_stored``, for multi-view fusion)."""
    if dequantize is not None:
        return dequantize > 0
    fmt = image_header(path)[3]
    return fmt in AUTO_DEQUANTIZE and AUTO_DEQUANTIZE[fmt] > 0


def _distortion(m: dict, fx: float, fy: float, cx: float, cy: float, where: str
                ) -> tuple[str, np.ndarray] | None:
    """The lens distortion of a frame as (COLMAP model name, COLMAP parameters), or None when
    there is none: nerfstudio's ``camera_model`` OPENCV (``k1 k2 k3 p1 p2``: OpenCV's radial and
    tangential model; COLMAP's OPENCV, FULL_OPENCV when k3 is given) or OPENCV_FISHEYE (``k1 k2 k3
    k4``), instant-ngp's ``k1 k2 p1 p2`` without ``camera_model`` (OPENCV; ``is_fisheye``: fisheye)."""
    model = m.get("camera_model")
    if model is not None:
        model = str(model).upper()
    k = {key: (_number(m, key, where) if key in m else 0.0) for key in ("k1", "k2", "k3", "k4", "p1", "p2")}
    if model is None:
        model = "OPENCV_FISHEYE" if m.get("is_fisheye") is True else "OPENCV"
    if model not in CAMERA_MODELS:
        raise FormatError(f"{where}: camera_model {m.get('camera_model')!r} is not supported "
                          f"(expected one of {', '.join(CAMERA_MODELS)})")
    if model == "OPENCV_FISHEYE":
        if k["p1"] or k["p2"]:
            raise FormatError(f"{where}: camera_model OPENCV_FISHEYE has no tangential terms, got "
                              f"p1={k['p1']:g}, p2={k['p2']:g}")
        params = np.array([fx, fy, cx, cy, k["k1"], k["k2"], k["k3"], k["k4"]])
    else:
        if model in ("PINHOLE", "SIMPLE_PINHOLE") and any(k.values()):
            raise FormatError(f"{where}: camera_model {model} with distortion coefficients "
                              f"({', '.join(f'{n}={v:g}' for n, v in k.items() if v)}); expected OPENCV")
        if k["k4"]:
            raise FormatError(f"{where}: k4 = {k['k4']:g} is a fisheye coefficient; expected camera_model "
                              "OPENCV_FISHEYE")
        if k["k3"]:
            model = "FULL_OPENCV"
            params = np.array([fx, fy, cx, cy, k["k1"], k["k2"], k["p1"], k["p2"], k["k3"], 0.0, 0.0, 0.0])
        else:
            model = "OPENCV"
            params = np.array([fx, fy, cx, cy, k["k1"], k["k2"], k["p1"], k["p2"]])
    return (model, params) if is_distorted(model, params) else None


def frame_size(m: dict, where: str) -> tuple[int, int] | None:
    """(w, h) of a frame's merged keys (top level overridden per frame), None when absent."""
    if "w" not in m or "h" not in m:
        return None
    try:
        w, h = int(m["w"]), int(m["h"])
    except (TypeError, ValueError, OverflowError):
        raise FormatError(f"{where}: 'w'/'h' are not integers ({m['w']!r}, {m['h']!r})") from None
    if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE):
        raise BadValueError(f"{where}: 'w'/'h' = {w}, {h}: expected image sides of 1 to {MAX_SIDE} pixels")
    return w, h


def cam_from_gl(camera_to_world: object, where: str) -> np.ndarray:
    """``cam_from_world`` (OpenCV axes) of a camera-to-world matrix in Blender/OpenGL camera axes
    (4x4 or 3x4, checked rigid): ``inverse(c2w @ GL_TO_CV)``. The one axis conversion of the
    transforms files and of the pose files in their conventions (formats/poses.py)."""
    return invert_rigid(rigid_from_matrix(camera_to_world, where) @ GL_TO_CV)


def frame_camera(meta: dict, frame: dict, size: tuple[int, int], where: str) -> Camera:
    """The pinhole camera of one ``frames[]`` entry of size ``size`` = (w, h): intrinsics from the
    entry's keys over the file's (module doc), pose from its ``transform_matrix``."""
    m = {**meta, **frame}  # per-frame intrinsics override the file's
    w, h = size
    fx = _focal(m, "x", w, where)
    if fx is None:
        raise FormatError(f"{where}: missing key 'camera_angle_x' (or 'fl_x')")
    fy = _focal(m, "y", h, where)
    if fy is None:
        fy = fx
    if not (fx > 0 and fy > 0):
        raise BadValueError(f"{where}: focal length must be positive, got fx={fx}, fy={fy}")
    cx = _number(m, "cx", where) if "cx" in m else w / 2
    cy = _number(m, "cy", where) if "cy" in m else h / 2
    if "transform_matrix" not in frame:
        raise FormatError(f"{where}: missing key 'transform_matrix'")
    pose = cam_from_gl(frame["transform_matrix"], f"{where} transform_matrix")
    with named(where):
        return Camera.pinhole(w, h, fx, fy, cx, cy, pose)


def _camera(meta: dict, frame: dict, image: Path, where: str) -> tuple[Camera, tuple[str, np.ndarray] | None]:
    """The frame's undistorted pinhole camera and its lens distortion (None: none)."""
    m = {**meta, **frame}
    size = frame_size(m, where)
    if size is not None:
        check_same_size(image, size, "image", f"'w', 'h' of {where}")
    else:
        size = image_size(image)
    cam = frame_camera(meta, frame, size, where)
    return cam, _distortion(m, cam.fx, cam.fy, cam.cx, cam.cy, where)


def _undistorted(und: Undistorter | None, fn: Callable[..., np.ndarray], nearest: bool = False
                 ) -> Callable[..., np.ndarray]:
    """``fn`` (a loader of the distorted image) followed by the undistortion (bilinear; nearest
    for depth and masks); ``fn`` itself when the camera has no distortion."""
    if und is None:
        return fn

    def load(*args, **kwargs):
        img = fn(*args, **kwargs)
        return und.nearest(img) if nearest else und.bilinear(img)
    return load


def _mask_undistorted(und: Undistorter, image: Path | None, size: tuple[int, int]) -> np.ndarray:
    """The mask of an undistorted view: its source inside the distorted image (and, for RGBA
    images, alpha > 0.5 there)."""
    inside = und.inside()
    return inside if image is None else np.ascontiguousarray(inside & und.nearest(_load_mask(image, size)))


@document_errors
def load(path: Path, options: dict) -> Scene:
    path = Path(path)
    options = check_options(options, OPTIONS, NAME)
    split = opt_choice(options, "split", "all", ("all",) + SPLITS)
    background = {"black": 0.0, "white": 1.0}[opt_choice(options, "background", "black", ("black", "white"))]
    depth_scale = opt_float(options, "depth_scale", 8.0, positive=True)
    if depth_scale > F32_MAX:  # the depth of code 0 would overflow float32
        raise BadValueError(f"option depth_scale: {depth_scale:g} overflows float32 (largest {F32_MAX:.3g}); "
                            "expected the ray distance of depth code 0")
    use_depth = opt_choice(options, "depth", "auto", ("auto", "none")) == "auto"
    depth_unit = opt_float(options, "depth_unit", 0.001, positive=True)
    dequantize = _dequantize_option(options)
    if not path.exists():
        raise MissingFileError(f"{path}: no such file or directory")
    files = _json_files(path)
    if split != "all":
        files = [(s, f) for s, f in files if s == split]
        if not files:
            raise MissingFileError(f"{path}: no transforms_{split}.json (option split={split})")
    if not files:
        raise FormatError(f"{path}: no transforms*.json found")

    entries = []  # (split, stem, camera, distortion, image, depth file)
    missing: list[str] = []  # frames whose image is not there (skipped, counted in one warning)
    listed = 0
    for s, jf in files:
        meta = read_json(jf)
        if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
            raise FormatError(f"{jf}: expected a JSON object with a 'frames' list")
        if not meta["frames"]:
            raise FormatError(f"{jf}: 'frames' is empty")
        for i, frame in enumerate(meta["frames"]):
            where = f"{jf} frames[{i}]"
            if not isinstance(frame, dict) or "file_path" not in frame:
                raise FormatError(f"{where}: missing key 'file_path'")
            listed += 1
            image = resolve_image(jf.parent, str(frame["file_path"]))
            if image is None:
                missing.append(str(jf.parent / str(frame["file_path"])))
                continue
            camera, distortion = _camera(meta, frame, image, where)
            metric = use_depth and "depth_file_path" in frame
            if metric:
                depth = jf.parent / str(frame["depth_file_path"])
                if not depth.is_file():
                    raise MissingFileError(f"{depth}: depth image of {where} (depth_file_path) not found")
                if image_header(depth)[3] == "uint8":
                    raise DtypeError(f"{depth}: 8-bit image cannot hold metric depth (depth_file_path: expected "
                                     "16-bit PNG or EXR)")
            else:
                depth = _depth_file(image) if use_depth else None
            if depth is not None:
                check_same_size(depth, (camera.width, camera.height), "depth image", f"size of {image.name}")
            entries.append((s, image.stem, camera, distortion, image, depth, metric))
    if not entries:
        raise MissingFileError(f"{missing[0]}: image not found (tried extensions "
                               f"{', '.join(e or 'none' for e in IMAGE_EXTS)}); none of the {listed} frames "
                               f"listed in {', '.join(str(f) for _, f in files)} has its image")
    warnings = []
    if missing:
        warnings.append(f"{len(missing)} of {listed} frames skipped: image not found ({missing[0]}"
                        + (f", ... {missing[-1]})" if len(missing) > 1 else ")"))

    stems = [e[1] for e in entries]
    collide = {st for st in stems if stems.count(st) > 1}
    views = []
    undistorters: dict[tuple, Undistorter] = {}
    for s, stem, camera, distortion, image, depth, metric in entries:
        name = f"{s}/{stem}" if stem in collide and s else stem
        size = (camera.width, camera.height)
        und = None
        if distortion is not None:
            key = (size, distortion[0], tuple(distortion[1]))
            und = undistorters.setdefault(key, Undistorter(camera, *distortion))
        alpha = _has_alpha(image)
        if und is None:
            mask = FileLoader(image, _load_mask, image, size=size) if alpha else None
        else:
            mask = FileLoader(image, _mask_undistorted, und, image if alpha else None, size=size)
        color = FileLoader(image, _undistorted(und, _load_color), image, background, size=size)
        if metric:  # nerfstudio's depth_file_path: z-depth, 16-bit values * depth_unit (float as stored)
            scale = depth_unit if image_header(depth)[3] == "uint16" else None
            views.append(View.create(name, camera, color=color, mask=mask,
                                     depth=FileLoader(depth, _undistorted(und, read_depth, True), depth, scale=scale,
                                                      size=size)))
            continue
        views.append(View.create(
            name, camera, color=color,
            depth=(FileLoader(depth, _undistorted(und, _load_depth, True), depth, camera, depth_scale, dequantize)
                   if depth is not None else None),
            mask=mask,
            depth_stored=(FileLoader(depth, _undistorted(und, _load_depth, True), depth, camera, depth_scale, 0)
                          if depth is not None and _filters_depth(depth, dequantize) else None)))
    dup = sorted({v.name for v in views if [w.name for w in views].count(v.name) > 1})
    if dup:
        raise FormatError(f"{path}: duplicate view names {dup[:5]} (two frames name the same image)")
    notes = [f"RGBA composited over {'white' if background else 'black'} on the sRGB values; "
             "mask = alpha > 0.5"]
    if any(e[6] for e in entries):
        notes.append(f"depth_file_path: z-depth = 16-bit value * {depth_unit:g} (float images as stored)")
    if any(e[5] is not None and not e[6] for e in entries):
        notes.append(f"depth: ray distance = {depth_scale:g} * (1 - v/vmax), v = 0 background at infinity, "
                     "converted to z"
                     + (f"; codes de-quantised: auto (8-bit: {AUTO_DEQUANTIZE['uint8']} rounds, "
                        f"16-bit: {AUTO_DEQUANTIZE['uint16']})" if dequantize is None
                        else f"; codes de-quantised ({dequantize} rounds)" if dequantize else ""))
    source = {"format": NAME, "path": str(path), "files": [str(f) for _, f in files],
              "background": "white" if background else "black", "notes": "; ".join(notes)}
    adapted = [f"{len(missing)} frames skipped (image not found)"] if missing else []
    models = [e[3][0] for e in entries if e[3] is not None]
    for model in sorted(set(models)):
        adapted.append(f"distortion removed: {models.count(model)} views ({model}), undistorted to a pinhole "
                       "with the same fx, fy, cx, cy")
    record_summary(source, adapted=adapted, warnings=warnings)
    return Scene(views=views, units="unknown", shading={"background": [background] * 3}, source=source,
                 root=path if path.is_dir() else path.parent)
