"""Raw planar YUV files (MPEG test content): reading one frame, Y'CbCr <-> linear RGB, and
writing frames (``rgb_to_yuv``, ``write_frame``: what ``ibr-render --yuv`` appends per frame).

File layout: frames one after the other; each frame is the Y plane (W x H) followed, for 4:2:0,
by the Cb and Cr planes (ceil(W/2) x ceil(H/2) each); 4:0:0 files hold the Y plane only.
Samples are uint8 for 8-bit content and little-endian uint16 for 9..16 bits (the value range
is [0, 2^bits - 1] whatever the container). Only the requested frame is read from disk.

Colour conversion (``yuv_to_rgb``): limited ("video") range by default, as MPEG test
sequences are: Y' in [16, 235] * 2^(bits-8), Cb/Cr centred on 128 * 2^(bits-8) with half-range
112 * 2^(bits-8); full range maps [0, 2^bits - 1]. Matrix BT.709 by default (Kr = 0.2126,
Kb = 0.0722) or BT.601 (Kr = 0.299, Kb = 0.114). Chroma is upsampled 2x with the centred
linear filter (weights 3/4, 1/4, edges clamped). The resulting R'G'B' are clipped to [0, 1]
and decoded with the sRGB transfer function (an approximation of the BT.709/BT.1886 display
transfer: the two differ by a few code values in the darks), giving linear RGB like every
other importer.

Writing (``rgb_to_yuv``) is the inverse: linear RGB clipped to [0, 1], sRGB-encoded, the same
matrix and range, chroma averaged over each 2x2 block (centred siting, the one ``yuv_to_rgb``
upsamples; the last row / column repeated for odd sizes), rounded to the nearest code.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ibrtools.errors import BadValueError, FormatError, MissingFileError

MATRICES = {"bt709": (0.2126, 0.0722), "bt601": (0.299, 0.114)}


def plane_shapes(width: int, height: int, chroma: str = "420") -> list[tuple[int, int]]:
    if not (isinstance(width, (int, np.integer)) and isinstance(height, (int, np.integer))
            and width > 0 and height > 0):
        raise BadValueError(f"YUV frame size: expected positive integers, got {width}x{height}")
    if chroma == "420":
        cw, ch = (width + 1) // 2, (height + 1) // 2
        return [(height, width), (ch, cw), (ch, cw)]
    if chroma == "400":
        return [(height, width)]
    raise BadValueError(f"chroma format: expected '420' or '400', got {chroma!r}")


def frame_bytes(width: int, height: int, bits: int, chroma: str = "420") -> int:
    bps = 1 if bits <= 8 else 2
    return bps * sum(h * w for h, w in plane_shapes(width, height, chroma))


def frame_count(path: Path, width: int, height: int, bits: int, chroma: str = "420") -> int:
    """Number of frames in ``path``; FormatError when its size is not a whole number of frames."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"{path}: no such file")
    size = path.stat().st_size
    fb = frame_bytes(width, height, bits, chroma)
    if size == 0 or size % fb:
        raise FormatError(f"{path}: {size} bytes is not a whole number of {width}x{height} "
                          f"{'4:2:0' if chroma == '420' else '4:0:0'} {bits}-bit frames "
                          f"({fb} bytes each; expected {fb} x N bytes)")
    return size // fb


def read_frame(path: Path, width: int, height: int, bits: int, frame: int = 0,
               chroma: str = "420") -> list[np.ndarray]:
    """The planes [Y, Cb, Cr] (or [Y]) of frame ``frame`` as uint8/uint16 arrays (H, W)."""
    if not 1 <= int(bits) <= 16:
        raise BadValueError(f"{path}: bit depth must be in 1..16, got {bits}")
    n = frame_count(path, width, height, bits, chroma)
    if not 0 <= frame < n:
        raise BadValueError(f"{path}: frame {frame} requested, the file has {n} frame(s) (0..{n - 1})")
    dtype = np.uint8 if bits <= 8 else np.dtype("<u2")
    offset = frame * frame_bytes(width, height, bits, chroma)
    planes = []
    for h, w in plane_shapes(width, height, chroma):
        a = np.fromfile(path, dtype=dtype, count=h * w, offset=offset).reshape(h, w)
        offset += a.nbytes
        planes.append(a.astype(np.uint16) if bits > 8 else a)
    return planes


def yuv_to_rgb(planes: list[np.ndarray], bits: int, matrix: str = "bt709", full_range: bool = False) -> np.ndarray:
    """Linear float32 RGB (H, W, 3) of Y'CbCr planes [Y] or [Y, Cb, Cr] as :func:`read_frame`
    returns them (see the module docstring). The C++ kernel ``_core.yuv_to_linear_rgb``
    (cpp/ibr/colour.h YuvToLinearRgb): every step in float32, bit for bit the numpy definition
    kept as the reference in tests/formats/test_yuv_kernel.py."""
    from ibrtools import _core

    if matrix not in MATRICES:
        raise BadValueError(f"yuv matrix: expected one of {', '.join(MATRICES)}, got {matrix!r}")
    arrays = [np.asarray(p) for p in planes]
    wide = bits > 8 or any(a.dtype != np.uint8 for a in arrays)
    dtype = np.uint16 if wide else np.uint8
    for a in arrays:
        if a.dtype != dtype and a.size and not (a.min() >= 0 and a.max() <= np.iinfo(dtype).max):
            raise BadValueError(f"yuv planes: expected samples in 0..{np.iinfo(dtype).max}, got {a.min()}..{a.max()}")
    y, *chroma = (np.ascontiguousarray(a, dtype=dtype) for a in arrays)
    cb, cr = chroma[:2] if len(chroma) >= 2 else (None, None)
    kr, kb = MATRICES[matrix]
    return _core.yuv_to_linear_rgb(y, cb, cr, int(bits), kr, kb, bool(full_range))


# The bits per sample of YUV output when none is asked for (--yuv-bits): 10, as MPEG content is.
DEFAULT_BITS = 10


def rgb_to_yuv(rgb: np.ndarray, bits: int = DEFAULT_BITS, matrix: str = "bt709", full_range: bool = False) -> list[np.ndarray]:
    """The 4:2:0 planes [Y, Cb, Cr] (uint8 for 8 bits, uint16 above) of linear RGB (H, W, 3)
    (see the module docstring); NaN counts as 0. The C++ kernel ``_core.linear_rgb_to_yuv``
    (cpp/ibr/colour.h LinearRgbToYuv), bit for bit the numpy definition kept as the reference in
    tests/formats/test_yuv_kernel.py."""
    from ibrtools import _core

    if not 8 <= int(bits) <= 16:
        raise BadValueError(f"YUV bit depth: expected 8..16, got {bits}")
    if matrix not in MATRICES:
        raise BadValueError(f"yuv matrix: expected one of {', '.join(MATRICES)}, got {matrix!r}")
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise BadValueError(f"rgb_to_yuv: expected an (H, W, 3) image, got shape {a.shape}")
    kr, kb = MATRICES[matrix]
    y, cb, cr = _core.linear_rgb_to_yuv(np.ascontiguousarray(a, dtype=np.float32), int(bits), kr, kb, bool(full_range))
    return [y, cb, cr]


def write_frame(f, planes: list[np.ndarray]) -> None:
    """Append one frame (its planes as ``rgb_to_yuv`` makes them) to the open binary file ``f``."""
    for p in planes:
        f.write(np.ascontiguousarray(p).tobytes())
