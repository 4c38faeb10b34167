"""Helpers shared by the importers: option parsing, JSON reading, lazy file loaders.

Options reach an importer as a dict; from the command line (``--opt key=value``) every value
is a string, from Python it may be a number. The ``opt_*`` helpers accept both, and every
importer rejects keys it does not know (a misspelt option must not be ignored silently).
"""
from __future__ import annotations

import json
import math
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from ibrtools.camera import orthonormalize
from ibrtools.errors import BadValueError, DtypeError, FormatError, MissingFileError, ShapeError
from ibrtools.camera import check_rigid
from ibrtools.errors import IbrError
from ibrtools.imageio import read_header


class FileLoader:
    """A zero-argument callable that loads one array from ``source`` (a file path) on first
    use; ``View.create`` reads ``.source`` to name the file in error messages.

    A ``size`` keyword ((width, height), passed on to ``fn``: the image size its camera expects)
    makes the loader checkable up front: :meth:`probe` reads the header of ``source`` and refuses
    a file that is unreadable or of another size (``Scene.validate`` probes every view)."""

    def __init__(self, source: str | Path, fn: Callable[..., np.ndarray], *args: Any, **kwargs: Any):
        self.source = str(source)
        self._fn, self._args, self._kwargs = fn, args, kwargs

    def __call__(self) -> np.ndarray:
        return self._fn(*self._args, **self._kwargs)

    @property
    def probe(self) -> Callable[[], Any] | None:
        """Checks the header of ``source`` against ``size`` (None when the loader has no size)."""
        size = self._kwargs.get("size")
        if size is None:
            return None

        return lambda: read_header(self.source, size)

    def __repr__(self) -> str:
        return f"FileLoader({self.source!r})"


@contextmanager
def named(where: str) -> Iterator[None]:
    """Errors of the value checks in the block (``Camera``'s width, focal length, pose...), which
    name the argument but not where it came from, re-raised with ``where`` (the file and entry)
    in front: "cameras.txt: camera 1: camera width: expected an integer >= 1, got 0"."""
    try:
        yield
    except (BadValueError, DtypeError, ShapeError) as e:
        raise type(e)(f"{where}: {e}") from None


def check_options(options: dict, known: dict[str, str], fmt: str) -> dict:
    """``options`` as a dict after checking every key is one ``fmt`` reads (``known``: key ->
    one-line help, used in the error message)."""
    options = dict(options or {})
    unknown = sorted(set(options) - set(known))
    if unknown:
        listing = ", ".join(sorted(known)) or "none"
        raise BadValueError(f"{fmt} importer: unknown option(s) {', '.join(unknown)} (known: {listing})")
    return options


def opt_float(options: dict, key: str, default: float | None, *, positive: bool = False,
              nonnegative: bool = False) -> float | None:
    """A finite float option; strings such as ``"8"`` or ``"1/5000"`` are accepted."""
    if key not in options or options[key] is None:
        return default
    raw = options[key]
    try:
        if isinstance(raw, str) and "/" in raw:
            num, den = raw.split("/", 1)
            value = float(num) / float(den)
        else:
            value = float(raw)
    except (TypeError, ValueError, ZeroDivisionError):
        raise DtypeError(f"option {key}: expected a number, got {raw!r}") from None
    if not math.isfinite(value):
        raise BadValueError(f"option {key}: expected a finite number, got {raw!r}")
    if positive and not value > 0:
        raise BadValueError(f"option {key}: expected a positive number, got {raw!r}")
    if nonnegative and value < 0:
        raise BadValueError(f"option {key}: expected a number >= 0, got {raw!r}")
    return value


def opt_int(options: dict, key: str, default: int | None, *, minimum: int | None = None) -> int | None:
    if key not in options or options[key] is None:
        return default
    raw = options[key]
    try:
        value = int(raw) if not isinstance(raw, float) or raw.is_integer() else None
    except (TypeError, ValueError):
        value = None
    if value is None or isinstance(raw, bool):
        raise DtypeError(f"option {key}: expected an integer, got {raw!r}")
    if minimum is not None and value < minimum:
        raise BadValueError(f"option {key}: expected an integer >= {minimum}, got {value}")
    return value


def opt_choice(options: dict, key: str, default: str, choices: tuple[str, ...]) -> str:
    value = str(options.get(key, default)).strip().lower()
    if value not in choices:
        raise BadValueError(f"option {key}: expected one of {', '.join(choices)}, got {options.get(key)!r}")
    return value


def document_errors(load: Callable) -> Callable:
    """Decorator for importer entry points whose first argument is the path they read.

    A data-set document of the wrong shape (a JSON list where an object is expected, null for a
    number, a string for a matrix...) makes the interpretation code fail with TypeError,
    AttributeError, KeyError, IndexError or a bare ValueError deep inside. Hypothesis fuzzing
    (tests/formats/test_fuzz_importers.py) found dozens of such paths. They are bad input, not bugs:
    re-raised as FormatError naming the file and the failure, so the commands exit 2 with one
    line. Typed errors raised on purpose pass through unchanged."""
    import functools

    @functools.wraps(load)
    def wrapper(path, *args, **kwargs):
        try:
            return load(path, *args, **kwargs)
        except IbrError:
            raise
        except (TypeError, AttributeError, KeyError, IndexError, ValueError, OverflowError) as e:
            raise FormatError(f"{path}: malformed content ({type(e).__name__}: {e})") from None
    return wrapper


def read_json(path: Path) -> Any:
    """Parsed JSON of ``path``; MissingFileError / FormatError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"{path}: no such file")
    try:
        with open(path, "r", encoding="utf-8") as f:
            return json.load(f)
    except json.JSONDecodeError as e:
        raise FormatError(f"{path}: malformed JSON (line {e.lineno}, column {e.colno}: {e.msg})") from None
    except UnicodeDecodeError:
        raise FormatError(f"{path}: not a UTF-8 text file") from None


def rigid_from_matrix(m: Any, where: str) -> np.ndarray:
    """A 4x4 float64 rigid matrix from ``m`` (4x4 or 3x4), checked, then re-orthonormalised
    (files store ~7 significant digits; the check rejects anything that is not noise)."""
    rigid = check_rigid(m, where)
    rigid[:3, :3] = orthonormalize(rigid[:3, :3])
    return rigid


def quat_to_rotation(qw: float, qx: float, qy: float, qz: float, where: str) -> np.ndarray:
    """Rotation matrix of a unit quaternion (Hamilton convention, as COLMAP, TUM and Eigen).
    A quaternion whose norm is not 1 to 1e-3 is refused: it is not a rotation as written."""
    q = np.array([qw, qx, qy, qz], dtype=np.float64)
    if not np.all(np.isfinite(q)):
        raise BadValueError(f"{where}: quaternion contains NaN or infinity")
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > 1e-3:
        raise BadValueError(f"{where}: quaternion norm {n:.6f} is not 1; not a rotation")
    w, x, y, z = q / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def invert_rigid(m: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    r, t = m[:3, :3], m[:3, 3]
    out[:3, :3] = r.T
    out[:3, 3] = -r.T @ t
    return out


def image_header(path: Path) -> tuple[int, int, int, str]:
    """(width, height, channels, sample format such as "uint8") of an image file, from its header
    alone (no pixel decoding)."""
    return read_header(path)


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file from its header only (no pixel decoding)."""
    w, h, _, _ = image_header(path)
    return w, h


def check_same_size(path: Path, size: tuple[int, int], what: str, expected_from: str) -> None:
    w, h = image_size(path)
    if (w, h) != tuple(size):
        from ibrtools.errors import ShapeError

        raise ShapeError(f"{path}: {what} is {w}x{h}, expected {size[0]}x{size[1]} ({expected_from})")


def record_summary(source: dict, *, adapted: list[str] | None = None, warnings: list[str] | None = None) -> None:
    """Add to a scene's ``source`` what the import adapted (``source["adapted"]``: frames skipped,
    distortion removed, images downscaled, depth clipped or marked unknown) and what the user
    should check (``source["warnings"]``: e.g. far depth outliers), one line each. Nothing is added
    when there is nothing to say, so a scene imported as it was stored keeps its scene.json."""
    for key, lines in (("adapted", adapted), ("warnings", warnings)):
        if lines:
            source.setdefault(key, []).extend(lines)
