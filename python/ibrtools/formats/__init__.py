"""Importers: each module converts one data-set convention into the native scene model.

Every importer module defines
  NAME         short name used by ``ibr-preprocess --format``
  DESCRIPTION  one line for ``--help``
  detect(path: Path) -> bool      True when ``path`` looks like this format
  load(path: Path, options: dict) -> Scene
and states, in its docstring, the convention it converts from. An importer of video data sets
also defines
  frame_range(path: Path, options: dict) -> (frames held, frames rendered by default)
and reads the frame given by its ``frame`` option (:func:`load_frames`).
"""
from __future__ import annotations

import importlib
from pathlib import Path

from ibrtools.errors import BadValueError, FormatError, MissingFileError
from ibrtools.scene import Scene, View
from ibrtools.formats.resize import check_factors, downscale_scene

# Order matters for detection: the most specific formats first.
# llff after colmap: an LLFF folder that also holds its COLMAP model (sparse/0) imports as COLMAP
# (distortion, the principal point as estimated) unless --format llff is given.
IMPORTERS = ("native", "mpeg", "nerf", "colmap", "llff", "middlebury", "rgbd")


def importer(name: str):
    if name not in IMPORTERS:
        raise FormatError.about("format", f"unknown format {name!r} (expected one of {', '.join(IMPORTERS)})")
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
                      "or name the format)")


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


def parse_frames(spec: str) -> tuple[int | None, int | None] | None:
    """A data set's frame selection: "A:B" (frames A to B - 1, as a Python slice), "A:" (A to the
    last), ":B", "all" (every frame), "default" (the data set's own, e.g. an RVS config's
    ``StartFrame`` and ``NumberOfFrames``: returns None). BadValueError naming ``frames``."""
    text = str(spec).strip()
    if text == "default":
        return None
    if text == "all":
        return (0, None)
    a, sep, b = text.partition(":")
    try:
        first = int(a) if a.strip() else 0
        stop = int(b) if b.strip() else None
    except ValueError:
        first = stop = -1
    if not sep or first < 0 or (stop is not None and stop <= first):
        raise BadValueError.about("frames", "expected A:B (frames A to B - 1, 0 <= A < B), A:, :B, all or default",
                                  spec)
    return first, stop


def load_frames(path: str | Path, fmt: str | None = None, options: dict | None = None, *,
                frames: str = "default", downscale: float | None = None,
                max_size: int | None = None) -> tuple[Scene, dict[str, Scene]]:
    """Import frames ``frames`` (:func:`parse_frames`) of a video data set as the parts of a video
    scene (docs/FORMAT.md "Frames"): the shared scene (the first frame's targets' cameras, paths,
    units and source) and frame name "f<index>" -> that frame's still scene (:func:`load` with
    the importer's ``frame`` option; images are decoded when used). Formats without frames, a
    frame out of the data set and a ``frame`` option beside ``frames`` are BadValueErrors."""
    path = Path(path)
    downscale, max_size = check_factors(downscale, max_size)
    selection = parse_frames(frames)
    if not path.exists():
        raise MissingFileError(f"{path}: no such file or directory")
    name = fmt or detect(path)
    module = importer(name)
    if not hasattr(module, "frame_range"):
        raise BadValueError.about("frames", f"the {name} format has one frame per view (video data sets: mpeg)")
    options = dict(options or {})
    if "frame" in options:
        raise BadValueError.about("frames", "not with the importer's option frame= (give the frames to import "
                                            "as frames A:B)")
    held, default = module.frame_range(path, options)
    if selection is None:
        chosen = default
    else:
        chosen = range(selection[0], held if selection[1] is None else selection[1])
    if not chosen or chosen.stop > held:
        raise BadValueError.about("frames", f"frames {chosen.start}..{chosen.stop - 1} asked for, "
                                            f"{path} has {held} frame(s) (0..{held - 1})", frames)
    width = max(3, len(str(chosen.stop - 1)))
    scenes = {f"f{i:0{width}d}": load(path, name, {**options, "frame": i}, downscale=downscale, max_size=max_size)
              for i in chosen}
    first = next(iter(scenes.values()))
    source = {**first.source, "frames": [chosen.start, chosen.stop]}
    video = Scene(targets=[View.create(t.name, t.camera) for t in first.targets], paths=first.paths,
                  units=first.units, source=source)
    return video, scenes
