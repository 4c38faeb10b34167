"""Checks of scalar arguments shared by the Python front (arrays are checked in C++ by
cpp/bindings/array.h). Each raises the typed error with the argument's name."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ibrtools.errors import BadValueError, DtypeError


def check_int(value: Any, name: str, minimum: int | None = None, maximum: int | None = None) -> int:
    """An integer (a float with an integral value is accepted), at least ``minimum`` and at most
    ``maximum``."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise DtypeError(f"{name}: expected an integer, got {value!r}")
    if minimum is not None and value < minimum:
        raise BadValueError(f"{name}: expected an integer >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise BadValueError(f"{name}: expected an integer <= {maximum}, got {value}")
    return int(value)


def check_float(value: Any, name: str, minimum: float | None = None) -> float:
    """A finite number, at least ``minimum``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise DtypeError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(v):
        raise BadValueError(f"{name}: expected a finite number, got {v}")
    if minimum is not None and v < minimum:
        raise BadValueError(f"{name}: expected a finite number >= {minimum:g}, got {v}")
    return v
