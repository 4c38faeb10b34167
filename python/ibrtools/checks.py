"""Checks of scalar arguments shared by the Python front (arrays are checked in C++ by
cpp/bindings/array.h). Each raises the typed error with the argument's name."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ibrtools.errors import BadValueError, DtypeError, InputError, ShapeError


def _error(cls: type[InputError], name: str, detail: str, argument: bool) -> InputError:
    """``NAME: DETAIL``; with ``argument``, an error about the public argument ``name``
    (:meth:`ibrtools.errors.IbrError.about`: the commands name its flag)."""
    return cls.about(name, detail) if argument else cls(f"{name}: {detail}")


def check_int(value: Any, name: str, minimum: int | None = None, maximum: int | None = None, *,
              argument: bool = False) -> int:
    """An integer (a float with an integral value is accepted), at least ``minimum`` and at most
    ``maximum``. ``argument``: ``name`` is the keyword of a public function's argument."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise _error(DtypeError, name, f"expected an integer, got {value!r}", argument)
    if minimum is not None and value < minimum:
        raise _error(BadValueError, name, f"expected an integer >= {minimum}, got {value}", argument)
    if maximum is not None and value > maximum:
        raise _error(BadValueError, name, f"expected an integer <= {maximum}, got {value}", argument)
    return int(value)


def check_float(value: Any, name: str, minimum: float | None = None, *, argument: bool = False) -> float:
    """A finite number, at least ``minimum``. ``argument``: as :func:`check_int`."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise _error(DtypeError, name, f"expected a number, got {value!r}", argument) from None
    if not math.isfinite(v):
        raise _error(BadValueError, name, f"expected a finite number, got {v}", argument)
    if minimum is not None and v < minimum:
        raise _error(BadValueError, name, f"expected a finite number >= {minimum:g}, got {v}", argument)
    return v


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
