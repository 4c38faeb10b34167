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

import functools
import math
import os
import signal
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from ibrtools.errors import BadValueError, DtypeError, FormatError, MissingFileError, ShapeError
from ibrtools.outputs import mkstemp_beside

FLOAT_EXTS = {".exr", ".pfm", ".hdr"}
F32_MAX = float(np.finfo(np.float32).max)
F32_MIN = float(np.finfo(np.float32).tiny)  # the smallest normal float32
INT_EXTS = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".ppm", ".pgm"}


def _oiio():
    import OpenImageIO as oiio  # deferred: a heavy import that only I/O needs

    return oiio


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding, values in [0, 1] (v / 12.92 continues below 0 and the power
    above 1; NaN stays NaN). float32 of v's shape; the C++ kernel ``_core.srgb_to_linear``
    (within 1e-5 relative of the exact curve, tests/test_imageio_srgb.py)."""
    from ibrtools import _core

    return _core.srgb_to_linear(np.asarray(v, dtype=np.float32, order="C"))


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding; input clipped to [0, 1], NaN mapped to 0. float32 of v's shape.

    The C++ kernel (``_core.linear_to_srgb``: vectorised, multithreaded, within 1e-6 relative of
    the exact curve, tests/test_imageio_srgb.py; ~6x faster than numpy's float32 formula on 2
    cores, docs/benchmarks.md "sRGB encoding and decoding")."""
    from ibrtools import _core

    return _core.linear_to_srgb(np.asarray(v, dtype=np.float32, order="C"))  # 0-d stays 0-d


def quantize(encoded: np.ndarray, bits: int = 8) -> np.ndarray:
    """Encoded values in [0, 1] (sRGB colour, alpha) -> unsigned integers of ``bits`` (8 or 16),
    rounded to nearest (ties to even): the one quantisation of every 8/16-bit output."""
    full = 255.0 if bits == 8 else 65535.0
    return np.round(encoded * full).astype(np.uint8 if bits == 8 else np.uint16)


def srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear colour -> 8-bit sRGB (clipped to [0, 1], NaN -> 0), as PNGs are written:
    ``quantize(linear_to_srgb(linear))`` in one C++ pass (``_core.linear_to_srgb8``, the same bits)."""
    from ibrtools import _core

    return _core.linear_to_srgb8(np.asarray(linear, dtype=np.float32, order="C"))  # 0-d stays 0-d


# Images read without an expected size (textures, reports, importers that learn the size from the
# image itself) are refused beyond this many pixels: 2^28 = 16384 x 16384, 3 GiB as float32 RGB.
# A PNG of that many zeros is a file of about 260 KB: only the header says what decoding would cost.
MAX_PIXELS = 1 << 28
_MESSAGE_CHARS = 300  # a library's error text is folded into one line of at most this many characters
_SAMPLE_BYTES = {"uint8": 1, "int8": 1, "uint16": 2, "int16": 2, "half": 2}


def one_line(text: str, limit: int = _MESSAGE_CHARS) -> str:
    """``text`` (a library's error message, possibly several lines) as one line: lines stripped,
    empty and repeated ones dropped, joined with "; ", cut to ``limit`` characters."""
    lines: list[str] = []
    for line in str(text).splitlines():
        line = line.strip()
        if line and line not in lines:
            lines.append(line)
    out = "; ".join(lines)
    return out if len(out) <= limit else out[:limit - 3] + "..."


def _geterror(source, default: str) -> str:
    """OpenImageIO's error text on one line, or ``default``. A corrupt file can put raw bytes from
    its header into the message, which OpenImageIO's Python binding then fails to decode as UTF-8
    (found by tests/formats/test_fuzz_importers.py): that must not turn a FormatError into a
    UnicodeDecodeError."""
    try:
        msg = source.geterror()
    except UnicodeDecodeError:
        return default + " (undecodable error text)"
    return one_line(msg) or default


_STDERR_LOCK = threading.Lock()


class _CapturedStderr:
    text = ""


@contextmanager
def _stderr_to_message() -> Iterator[_CapturedStderr]:
    """Captures file descriptor 2 for the block: libpng reports a corrupt file with its own
    "libpng error: ..." lines on the process's stderr (besides OpenImageIO's error text), which
    would otherwise reach the terminal beside the command's one-line error. The caller folds
    ``.text`` into its message when the decode fails; when it succeeds the text is written back
    to stderr (it may be another thread's output written meanwhile). One capture at a time."""
    cap = _CapturedStderr()
    with _STDERR_LOCK:
        try:
            saved = os.dup(2)
        except OSError:  # no fd 2 (a daemon): nothing to capture
            saved = None
        if saved is None:
            yield cap
            return
        try:
            with tempfile.TemporaryFile() as tmp:
                os.dup2(tmp.fileno(), 2)
                try:
                    yield cap
                finally:
                    os.dup2(saved, 2)
                    tmp.seek(0)
                    cap.text = tmp.read(1 << 16).decode("utf-8", "replace")
        finally:
            os.close(saved)


# Lines that image libraries write to fd 2 themselves (libpng's default error and warning handlers).
_LIBRARY_LINES = ("libpng error: ", "libpng warning: ")


def _library_error(source, cap: _CapturedStderr, default: str) -> str:
    """The failure as one line: OpenImageIO's text, then what the library printed on fd 2 that it
    does not already say. Other captured lines (another thread's output written meanwhile) go
    back to stderr."""
    msg = _geterror(source, "")
    extra, other = [], []
    for line in cap.text.splitlines(keepends=True):
        if line.startswith(_LIBRARY_LINES):
            said = line.strip().split(": ", 1)[1]
            if said not in msg:
                extra.append(line)
        elif line.strip():
            other.append(line)
    cap.text = "".join(other)
    _release(cap)
    return one_line("\n".join([msg, *extra])) or default


def _release(cap: _CapturedStderr) -> None:
    """Writes what a capture caught back to stderr (after a successful decode: nothing is lost)."""
    if cap.text:
        try:
            os.write(2, cap.text.encode("utf-8", "replace"))
        except OSError:
            pass
        cap.text = ""


def _check_header(path: Path, spec, size: tuple[int, int] | None) -> None:
    """Refuses, from the header alone, an image of the wrong size or one whose decoding would not
    fit: the pixels of a decompression bomb are never decoded."""
    w, h, c = int(spec.width), int(spec.height), int(spec.nchannels)
    if w < 1 or h < 1 or c < 1:
        raise FormatError(f"{path}: image header says {w}x{h} with {c} channels")
    if size is not None:
        want = (int(size[0]), int(size[1]))
        if (w, h) != want:
            raise ShapeError(f"{path}: image is {w}x{h}, the camera says {want[0]}x{want[1]}")
    elif w * h > MAX_PIXELS:
        raise ShapeError(f"{path}: image is {w}x{h} ({w * h / 1e6:.0f} Mpixels), more than the "
                         f"{MAX_PIXELS / 1e6:.0f} Mpixels read without an expected size")
    # as stored, then as float32 RGB(A) after conversion (read_image)
    need = w * h * (c * _SAMPLE_BYTES.get(str(spec.format), 4) + 4 * min(max(c, 3), 4))
    if need > 64 << 20:
        from ibrtools.memory import available_memory

        avail = available_memory()
        if need > avail:
            raise BadValueError(f"{path}: image is {w}x{h} with {c} channels: decoding needs "
                                f"{need / 2**30:.1f} GiB, {max(avail, 0) / 2**30:.1f} GiB available")


def read_header(path: str | os.PathLike, size: tuple[int, int] | None = None) -> tuple[int, int, int, str]:
    """(width, height, channels, sample format such as "uint8") of an image file from its header
    alone (no pixel is decoded), checked as :func:`read_pixels` checks it before decoding."""
    path = Path(path)
    inp = _open(path)
    try:
        spec = inp.spec()
        _check_header(path, spec, size)
        if inp.format_name() == "png":
            _check_png_end(path)
        return int(spec.width), int(spec.height), int(spec.nchannels), str(spec.format)
    finally:
        inp.close()


def _open(path: Path, config=None):
    """OpenImageIO's reader of ``path`` (its header read), or the one-line error of a file that
    is missing or not a readable image (what the library printed folded into it)."""
    if not path.is_file():
        raise MissingFileError(f"{path}: no such file")
    oiio = _oiio()
    with _stderr_to_message() as cap:
        inp = oiio.ImageInput.open(str(path)) if config is None else oiio.ImageInput.open(str(path), config)
    if inp is None:
        raise FormatError(f"{path}: not a readable image ({_library_error(oiio, cap, 'unknown format')})")
    _release(cap)
    return inp


_PNG_END = b"\0\0\0\0IEND\xaeB`\x82"  # the IEND chunk (empty, and its CRC) that closes every PNG
_PNG_TAIL = 1 << 16  # bytes searched for it: decoders ignore data appended after IEND, so must we


def _check_png_end(path: Path) -> None:
    """A PNG without its IEND chunk near the end is cut short (an interrupted copy or download):
    found from the file's end, without decoding, where decoding would fail later."""
    with open(path, "rb") as fh:
        fh.seek(0, os.SEEK_END)
        n = fh.tell()
        fh.seek(max(0, n - _PNG_TAIL))
        if _PNG_END not in fh.read():
            raise FormatError(f"{path}: truncated PNG (no IEND chunk at the end of its {n} bytes)")


def read_pixels(path: str | os.PathLike, size: tuple[int, int] | None = None) -> tuple[np.ndarray, str]:
    """Pixels as stored (H, W, C), alpha **straight** (unassociated, as PNG holds it: OpenImageIO
    would otherwise premultiply colour, and any channel stored beside alpha, on read), and the
    base type name ('uint8', 'uint16' or 'float').

    ``size`` (width, height): the size the caller expects (its camera's); an image of another size
    is refused from its header (ShapeError), before any pixel is decoded. Without it, images of
    more than :data:`MAX_PIXELS` pixels are refused; and any image whose decoding would need more
    memory than is available. A file that cannot be decoded is a FormatError with one line."""
    path = Path(path)
    oiio = _oiio()
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = _open(path, config)
    try:
        spec = inp.spec()
        _check_header(path, spec, size)
        fmt = str(spec.format)
        if fmt not in ("uint8", "uint16"):
            fmt = "float"
        with _stderr_to_message() as cap:
            arr = inp.read_image(fmt)
        if arr is None:
            raise FormatError(f"{path}: could not decode ({_library_error(inp, cap, 'truncated or corrupt')})")
        _release(cap)
    finally:
        inp.close()
    arr = np.asarray(arr)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    # PFM stores rows bottom to top. OpenImageIO 3.2 flips them on read only when opened with
    # a configuration spec (as here); tests/test_imageio.py pins this with a hand-written file.
    return arr, fmt


@functools.lru_cache(maxsize=2)
def _srgb_decode_table(fmt: str) -> np.ndarray:
    """Linear float32 of every code of an 8- or 16-bit sRGB sample: srgb_to_linear(code / max)."""
    n = 256 if fmt == "uint8" else 65536
    table = srgb_to_linear(np.arange(n, dtype=np.float32) / np.float32(n - 1))
    table.flags.writeable = False
    return table


def read_image(path: str | os.PathLike, *, alpha: bool = False, size: tuple[int, int] | None = None
               ) -> np.ndarray:
    """Linear float32 colour (H, W, 3), or (H, W, 4) with ``alpha=True`` (alpha is never
    sRGB-decoded). Colour is straight, not multiplied by alpha. Grey images are expanded to
    RGB; missing alpha reads as 1. ``size`` (width, height): as :func:`read_pixels`."""
    from ibrtools import _core

    arr, fmt = read_pixels(path, size)
    c = arr.shape[2]
    if fmt in ("uint8", "uint16"):
        # The decode of every code, looked up: the same values as decoding code / (2^bits - 1)
        # pixel by pixel, in one gather.
        codes = arr[..., :3] if c >= 3 else np.repeat(arr[..., :1], 3, axis=2)
        rgb = _core.lookup_codes(np.ascontiguousarray(codes), _srgb_decode_table(fmt))
        if alpha and c in (2, 4):
            scaled = arr.astype(np.float32) / (255.0 if fmt == "uint8" else 65535.0)
    else:
        scaled = arr.astype(np.float32)
        rgb = scaled[..., :3] if c >= 3 else np.repeat(scaled[..., :1], 3, axis=2)
    bad = int(np.count_nonzero(~np.isfinite(rgb)))
    if bad:
        raise BadValueError(f"{path}: colour contains NaN or infinity ({bad} values); expected finite colour")
    if not alpha:
        return np.ascontiguousarray(rgb)
    a = scaled[..., 3:4] if c in (2, 4) else np.ones(rgb.shape[:2] + (1,), np.float32)
    if c == 2:
        a = scaled[..., 1:2]
    return np.ascontiguousarray(np.concatenate([rgb, a], axis=2))


def read_mask(path: str | os.PathLike, *, size: tuple[int, int] | None = None) -> np.ndarray:
    """A boolean mask (H, W): true where the first channel is above half its range (NaN: false).
    ``size`` (width, height): as :func:`read_pixels`."""
    arr, fmt = read_pixels(path, size)
    full = {"uint8": 255, "uint16": 65535}.get(fmt, 1.0)
    return np.ascontiguousarray(arr[..., 0] > full / 2)


def read_depth(path: str | os.PathLike, *, scale: float | None = None, channel: int = 0,
               size: tuple[int, int] | None = None) -> np.ndarray:
    """Depth (H, W) float32. Float formats are read as they are; 16-bit integer images need
    ``scale`` (depth = value * scale, 0 stays unknown). 8-bit depth is refused: it cannot hold
    depth (importers with a documented 8-bit encoding, e.g. NeRF lego, decode it themselves).
    A scale that takes a finite stored value to infinity (float32 overflow) is refused.
    ``size`` (width, height): as :func:`read_pixels`."""
    arr, fmt = read_pixels(path, size)
    if channel >= arr.shape[2]:
        raise ShapeError(f"{path}: depth channel {channel} requested, image has {arr.shape[2]}")
    v = arr[..., channel]
    if fmt == "uint8":
        raise DtypeError(f"{path}: 8-bit image cannot hold depth; use EXR/PFM or 16-bit PNG with a scale")
    if fmt == "uint16":
        if scale is None or not (scale > 0):
            raise BadValueError(f"{path}: 16-bit depth needs a positive scale (depth = value * scale)")
    d = v.astype(np.float32)
    if scale is not None:
        scale = float(scale)
        if not (math.isfinite(scale) and F32_MIN <= scale <= F32_MAX):
            raise BadValueError(f"{path}: depth scale {scale:g} is not a positive float32 "
                                f"(expected {F32_MIN:.3g} to {F32_MAX:.3g})")
        with np.errstate(over="ignore"):
            d = d * np.float32(scale)
        over = np.isinf(d) & np.isfinite(v)
        if over.any():
            raise BadValueError(f"{path}: depth scale {scale:g} times the stored value "
                                f"{float(np.max(v[over])):g} overflows float32 (largest {F32_MAX:.3g})")
    return np.ascontiguousarray(d)


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


# A PNG's row filters (libpng's PNG_FILTER_* bits), by name.
PNG_FILTERS = {"none": 0x08, "sub": 0x10, "up": 0x20, "avg": 0x40, "paeth": 0x80}


def write_image(path: str | os.PathLike, image: np.ndarray, *, bits: int = 8, png_level: int | None = None,
                png_filter: str | None = None) -> Path:
    """Write linear float colour (H, W, C). PNG/JPEG/TIFF: sRGB-encoded at ``bits`` (8 or 16;
    an alpha channel stays linear); EXR/PFM: linear float32, as it is (NaN written as 0, +-inf kept: a depth map's
    background at infinity). ``png_level``: a PNG's zlib compression level, 0-9 (None: zlib's
    default, 6; 1 encodes a 1080p frame about 2.6x faster for a file about 30 % larger; the
    pixels are the same); ``png_filter``: one row filter of PNG_FILTERS for every row (None:
    libpng's adaptive choice among all five, which tries each per row; "sub" at level 1 encodes a
    1080p frame in 40 ms of CPU instead of 86 ms, for a file 1.6 % larger; the same pixels);
    other formats ignore both."""
    path = Path(path)
    if png_level is not None and (isinstance(png_level, bool) or not isinstance(png_level, int)
                                  or not 0 <= png_level <= 9):
        raise BadValueError(f"{path}: png_level must be an integer 0-9, got {png_level!r}")
    if png_filter is not None and png_filter not in PNG_FILTERS:
        raise BadValueError(f"{path}: png_filter must be one of {', '.join(PNG_FILTERS)}, got {png_filter!r}")
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
        pixels = np.nan_to_num(image.astype(np.float32), nan=0.0, posinf=np.inf, neginf=-np.inf)
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
        colour = min(c, 3) if c != 2 else 1
        if bits == 8 and colour == c:
            pixels = srgb8(image)  # the colour in one pass, without the float copy
        else:
            enc = image.astype(np.float32).copy()
            enc[..., :colour] = linear_to_srgb(enc[..., :colour])
            enc[..., colour:] = np.clip(np.nan_to_num(enc[..., colour:]), 0, 1)
            pixels = quantize(enc, bits)
        spec = oiio.ImageSpec(w, h, c, "uint8" if bits == 8 else "uint16")
        if png_level is not None and ext == ".png":
            spec.attribute("png:compressionLevel", png_level)
        if png_filter is not None and ext == ".png":
            spec.attribute("png:filter", PNG_FILTERS[png_filter])
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
