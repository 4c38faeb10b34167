"""Typed errors of ibrtools.

Bad input is an :class:`InputError` (a ``ValueError``): the commands print its one-line
message and exit with status 2. Each kind of bad input has its own class so that callers
(and tests) can tell them apart. Everything else is an internal error (exit status 1).
"""
from __future__ import annotations

from typing import TypeVar

_E = TypeVar("_E", bound="IbrError")


class IbrError(Exception):
    """Base of every error ibrtools raises on purpose.

    An error about an argument of a public function is made by :meth:`about`, which keeps the
    argument's keyword apart from the message, so that the commands can name the flag that sets
    it instead (``--max-size`` for ``max_size``); the library itself never spells a flag."""

    argument: tuple[str, ...] = ()  # the argument(s) at fault, by their keywords (() = none)
    value: object = None            # the value given, shown after the name (None: not shown)
    detail: str = ""                # what was expected

    @classmethod
    def about(cls: type[_E], argument: str | tuple[str, ...], detail: str, value: object = None) -> _E:
        """The error ``ARGUMENT: DETAIL`` (``ARGUMENT 'VALUE': DETAIL`` when ``value`` is given;
        several arguments are joined by ``/``)."""
        names = (argument,) if isinstance(argument, str) else tuple(argument)
        e = cls(f"{'/'.join(names)}{'' if value is None else f' {value!r}'}: {detail}")
        e.argument, e.value, e.detail = names, value, detail
        return e

    def __reduce__(self):
        # Rebuilt from the message and the instance's attributes (Dask returns a worker's errors
        # pickled, through tblib). Our own reducer: tblib's rebuilds an exception whose __init__
        # is not BaseException's with __new__ alone, which the classes that are also an OSError
        # (MissingFileError) refuse.
        return (type(self), self.args, self.__dict__ or None)


class InputError(IbrError, ValueError):
    """Bad input: the message names the file or argument and what was expected."""


class ShapeError(InputError):
    """An array has the wrong number of dimensions, sizes or memory layout."""


class DtypeError(InputError, TypeError):
    """An array (or value) has the wrong type."""


class BadValueError(InputError):
    """A value is out of its valid range (NaN depth, zero focal length, non-rigid pose, ...)."""


class MissingFileError(InputError, FileNotFoundError):
    """A file or directory that the input names does not exist."""


class FormatError(InputError):
    """A file or directory is in an unknown format, or is malformed."""


class NotBuiltError(IbrError):
    """A documented feature that is not built yet (exit status 2, like bad usage)."""


class InternalError(IbrError, RuntimeError):
    """A bug or a failure of a library underneath; not the user's input."""


class ParamError(BadValueError):
    """A method parameter has a bad value (or is not a parameter of the method).

    ``param`` names it (None: the key itself is unknown) and ``detail`` says what was expected;
    the message is "parameter PARAM: DETAIL". The commands reprint it under the flag the user
    typed (``--blend-exponent``, ``--param k``), which the library does not know."""

    def __init__(self, param: str | None, detail: str):
        self.param, self.detail = param, detail
        super().__init__(detail if param is None else f"parameter {param}: {detail}")

    def __reduce__(self):  # pickled as its two parts (Dask workers raise it in another process)
        return (type(self), (self.param, self.detail))
