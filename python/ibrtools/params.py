"""Typed method parameters (``ibr-render --param key=value``, the method flags, the Python API).

Each method's parameters are a frozen dataclass deriving from :class:`MethodParams`; each field is
declared with :func:`number`, :func:`integer`, :func:`boolean`, :func:`choice` or :func:`custom`,
which hold its default and its bounds (defined once, there). ``Cls.from_dict(mapping)`` fills in the
defaults, converts the strings of ``--param`` (``"3"``, ``"true"``), checks every field, then runs
``check()`` (the bounds that tie fields together). A bad value raises
:class:`~ibrtools.errors.ParamError`, which names the parameter; the commands reprint it under the
flag the user typed.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, ClassVar, Mapping, TypeVar

import numpy as np

from ibrtools.checks import check_int
from ibrtools.errors import InputError, ParamError

# The largest value of a parameter that only has to stay finite in the kernels' float32 arithmetic
# (a length in scene units, a weight, a tolerance): 1e6 keeps products of two such values and a
# pixel coordinate (< 2^16) below float32's 3.4e38 with room to spare, and is past any value that
# changes a picture (docs/*.md parameter tables). A bound with a reason of its own says it.
FINITE_MAX = 1e6

_TRUE = {"1": True, "true": True, "yes": True, "on": True, "0": False, "false": False, "no": False, "off": False}

Parse = Callable[[Any, str], Any]  # (value, parameter name) -> the checked value, or ParamError


def to_number(value: Any, name: str, minimum: float | None = None, *, strict: bool = False,
              maximum: float | None = None, strict_max: bool = False) -> float:
    """A finite number, above ``minimum`` (``strict``: not equal) and below ``maximum``."""
    try:
        if isinstance(value, bool):
            raise ValueError
        f = float(value)
    except (TypeError, ValueError):
        raise ParamError(name, f"expected a number, got {value!r}") from None
    low_bad = minimum is not None and (f <= minimum if strict else f < minimum)
    high_bad = maximum is not None and (f >= maximum if strict_max else f > maximum)
    if not math.isfinite(f) or low_bad or high_bad:
        bounds = []
        if minimum is not None:
            bounds.append(f"{'>' if strict else '>='} {minimum:g}")
        if maximum is not None:
            bounds.append(f"{'<' if strict_max else '<='} {maximum:g}")
        bound = f" {' and '.join(bounds)}" if bounds else ""
        raise ParamError(name, f"expected a finite number{bound}, got {value!r}")
    return f


def to_integer(value: Any, name: str, minimum: int, maximum: int | None = None) -> int:
    """An integer in [``minimum``, ``maximum``]; strings of digits (``--param``) and floats with an
    integral value are converted first."""
    if isinstance(value, str) and value.strip().lstrip("+-").isdigit():
        value = int(value)
    try:
        return check_int(value, name, minimum, maximum)
    except InputError:  # a parameter's value is a bad value, whatever its type
        bound = f">= {minimum}" + ("" if maximum is None else f" and <= {maximum}")
        raise ParamError(name, f"expected an integer {bound}, got {value!r}") from None


def to_boolean(value: Any, name: str) -> bool:
    if isinstance(value, str):
        value = _TRUE.get(value.strip().lower(), value)
    if isinstance(value, (bool, np.bool_)) or (isinstance(value, (int, np.integer)) and value in (0, 1)):
        return bool(value)
    raise ParamError(name, f"expected true or false, got {value!r}")


def to_choice(value: Any, name: str, options: tuple[str, ...]) -> str:
    """One of ``options`` (strings), else a ParamError naming them."""
    if isinstance(value, str) and value in options:
        return value
    names = ", ".join(repr(o) for o in options[:-1]) + f" or {options[-1]!r}" if len(options) > 1 else repr(options[0])
    raise ParamError(name, f"expected {names}, got {value!r}")


def custom(default: Any, parse: Parse) -> Any:
    """A field whose value ``parse(value, name)`` checks and converts (ParamError when bad)."""
    return dataclasses.field(default=default, metadata={"parse": parse})


def number(default: float | None, minimum: float | None = None, *, strict: bool = False,
           maximum: float | None = None, strict_max: bool = False, optional: bool = False) -> Any:
    """A finite-number field (``optional``: None is a value too, meaning "derive it")."""
    def parse(v: Any, name: str) -> float | None:
        if optional and v is None:
            return None
        return to_number(v, name, minimum, strict=strict, maximum=maximum, strict_max=strict_max)
    return custom(default, parse)


def integer(default: int, minimum: int, maximum: int | None = None) -> Any:
    return custom(default, lambda v, name: to_integer(v, name, minimum, maximum))


def boolean(default: bool) -> Any:
    return custom(default, to_boolean)


def choice(default: str, options: tuple[str, ...]) -> Any:
    return custom(default, lambda v, name: to_choice(v, name, options))


def same_as(params: type[MethodParams], name: str) -> Any:
    """A field declared as ``params``' field ``name`` (its default and checks), for a method whose
    parameters include another's (the hybrid passes the PVM renderer's on)."""
    f = {f.name: f for f in dataclasses.fields(params)}[name]
    return dataclasses.field(default=f.default, metadata=f.metadata)


P = TypeVar("P", bound="MethodParams")


@dataclasses.dataclass(frozen=True)
class MethodParams:
    """Base of the methods' parameter dataclasses (see the module doc)."""

    method: ClassVar[str] = ""

    @classmethod
    def from_dict(cls: type[P], params: Mapping[str, Any] | MethodParams | None = None) -> P:
        """The checked parameters: ``params`` over the defaults (an instance of ``cls`` as is)."""
        if isinstance(params, cls):
            return params
        given = dict(params.as_dict() if isinstance(params, MethodParams) else params or {})
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(given) - set(names))
        if unknown:
            raise ParamError(None, f"method {cls.method!r} has no parameter(s) {unknown} "
                                   f"(parameters: {', '.join(names) or 'none'})")
        values = {}
        for f in dataclasses.fields(cls):
            v = given.get(f.name, f.default)
            parse = f.metadata.get("parse")
            values[f.name] = parse(v, f.name) if parse is not None else v
        out = cls(**values)
        out.check()
        return out

    def check(self) -> None:
        """The bounds between fields (ParamError); each field's own bounds are checked already."""

    def as_dict(self) -> dict[str, Any]:
        """The parameters by name, in declaration order (the report's and the cache's form)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def replace(self: P, **changes: Any) -> P:
        """A checked copy with ``changes``."""
        return type(self).from_dict({**self.as_dict(), **changes})


def defaults(params: type[MethodParams]) -> dict[str, Any]:
    """The default values of a parameter class, by name."""
    return {f.name: f.default for f in dataclasses.fields(params)}
