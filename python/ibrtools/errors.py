"""Typed errors of ibrtools.

Bad input is an :class:`InputError` (a ``ValueError``): the commands print its one-line
message and exit with status 2. Each kind of bad input has its own class so that callers
(and tests) can tell them apart. Everything else is an internal error (exit status 1).
"""
from __future__ import annotations


class IbrError(Exception):
    """Base of every error ibrtools raises on purpose."""


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
