"""Image and depth I/O through OpenImageIO.

Colour in memory is float32 *linear* RGB (H, W, 3), C-contiguous. Integer formats (PNG 8/16-bit,
JPEG) hold sRGB-encoded values: decoded on read, encoded on write. EXR and PFM hold linear
floats as they are. Depth never goes through 8 bits: it is read from float formats (EXR, PFM,
TIFF float) or from 16-bit PNG with an explicit scale (``depth = value * scale``, the
documented integer encoding of RGB-D data sets such as ICL-NUIM and TUM: scale 1/5000).
Unknown depth is 0 in memory and on disk (docs/FORMAT.md).

Writes are atomic: a temporary file in the same directory, then a rename.
"""
from __future__ import annotations

import os
import signal
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import BadValueError, DtypeError, FormatError, MissingFileError, ShapeError
from .outputs import mkstemp_beside

FLOAT_EXTS = {".exr", ".pfm", ".hdr"}
INT_EXTS = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".ppm", ".pgm"}


def _oiio():
    import OpenImageIO as oiio  # deferred: a heavy import that only I/O needs

    return oiio


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding, values in [0, 1] (v / 12.92 continues below 0 and the power
    above 1; NaN stays NaN). float32 of v's shape; the C++ kernel ``_core.srgb_to_linear``
    (within 1e-5 relative of the exact curve, tests/test_imageio_srgb.py)."""
    from . import _core

    return _core.srgb_to_linear(np.asarray(v, dtype=np.float32, order="C"))


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding; input clipped to [0, 1], NaN mapped to 0. float32 of v's shape.

    The C++ kernel (``_core.linear_to_srgb``: vectorised, multithreaded, within 1e-6 relative of
    the exact curve, tests/test_imageio_srgb.py; ~6x faster than numpy's float32 formula on 2
    cores, docs/benchmarks.md "sRGB encoding and decoding")."""
    from . import _core

    return _core.linear_to_srgb(np.asarray(v, dtype=np.float32, order="C"))  # 0-d stays 0-d


def _geterror(source, default: str) -> str:
    """OpenImageIO's error text, or ``default``. A corrupt file can put raw bytes from its header
    into the message, which OpenImageIO's Python binding then fails to decode as UTF-8 (found by
    tests/test_fuzz_importers.py): that must not turn a FormatError into a UnicodeDecodeError."""
    try:
        msg = source.geterror()
    except UnicodeDecodeError:
        return default + " (undecodable error text)"
    return msg.strip() or default


def read_pixels(path: str | os.PathLike) -> tuple[np.ndarray, str]:
    """Pixels as stored (H, W, C), alpha **straight** (unassociated, as PNG holds it: OpenImageIO
    would otherwise premultiply colour, and any channel stored beside alpha, on read), and the
    base type name ('uint8', 'uint16' or 'float')."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"{path}: no such file")
    oiio = _oiio()
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    if inp is None:
        raise FormatError(f"{path}: not a readable image ({_geterror(oiio, 'unknown format')})")
    try:
        spec = inp.spec()
        fmt = str(spec.format)
        if fmt in ("uint8", "uint16"):
            arr = inp.read_image(fmt)
        else:
            fmt = "float"
            arr = inp.read_image("float")
        if arr is None:
            raise FormatError(f"{path}: could not decode ({_geterror(inp, 'truncated or corrupt')})")
    finally:
        inp.close()
    arr = np.asarray(arr)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    # PFM stores rows bottom to top. OpenImageIO 3.2 flips them on read only when opened with
    # a configuration spec (as here); tests/test_imageio.py pins this with a hand-written file.
    return arr, fmt


def read_image(path: str | os.PathLike, *, alpha: bool = False) -> np.ndarray:
    """Linear float32 colour (H, W, 3), or (H, W, 4) with ``alpha=True`` (alpha is never
    sRGB-decoded). Colour is straight, not multiplied by alpha. Grey images are expanded to
    RGB; missing alpha reads as 1."""
    arr, fmt = read_pixels(path)
    c = arr.shape[2]
    if fmt in ("uint8", "uint16"):
        scaled = arr.astype(np.float32) / (255.0 if fmt == "uint8" else 65535.0)
        rgb = srgb_to_linear(scaled[..., :3] if c >= 3 else np.repeat(scaled[..., :1], 3, axis=2))
    else:
        scaled = arr.astype(np.float32)
        rgb = scaled[..., :3] if c >= 3 else np.repeat(scaled[..., :1], 3, axis=2)
    if not np.all(np.isfinite(rgb)):
        raise BadValueError(f"{path}: colour contains NaN or infinity")
    if not alpha:
        return np.ascontiguousarray(rgb)
    a = scaled[..., 3:4] if c in (2, 4) else np.ones(rgb.shape[:2] + (1,), np.float32)
    if c == 2:
        a = scaled[..., 1:2]
    return np.ascontiguousarray(np.concatenate([rgb, a], axis=2))


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """A boolean mask (H, W): true where the first channel is above half its range."""
    arr, fmt = read_pixels(path)
    full = {"uint8": 255, "uint16": 65535}.get(fmt, 1.0)
    return np.ascontiguousarray(arr[..., 0] > full / 2)


def read_depth(path: str | os.PathLike, *, scale: float | None = None, channel: int = 0) -> np.ndarray:
    """Depth (H, W) float32. Float formats are read as they are; 16-bit integer images need
    ``scale`` (depth = value * scale, 0 stays unknown). 8-bit depth is refused: it cannot hold
    depth (importers with a documented 8-bit encoding, e.g. NeRF lego, decode it themselves)."""
    arr, fmt = read_pixels(path)
    if channel >= arr.shape[2]:
        raise ShapeError(f"{path}: depth channel {channel} requested, image has {arr.shape[2]}")
    v = arr[..., channel]
    if fmt == "uint8":
        raise DtypeError(f"{path}: 8-bit image cannot hold depth; use EXR/PFM or 16-bit PNG with a scale")
    if fmt == "uint16":
        if scale is None or not (scale > 0):
            raise BadValueError(f"{path}: 16-bit depth needs a positive scale (depth = value * scale)")
        d = v.astype(np.float32) * np.float32(scale)
    else:
        d = v.astype(np.float32) if scale is None else v.astype(np.float32) * np.float32(scale)
    return np.ascontiguousarray(d)


def check_depth(depth: np.ndarray, name: str, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Validate a depth map: float32 (H, W), no NaN, no negatives, some known pixels.
    +inf is allowed (a point at infinity, e.g. sky in MPEG content); 0 means unknown."""
    if not isinstance(depth, np.ndarray) or depth.dtype != np.float32:
        raise DtypeError(f"{name}: expected float32 depth array, got "
                         f"{getattr(depth, 'dtype', type(depth).__name__)}")
    if depth.ndim != 2 or (shape is not None and depth.shape != tuple(shape)):
        want = f"(H, W) = {tuple(shape)}" if shape is not None else "(H, W)"
        raise ShapeError(f"{name}: expected depth of shape {want}, got {depth.shape}")
    nan = int(np.isnan(depth).sum())
    if nan:
        raise BadValueError(f"{name}: {nan} NaN depth pixels; unknown depth must be 0")
    neg = int((depth < 0).sum())
    if neg:
        raise BadValueError(f"{name}: {neg} negative depth pixels (min {float(depth.min()):g})")
    if not np.any(depth > 0):
        raise BadValueError(f"{name}: no valid depth (every pixel is 0 = unknown)")
    return depth


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yields a temporary path beside ``path`` (same extension); renames it over ``path``
    only when the block succeeds, so a reader never sees a half-written file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # SIGINT/SIGTERM raise in Python (cli/ibrtools_cli/common.py): held back while the temporary
    # file is created and not yet guarded by the ``finally`` below, so an interrupt can never
    # leave it behind.
    # The mask in force is read first and restored by the ``finally`` whatever happens after:
    # Python checks for pending signals right after the pthread_sigmask call that blocks, so a
    # KeyboardInterrupt can come out of that call with the signals already blocked (before, the
    # thread then kept SIGINT/SIGTERM blocked for good, and so did every child it started).
    held = {signal.SIGINT, signal.SIGTERM}
    block = hasattr(signal, "pthread_sigmask") and threading.current_thread() is threading.main_thread()
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, ()) if block else None
    old_mask = None
    tmp_path: Path | None = None
    try:
        if mask is not None:
            old_mask = mask
            signal.pthread_sigmask(signal.SIG_BLOCK, held)
        tmp_path = mkstemp_beside(path)  # this process's mark, the umask's mode (ibrtools.outputs)
        if old_mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)
            old_mask = None
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        # the temporary goes first: restoring the mask can raise a signal that arrived meanwhile
        if tmp_path is not None and tmp_path.exists():
            tmp_path.unlink()
        if old_mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)


def write_image(path: str | os.PathLike, image: np.ndarray, *, bits: int = 8) -> Path:
    """Write linear float colour (H, W, C). PNG/JPEG/TIFF: sRGB-encoded at ``bits`` (8 or 16;
    an alpha channel stays linear); EXR/PFM: linear float32, as it is (NaN written as 0)."""
    path = Path(path)
    image = np.asarray(image)
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3 or image.shape[2] not in (1, 2, 3, 4) or image.shape[0] == 0 or image.shape[1] == 0:
        raise ShapeError(f"{path}: expected image of shape (H, W, C) with C in 1..4, got {image.shape}")
    if not np.issubdtype(image.dtype, np.floating):
        raise DtypeError(f"{path}: expected a float image (linear colour), got {image.dtype}")
    ext = path.suffix.lower()
    oiio = _oiio()
    h, w, c = image.shape
    if ext in FLOAT_EXTS:
        pixels = np.nan_to_num(image.astype(np.float32), nan=0.0)
        spec = oiio.ImageSpec(w, h, c, "float")
        # A fixed capture date (OpenEXR "capDate", else the time of writing): the same pixels
        # give the same bytes, so reruns and distributed runs (docs/distributed.md) write
        # identical files.
        spec.attribute("DateTime", "1970:01:01 00:00:00")
    elif ext in INT_EXTS:
        if bits not in (8, 16):
            raise BadValueError(f"{path}: bits must be 8 or 16, got {bits}")
        if ext in (".jpg", ".jpeg") and bits != 8:
            raise BadValueError(f"{path}: JPEG is 8-bit only")
        enc = image.astype(np.float32).copy()
        colour = min(c, 3) if c != 2 else 1
        enc[..., :colour] = linear_to_srgb(enc[..., :colour])
        enc[..., colour:] = np.clip(np.nan_to_num(enc[..., colour:]), 0, 1)
        full = 255.0 if bits == 8 else 65535.0
        pixels = np.round(enc * full).astype(np.uint8 if bits == 8 else np.uint16)
        spec = oiio.ImageSpec(w, h, c, "uint8" if bits == 8 else "uint16")
    else:
        raise FormatError(f"{path}: unknown image extension {ext!r} (expected one of "
                          f"{sorted(FLOAT_EXTS | INT_EXTS)})")
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise FormatError(f"{path}: OpenImageIO cannot write this format ({oiio.geterror().strip()})")
        try:
            if not out.open(str(tmp), spec) or not out.write_image(np.ascontiguousarray(pixels)):
                raise FormatError(f"{path}: write failed ({out.geterror().strip()})")
        finally:
            out.close()
    return path


def write_depth(path: str | os.PathLike, depth: np.ndarray) -> Path:
    """Depth (H, W) as single-channel float32 EXR or PFM (unknown = 0; NaN written as 0)."""
    path = Path(path)
    if path.suffix.lower() not in (".exr", ".pfm"):
        raise FormatError(f"{path}: depth is written as .exr or .pfm only, never through 8 bits")
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ShapeError(f"{path}: expected depth of shape (H, W), got {depth.shape}")
    return write_image(path, depth.astype(np.float32)[:, :, None])
