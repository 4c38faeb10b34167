"""Checks of method parameters (``ibr-render --param key=value`` and the method flags).

Values arrive as numbers or as the strings of ``--param``; each check converts and raises a
BadValueError that names the flag and says what was expected.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ibrtools.checks import check_int
from ibrtools.errors import BadValueError, DtypeError

# The largest value of a parameter that only has to stay finite in the kernels' float32 arithmetic
# (a length in scene units, a weight, a tolerance): 1e6 keeps products of two such values and a
# pixel coordinate (< 2^16) below float32's 3.4e38 with room to spare, and is past any value that
# changes a picture (docs/*.md parameter tables). A bound with a reason of its own says it.
FINITE_MAX = 1e6

_TRUE = {"1": True, "true": True, "yes": True, "on": True, "0": False, "false": False, "no": False, "off": False}


def with_defaults(method: str, params: dict | None, defaults: dict) -> dict:
    """``params`` over ``defaults``; an unknown key is an error listing the known ones."""
    params = dict(params or {})
    unknown = set(params) - set(defaults)
    if unknown:
        raise BadValueError(f"--param: method {method!r} has no parameter(s) {sorted(unknown)} "
                            f"(parameters: {', '.join(defaults)})")
    return {**defaults, **params}


def number(value: Any, flag: str, minimum: float | None = None, *, strict: bool = False,
           maximum: float | None = None, strict_max: bool = False) -> float:
    """A finite number, above ``minimum`` (``strict``: not equal) and below ``maximum``."""
    try:
        if isinstance(value, bool):
            raise ValueError
        f = float(value)
    except (TypeError, ValueError):
        raise BadValueError(f"{flag}: expected a number, got {value!r}") from None
    low_bad = minimum is not None and (f <= minimum if strict else f < minimum)
    high_bad = maximum is not None and (f >= maximum if strict_max else f > maximum)
    if not math.isfinite(f) or low_bad or high_bad:
        bounds = []
        if minimum is not None:
            bounds.append(f"{'>' if strict else '>='} {minimum:g}")
        if maximum is not None:
            bounds.append(f"{'<' if strict_max else '<='} {maximum:g}")
        bound = f" {' and '.join(bounds)}" if bounds else ""
        raise BadValueError(f"{flag}: expected a finite number{bound}, got {value!r}")
    return f


def integer(value: Any, flag: str, minimum: int, maximum: int | None = None) -> int:
    """An integer in [``minimum``, ``maximum``]; ``--param`` strings of digits are converted first."""
    if isinstance(value, str) and value.strip().lstrip("+-").isdigit():
        value = int(value)
    bound = f">= {minimum}" + ("" if maximum is None else f" and <= {maximum}")
    try:
        v = check_int(value, flag, minimum, maximum)
    except DtypeError:  # a parameter's value is a bad value, whatever its type
        raise BadValueError(f"{flag}: expected an integer {bound}, got {value!r}") from None
    except BadValueError:
        raise BadValueError(f"{flag}: expected an integer {bound}, got {value!r}") from None
    return v


def boolean(value: Any, flag: str) -> bool:
    if isinstance(value, str):
        value = _TRUE.get(value.strip().lower(), value)
    if isinstance(value, (bool, np.bool_)) or (isinstance(value, (int, np.integer)) and value in (0, 1)):
        return bool(value)
    raise BadValueError(f"{flag}: expected true or false, got {value!r}")


def choice(value: Any, flag: str, options: tuple[str, ...]) -> str:
    """One of ``options`` (strings), else a BadValueError naming them."""
    if isinstance(value, str) and value in options:
        return value
    names = ", ".join(repr(o) for o in options[:-1]) + f" or {options[-1]!r}"
    raise BadValueError(f"{flag}: expected {names}, got {value!r}")
