"""An RVS synthesis config rendered as RVS renders it, in one call (docs/render.md "RVS configs").

:func:`prepare` imports the config's input frames (``StartFrame``, ``NumberOfFrames``) into a
scene beside the outputs, runs the stages the method needs, and returns what the render job takes
from the config: the virtual cameras to render (the scene's targets) and one YUV 4:2:0 file per
virtual camera, named by ``OutputFiles``, at its camera's ``BitDepthColor``
(:class:`ibrtools.pipeline.job.YuvSink`).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ibrtools.cache import StageResult
from ibrtools.errors import BadValueError
from ibrtools.formats import mpeg
from ibrtools.outputs import is_plain_name

# The imported scene's directory inside the output directory.
SCENE_DIR = "scene"


@dataclass
class RvsRun:
    scene_dir: Path
    yuv: dict[str, Path]  # virtual camera -> the YUV file written
    yuv_bits: dict[str, int]  # virtual camera -> bits per sample
    params: dict  # method parameters the config sets (BlendingFactor -> blend_exponent)
    stages: list[StageResult] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # what the config asks for that is not written


def is_config(path: str | os.PathLike) -> bool:
    """True when ``path`` is an RVS synthesis config file (not a scene directory)."""
    return mpeg.is_config(Path(path))


def prepare(config: str | os.PathLike, out_dir: str | os.PathLike, method: str = "auto", *,
            force: bool = False, progress: Callable[[str], None] | None = None) -> RvsRun:
    """Import RVS config ``config`` (its frames as a video scene when NumberOfFrames > 1) into
    ``out_dir``/scene (up to date on a second run) and preprocess it for ``method``; the YUV
    outputs are ``out_dir``/<the file name of each OutputFiles entry>. An OutputFiles entry
    that is not a .yuv file is written as the frames' PNGs only (said in ``notes``)."""
    from ibrtools.pipeline.stages import preprocess

    config, out_dir = Path(config), Path(out_dir)
    info = mpeg.config_outputs(config)
    yuv: dict[str, Path] = {}
    bits: dict[str, int] = {}
    notes: list[str] = []
    for camera, (name, b) in info["files"].items():
        file = Path(name).name
        if not is_plain_name(file) or file == SCENE_DIR:
            raise BadValueError(f"{config}: OutputFiles entry {name!r} is not a file name")
        if Path(file).suffix.lower() != ".yuv":
            notes.append(f"{camera}: OutputFiles {name!r} is not .yuv; its frames are the PNGs <frame>_{camera}.png")
            continue
        yuv[camera], bits[camera] = out_dir / file, b
    if len(set(yuv.values())) != len(yuv):
        raise BadValueError(f"{config}: two OutputFiles entries have the same file name")
    if info["ignored"]:
        notes.append(f"not written: {', '.join(info['ignored'])}")
    n = len(info["frames"])
    frames = None if n == 1 else f"{info['frames'].start}:{info['frames'].stop}"
    options = {} if n > 1 else {"frame": info["frames"].start}
    scene_dir = out_dir / SCENE_DIR
    out_dir.mkdir(parents=True, exist_ok=True)
    methods = None if method == "auto" else [method]
    stages = preprocess(str(config), scene_dir, fmt="mpeg", options=options, force=force, methods=methods,
                        progress=progress, frames=frames)
    params = {}
    if info["blending_factor"] is not None and method in ("auto", "dibr"):
        params["blend_exponent"] = info["blending_factor"]
    return RvsRun(scene_dir, yuv, bits, params, stages, notes)
