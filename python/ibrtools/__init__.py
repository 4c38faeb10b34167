"""ibrtools: image-based rendering and view synthesis on the CPU.

Layers (none calls upwards): cli -> ibrtools (Python) -> ibrtools._core (pybind11) -> cpp/kernels -> cpp/ibr
(README "Architecture").

The names most programs need are here (docs/api.md):

>>> import ibrtools
>>> cam = ibrtools.Camera.from_fov(640, 480, 60.0, ibrtools.look_at((0, 1, 5), (0, 0, 0)))
>>> cam
Camera(pinhole 640x480, f=(554.26, 554.26), c=(320.00, 240.00), centre=(0.000, 1.000, 5.000))
>>> issubclass(ibrtools.FormatError, ibrtools.InputError)   # every bad input is an InputError
True

``load_scene``, ``RenderResult`` and the sub-modules (``synth``, ``formats``, ``metrics``, ...)
are imported on first use, so that ``import ibrtools`` stays fast (it loads numpy, not the
C++ engine nor open3d).
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ibrtools.camera import Camera, look_at
from ibrtools.errors import (BadValueError, DtypeError, FormatError, IbrError, InputError, InternalError,
                     MissingFileError, NotBuiltError, ShapeError)
from ibrtools.mesh import Mesh
from ibrtools.scene import Scene, View

if TYPE_CHECKING:  # the lazy names below, for type checkers
    from ibrtools import formats, imageio, metrics, synth
    from ibrtools.api import (CameraLike, RenderResult, bench, clear_render_cache, import_dataset, load_scene,
                              preprocess, render, render_job, save_scene)

__version__ = "0.1.0"

__all__ = [
    "Camera", "look_at", "Mesh", "Scene", "View",
    "load_scene", "save_scene", "import_dataset", "preprocess", "render", "render_job", "bench", "RenderResult", "CameraLike", "clear_render_cache",
    "IbrError", "InputError", "ShapeError", "DtypeError", "BadValueError", "MissingFileError",
    "FormatError", "NotBuiltError", "InternalError",
]

# name -> module that defines it (imported on first access, PEP 562).
_LAZY = {name: "api" for name in ("load_scene", "save_scene", "import_dataset", "preprocess", "render", "render_job",
                                   "bench", "RenderResult", "CameraLike", "clear_render_cache")}
_LAZY_MODULES = ("formats", "imageio", "metrics", "synth")


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    elif name in _LAZY_MODULES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module 'ibrtools' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY) | set(_LAZY_MODULES))
