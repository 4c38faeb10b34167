"""COLMAP sparse models (cameras, images; .bin or .txt) with their images, and dense depth maps.

Reader: a small numpy/struct reader of COLMAP's documented binary and text formats
(https://colmap.github.io/format.html). We do not go through pycolmap: it is an optional
extra, its Python API has changed across releases (4.x added rigs and frames), and all we need
is three record types; the tests cross-check this reader against pycolmap when installed.

Convention converted from
  COLMAP already uses OpenCV camera axes (x right, y down, z forward) and stores
  world-to-camera poses: ``qvec`` (w, x, y, z; Hamilton) and ``tvec`` with
  ``point_in_cam = R(q) point_in_world + t``; pixel centres at +0.5 (as ours). So
  cam_from_world = [R(q) | t]. Quaternions whose norm is not 1 (to 1e-3) are refused.
  Camera models: SIMPLE_PINHOLE (f, cx, cy), PINHOLE (fx, fy, cx, cy), SIMPLE_RADIAL (f, cx,
  cy, k), RADIAL (f, cx, cy, k1, k2), OPENCV (fx, fy, cx, cy, k1, k2, p1, p2). Other models
  are refused (FormatError).

Distortion: images of distorted models are undistorted **lazily, on load**, to a pinhole camera
with the same fx, fy, cx, cy and size: each output pixel's normalised coordinate is distorted
with COLMAP's model (exact, no iteration needed in this direction) and the source image is
sampled bilinearly (numpy, vectorised). The only residual is the bilinear interpolation;
pixels that map outside the source are black and excluded from the view's mask. Depth maps
are resampled the same way with nearest-neighbour sampling (depth must not be blended).

Layout
  ``path`` may be a model folder (holding cameras.bin|txt) or a data-set folder with the model
  in ``sparse/0``, ``sparse`` or any sub-folder (two levels deep; ``sparse/0`` wins, then the
  shortest path) and images in ``images/`` or the single ``images_*`` folder (e.g. LLFF
  ``images_4``, fountain-P11 ``images_25``). Images are matched by the file name stored in the
  model. When the images are smaller or larger than the model's cameras (downscaled sets), the
  intrinsics are scaled to the images; the aspect ratio must agree (to one pixel), else
  FormatError. Dense depth maps ``stereo/depth_maps/<name>.geometric.bin`` are read when present
  (COLMAP's array format: ASCII header ``width&height&channels&`` then float32 values, the
  column index fastest, then row, then channel; values <= 0 or non-finite = unknown).

Options
  model=<dir>                 model folder, relative to ``path`` (default: searched)
  images=<dir>                image folder, relative to ``path`` (default: images/ or images_*/)
  depth=geometric|photometric|none   dense depth maps to read (default geometric)
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ibrtools.camera import Camera, check_rigid
from ibrtools.errors import BadValueError, FormatError, MissingFileError, ShapeError
from ibrtools.imageio import read_image
from ibrtools.scene import Scene, View
from ibrtools.formats._common import document_errors, FileLoader, check_options, image_size, named, opt_choice, quat_to_rotation
from ibrtools.formats._undistort import Undistorter, _distort, is_distorted  # noqa: F401 (tests use colmap._distort)

NAME = "colmap"
DESCRIPTION = "COLMAP sparse model (cameras/images .bin|.txt) + images (+ dense depth maps)"
OPTIONS = {"model": "model folder relative to the input", "images": "image folder relative to the input",
           "depth": "geometric|photometric|none"}

# model id -> (name, number of params)
MODELS = {0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
          4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
          8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12)}
SUPPORTED = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
NPARAMS = {name: n for name, n in MODELS.values()}


# --- model reading ------------------------------------------------------------------------------
class _Reader:
    def __init__(self, path: Path):
        self.path, self.data, self.pos = path, path.read_bytes(), 0

    def take(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise FormatError(f"{self.path}: truncated at byte {self.pos} (needed {size} more bytes)")
        out = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return out

    def cstring(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise FormatError(f"{self.path}: truncated image name at byte {self.pos}")
        s = self.data[self.pos:end].decode("utf-8", errors="replace")
        self.pos = end + 1
        return s


def _text_lines(path: Path) -> list[str]:
    return [ln for ln in path.read_text(encoding="utf-8", errors="replace").splitlines()
            if not ln.lstrip().startswith("#")]


def read_cameras(path: Path) -> dict[int, dict]:
    """{camera_id: {"model": name, "width", "height", "params": np.ndarray}} from cameras.bin/.txt."""
    cams = {}
    if path.suffix == ".bin":
        r = _Reader(path)
        (n,) = r.take("<Q")
        for _ in range(n):
            cid, mid, w, h = r.take("<iiQQ")
            if mid not in MODELS:
                raise FormatError(f"{path}: camera {cid}: unknown model id {mid}")
            name, npar = MODELS[mid]
            cams[cid] = {"model": name, "width": w, "height": h, "params": np.array(r.take(f"<{npar}d"))}
        return cams
    for i, ln in enumerate(_text_lines(path), 1):
        parts = ln.split()
        if not parts:
            continue
        try:
            cid, name, w, h = int(parts[0]), parts[1], int(parts[2]), int(parts[3])
            params = np.array([float(v) for v in parts[4:]])
        except (ValueError, IndexError):
            raise FormatError(f"{path}: malformed camera line {ln[:80]!r}") from None
        if name not in NPARAMS:
            raise FormatError(f"{path}: camera {cid}: unknown model {name!r}")
        if len(params) != NPARAMS[name]:
            raise FormatError(f"{path}: camera {cid} ({name}): expected {NPARAMS[name]} parameters, got {len(params)}")
        cams[cid] = {"model": name, "width": w, "height": h, "params": params}
    return cams


def read_images(path: Path) -> dict[int, dict]:
    """{image_id: {"qvec", "tvec", "camera_id", "name"}} from images.bin/.txt (2-D points skipped)."""
    imgs = {}
    if path.suffix == ".bin":
        r = _Reader(path)
        (n,) = r.take("<Q")
        for _ in range(n):
            vals = r.take("<i7di")
            name = r.cstring()
            (npts,) = r.take("<Q")
            skip = npts * 24  # x, y (double), point3D_id (int64)
            if r.pos + skip > len(r.data):
                raise FormatError(f"{path}: truncated in the 2-D points of image {name!r}")
            r.pos += skip
            imgs[vals[0]] = {"qvec": np.array(vals[1:5]), "tvec": np.array(vals[5:8]), "camera_id": vals[8],
                             "name": name}
        return imgs
    lines = _text_lines(path)
    i = 0
    while i < len(lines):
        parts = lines[i].split()
        if not parts:
            i += 1
            continue
        try:
            iid = int(parts[0])
            q = np.array([float(v) for v in parts[1:5]])
            t = np.array([float(v) for v in parts[5:8]])
            cid = int(parts[8])
            name = " ".join(parts[9:])
        except (ValueError, IndexError):
            raise FormatError(f"{path}: malformed image line {lines[i][:80]!r}") from None
        if not name:
            raise FormatError(f"{path}: image {iid} has no name")
        imgs[iid] = {"qvec": q, "tvec": t, "camera_id": cid, "name": name}
        i += 2  # the next line holds the 2-D points (possibly empty)
    return imgs


def read_array(path: Path) -> np.ndarray:
    """A COLMAP dense array (depth or normal map) as (H, W) or (H, W, C) float32."""
    data = Path(path).read_bytes()
    pos, fields = 0, []
    for _ in range(3):
        end = data.find(b"&", pos)
        if end < 0 or end - pos > 20:
            raise FormatError(f"{path}: not a COLMAP array (expected 'width&height&channels&' header)")
        fields.append(data[pos:end])
        pos = end + 1
    try:
        w, h, c = (int(f) for f in fields)
    except ValueError:
        raise FormatError(f"{path}: malformed COLMAP array header {b'&'.join(fields)!r}") from None
    n = w * h * c
    if len(data) - pos != 4 * n:
        raise FormatError(f"{path}: {w}x{h}x{c} float32 array needs {4 * n} bytes after the header, "
                          f"file has {len(data) - pos}")
    arr = np.frombuffer(data, np.float32, count=n, offset=pos).reshape(c, h, w).transpose(1, 2, 0)
    return np.ascontiguousarray(arr[..., 0] if c == 1 else arr)


# --- distortion (the models and the maps: _undistort.py) ---------------------------------------
def _intrinsics(model: str, p: np.ndarray) -> tuple[float, float, float, float]:
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        return p[0], p[0], p[1], p[2]
    return p[0], p[1], p[2], p[3]


class _Undistorter(Undistorter):
    """COLMAP's files through the shared undistortion map."""

    def color(self, path: Path, size: tuple[int, int] | None = None) -> np.ndarray:
        img = read_image(path, size=(self.cam.width, self.cam.height))  # refused from its header
        return self.bilinear(img)

    def mask(self) -> np.ndarray:
        return self.inside()

    def depth(self, path: Path) -> np.ndarray:
        return self.nearest(_load_depth(path, self.cam))


def _load_depth(path: Path, cam: Camera) -> np.ndarray:
    d = read_array(path)
    if d.ndim != 2:
        raise ShapeError(f"{path}: expected a one-channel depth map, got {d.shape[2]} channels")
    if d.shape != (cam.height, cam.width):
        raise ShapeError(f"{path}: depth map is {d.shape[1]}x{d.shape[0]}, expected {cam.width}x{cam.height} "
                         "(the view's image size)")
    d = np.where(np.isfinite(d) & (d > 0), d, 0).astype(np.float32)
    return np.ascontiguousarray(d)


# --- layout -------------------------------------------------------------------------------------
def _is_model(d: Path) -> bool:
    return (d / "cameras.bin").is_file() or (d / "cameras.txt").is_file()


def _find_model(path: Path) -> Path | None:
    if _is_model(path):
        return path
    for cand in (path / "sparse" / "0", path / "sparse"):
        if _is_model(cand):
            return cand
    subs = sorted([d for d in path.glob("*") if d.is_dir() and _is_model(d)]
                  + [d for d in path.glob("*/*") if d.is_dir() and _is_model(d)],
                  key=lambda d: (len(d.relative_to(path).parts), str(d)))
    return subs[0] if subs else None


def _find_images(root: Path) -> Path | None:
    if (root / "images").is_dir():
        return root / "images"
    cands = sorted(d for d in root.glob("images_*") if d.is_dir())
    return cands[0] if len(cands) == 1 else None


def detect(path: Path) -> bool:
    path = Path(path)
    return path.is_dir() and _find_model(path) is not None


def _model_file(model: Path, stem: str) -> Path:
    for ext in (".bin", ".txt"):
        if (model / (stem + ext)).is_file():
            return model / (stem + ext)
    raise MissingFileError(f"{model}: no {stem}.bin or {stem}.txt")


@document_errors
def load(path: Path, options: dict) -> Scene:
    path = Path(path)
    options = check_options(options, OPTIONS, NAME)
    depth_kind = opt_choice(options, "depth", "geometric", ("geometric", "photometric", "none"))
    if not path.is_dir():
        raise MissingFileError(f"{path}: not a directory")
    if "model" in options:
        model = path / str(options["model"])
        if not _is_model(model):
            raise MissingFileError(f"{model}: no cameras.bin or cameras.txt (option model=)")
    else:
        model = _find_model(path)
        if model is None:
            raise FormatError(f"{path}: no COLMAP model (cameras.bin|txt in sparse/0, sparse or a sub-folder)")
    root = path if model != path else (path.parent if not _find_images(path) else path)
    if "images" in options:
        images_dir = path / str(options["images"])
        if not images_dir.is_dir():
            raise MissingFileError(f"{images_dir}: no such directory (option images=)")
    else:
        images_dir = _find_images(root)
        if images_dir is None:
            found = sorted(d.name for d in root.glob("images*") if d.is_dir())
            raise FormatError(f"{root}: no image folder (expected images/ or a single images_*/, found "
                              f"{found or 'none'}; pass images=DIR)")
    cams_file = _model_file(model, "cameras")
    cams = read_cameras(cams_file)
    imgs = read_images(_model_file(model, "images"))
    if not imgs:
        raise FormatError(f"{model}: the model has no images")
    depth_dir = root / "stereo" / "depth_maps"

    views = []
    undistorters: dict[tuple[int, int, int], _Undistorter] = {}
    scaled_note = None
    for iid in sorted(imgs, key=lambda k: imgs[k]["name"]):
        im = imgs[iid]
        where = f"{model} image {im['name']!r}"
        if im["camera_id"] not in cams:
            raise FormatError(f"{where}: camera {im['camera_id']} is not in cameras")
        c = cams[im["camera_id"]]
        if c["model"] not in SUPPORTED:
            raise FormatError(f"{where}: camera model {c['model']} is not supported "
                              f"(supported: {', '.join(SUPPORTED)})")
        fx, fy, cx, cy = _intrinsics(c["model"], c["params"])
        if not (fx > 0 and fy > 0):
            raise BadValueError(f"{cams_file}: camera {im['camera_id']}: focal length must be positive, got {fx}, {fy}")
        pose = np.eye(4)
        pose[:3, :3] = quat_to_rotation(*im["qvec"], where=where)
        pose[:3, 3] = im["tvec"]
        with named(f"{where}: pose"):
            pose = check_rigid(pose)
        with named(f"{cams_file}: camera {im['camera_id']}"):
            cam = Camera.pinhole(c["width"], c["height"], fx, fy, cx, cy, pose)
        img_path = images_dir / im["name"]
        if not img_path.is_file():
            raise MissingFileError(f"{img_path}: image {im['name']!r} of the model not found in {images_dir}")
        w, h = image_size(img_path)
        if (w, h) != (cam.width, cam.height):
            # Downscaled images: scale the intrinsics; the aspect ratio must agree to a pixel.
            s = w / cam.width
            if abs(cam.height * s - h) > 1.0 or abs(cam.width * (h / cam.height) - w) > 1.0:
                raise FormatError(f"{img_path}: image is {w}x{h} but the model's camera {im['camera_id']} is "
                                  f"{cam.width}x{cam.height}: different aspect ratio, cannot scale")
            cam = cam.scaled(w, h)
            scaled_note = f"intrinsics scaled from {c['width']}x{c['height']} to the images ({w}x{h})"
        distorted = is_distorted(c["model"], c["params"])
        depth_file = depth_dir / f"{im['name']}.{depth_kind}.bin" if depth_kind != "none" else None
        has_depth = depth_file is not None and depth_file.is_file()
        if distorted:
            key = (im["camera_id"], w, h)
            if key not in undistorters:
                undistorters[key] = _Undistorter(cam, c["model"], c["params"])
            und = undistorters[key]
            view = View.create(str(Path(im["name"]).with_suffix("")), cam,
                               color=FileLoader(img_path, und.color, img_path, size=(w, h)),
                               depth=FileLoader(depth_file, und.depth, depth_file) if has_depth else None,
                               mask=FileLoader(img_path, und.mask))
        else:
            view = View.create(str(Path(im["name"]).with_suffix("")), cam,
                               color=FileLoader(img_path, read_image, img_path, size=(w, h)),
                               depth=FileLoader(depth_file, _load_depth, depth_file, cam) if has_depth else None)
        views.append(view)
    notes = []
    if scaled_note:
        notes.append(scaled_note)
    if undistorters:
        notes.append("distorted cameras undistorted on load to pinhole with the same K (bilinear)")
    return Scene(views=views, units="unknown",
                 source={"format": NAME, "path": str(path), "model": str(model), "images": str(images_dir),
                         "notes": "; ".join(notes)},
                 root=root)
