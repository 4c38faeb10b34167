"""Importers: each module converts one data-set convention into the native scene model.

Every importer module defines
  NAME         short name used by ``ibr-preprocess --format``
  DESCRIPTION  one line for ``--help``
  detect(path: Path) -> bool      True when ``path`` looks like this format
  load(path: Path, options: dict) -> Scene
and states, in its docstring, the convention it converts from.
"""
from __future__ import annotations

import importlib
from pathlib import Path

from ibrtools.errors import FormatError, MissingFileError
from ibrtools.scene import Scene
from ibrtools.formats.resize import check_factors, downscale_scene

# Order matters for detection: the most specific formats first.
# llff after colmap: an LLFF folder that also holds its COLMAP model (sparse/0) imports as COLMAP
# (distortion, the principal point as estimated) unless --format llff is given.
IMPORTERS = ("native", "mpeg", "nerf", "colmap", "llff", "middlebury", "rgbd")


def importer(name: str):
    if name not in IMPORTERS:
        raise FormatError(f"--format: unknown format {name!r} (expected one of {', '.join(IMPORTERS)})")
    return importlib.import_module(f"{__name__}.{name}")


def detect(path: Path) -> str:
    """Name of the format of ``path`` (a file or directory)."""
    path = Path(path)
    if not path.exists():
        raise MissingFileError(f"{path}: no such file or directory")
    for name in IMPORTERS:
        if importer(name).detect(path):
            return name
    raise FormatError(f"{path}: unknown data-set format (expected one of: {', '.join(IMPORTERS)}; "
                      "or pass --format)")


def load(path: str | Path, fmt: str | None = None, options: dict | None = None, *,
         downscale: float | None = None, max_size: int | None = None) -> Scene:
    """Import a data set (format detected unless given) as a Scene; ``downscale`` (a factor >= 1)
    / ``max_size`` (the longer side, pixels) resize every view on the way in (formats/resize.py,
    whatever the importer)."""
    path = Path(path)
    downscale, max_size = check_factors(downscale, max_size)  # before any file is read
    if not path.exists():
        raise MissingFileError(f"{path}: no such file or directory")
    name = fmt or detect(path)
    scene = importer(name).load(path, dict(options or {}))
    scene.source.setdefault("format", name)
    scene.source.setdefault("path", str(path))
    if downscale is not None or max_size is not None:
        scene = downscale_scene(scene, downscale, max_size)
    scene.validate()
    return scene
