"""ibrtools: image-based rendering and view synthesis on the CPU.

Layers (DESIGN.md): cli -> ibrtools (Python) -> ibrtools._core (pybind11) -> cpp/ibr -> cpp/kernels.
"""
from __future__ import annotations

from .camera import Camera, look_at
from .errors import (BadValueError, DtypeError, FormatError, IbrError, InputError, InternalError,
                     MissingFileError, NotBuiltError, ShapeError)
from .mesh import Mesh
from .scene import Scene, View

__version__ = "0.1.0"

__all__ = [
    "Camera", "look_at", "Mesh", "Scene", "View",
    "IbrError", "InputError", "ShapeError", "DtypeError", "BadValueError", "MissingFileError",
    "FormatError", "NotBuiltError", "InternalError",
]
