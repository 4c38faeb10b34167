"""The ``import`` stage: read a data set (or make a synthetic one), validate it, write the native
scene with its import record (docs/preprocess.md, docs/importers.md). The derived stages after it
are :mod:`ibrtools.pipeline.stages`.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ibrtools.cache import StageResult, existing_record, hash_inputs
from ibrtools.dibr.view_selection import outlier_limits
from ibrtools.errors import BadValueError
from ibrtools.formats import load as load_dataset, load_frames, native, parse_frames
from ibrtools.formats._common import record_summary
from ibrtools.formats.resize import check_factors
from ibrtools.scene import Scene


# Bump when the import code changes what it writes, so that old scenes are rebuilt.
IMPORT_STAGE_VERSION = 2  # 2: the background at infinity (depth +inf) of synthetic and nerf scenes


def _no_video_holdout() -> BadValueError:
    return BadValueError.about("holdout", "not for a video scene (a render job's holdout removes views from "
                                          "a render: ibr-render --holdout)")


def run_import(input_spec: str, output: Path, *, fmt: str | None = None, options: dict | None = None,
               synth: dict | None = None, force: bool = False, holdout: list[str] | None = None,
               mesh: str | os.PathLike | None = None, downscale: float | None = None,
               max_size: int | None = None, frames: str | None = None) -> StageResult:
    """The ``import`` stage: read a data set (or make a synthetic one), validate it, write the
    native scene. Up to date when ``output`` holds a scene made from the same input bytes and
    parameters. ``holdout``: input views imported as targets (ground truth no stage reads), so
    that ``ibr-render SCENE`` scores them as unseen views (:func:`hold_out`). ``mesh``: a PLY/OBJ
    in the capture's frame, imported as the scene's ``reconstructed`` mesh (the mesh stage then
    uses it, and the depth stage renders it for the views without depth; no multi-view stereo).
    ``downscale`` / ``max_size``: every view resized on import (``formats.resize``; data sets only:
    a synthetic scene is made at its ``--size``). ``frames``: the frames of a video data set
    imported as a video scene (``formats.load_frames``: "A:B", "all", "default"). The import's summary (``source["adapted"]`` and
    ``source["warnings"]``, what the importer adapted) is in the result's details."""
    options = dict(options or {})
    output = Path(output)
    held = list(dict.fromkeys(holdout or []))
    src = Path(input_spec)
    downscale, max_size = check_factors(downscale, max_size)
    if synth is not None and (downscale is not None or max_size is not None):
        raise BadValueError.about("downscale" if downscale is not None else "max_size",
                                  "for data sets only (a synthetic scene is made at its own size)")
    if synth is not None:
        params: dict = {"synth": synth, "version": IMPORT_STAGE_VERSION}
    else:
        if src.resolve() == output.resolve():
            # A native scene preprocessed in place (`ibr-preprocess SCENE -o SCENE --stages ...`,
            # what the renderers' error messages suggest): nothing to import.
            if not (output / "scene.json").is_file():
                raise BadValueError.about("output", "output is the input and it holds no native scene "
                                                    "(scene.json); choose another directory", str(output))
            if held or mesh is not None:
                raise BadValueError.about("holdout" if held else "mesh",
                                          "only when importing a data set (the input is the scene itself; "
                                          "import the data set again into another directory)")
            record = existing_record(output, "import") or {}
            return StageResult("import", "up to date", "the input is the scene itself (preprocessed in place)", 0.0,
                               {k: record[k] for k in ("views", "targets") if k in record})
        params = {"format": fmt, "options": options, "version": IMPORT_STAGE_VERSION}
    if held:  # only then: the import key of scenes without held-out views is unchanged
        params["holdout"] = held
    if downscale is not None:  # likewise
        params["downscale"] = downscale
    if max_size is not None:
        params["max_size"] = max_size
    if frames is not None:
        if synth is not None:
            raise BadValueError.about("frames", "A:B is for video data sets (a synthetic video is made with "
                                                "its number of frames: ibr-preprocess synth:NAME --frames N)")
        parse_frames(frames)  # a bad value fails before any file is read
        if held or mesh is not None:
            raise (_no_video_holdout() if held else
                   BadValueError.about("mesh", "not for a video scene (one mesh per frame)"))
        params["frames"] = frames
    user_mesh = None
    if mesh is not None:  # only then, likewise; the mesh's bytes enter the key
        from ibrtools.meshio import read_mesh

        user_mesh = read_mesh(mesh, kind="reconstructed")
        if len(user_mesh.faces) == 0:
            raise BadValueError.about("mesh", "the mesh has no faces", str(mesh))
        params["mesh"] = hash_inputs(Path(mesh), {})
    key = (hashlib.blake2b(json.dumps(params, sort_keys=True).encode(), digest_size=16).hexdigest()
           if synth is not None else hash_inputs(src, params))
    record = existing_record(output, "import")
    if not force and record and record.get("key") == key:
        return StageResult("import", "up to date", "inputs and parameters unchanged", 0.0,
                           {"views": record.get("views"), "targets": record.get("targets")})
    t0 = time.perf_counter()
    video = None
    if synth is not None and synth.get("frames", 1) > 1:  # a synthetic video (docs/FORMAT.md "Frames")
        from ibrtools.synth import make_video

        if held:
            raise _no_video_holdout()
        video, scenes = make_video(**synth)
        fmt_used = f"synth:{synth['preset']}"
    elif frames is not None:  # a video data set: its frames, each a still scene
        video, scenes = load_frames(src, fmt, options, frames=frames, downscale=downscale, max_size=max_size)
        fmt_used = video.source.get("format", fmt)
        first_name, first = next(iter(scenes.items()))
        warning = depth_outlier_warning(first.views + first.targets)
        if warning:
            record_summary(video.source, warnings=[f"frame {first_name}: {warning}"])
    if video is not None:
        n_views = len(next(iter(scenes.values())).views)
        video.stages["import"] = {"key": key, "format": fmt_used, "frames": len(scenes), "views": n_views,
                                  "targets": len(video.targets), "seconds": round(time.perf_counter() - t0, 4)}
        native.save_video(video, scenes, output)
        seconds = time.perf_counter() - t0
        reason = "forced" if force else ("inputs changed" if record else "no scene yet")
        details: dict = {"frames": len(scenes), "views": n_views, "targets": len(video.targets)}
        for k in ("adapted", "warnings"):
            if video.source.get(k):
                details[k] = list(video.source[k])
        return StageResult("import", "ran", f"{reason}; {fmt_used}, {len(scenes)} frames", seconds, details)
    if synth is not None:
        from ibrtools.synth import make_scene

        scene: Scene = make_scene(**synth)
        fmt_used = f"synth:{synth['preset']}"
    else:
        scene = load_dataset(Path(input_spec), fmt, options, downscale=downscale, max_size=max_size)
        fmt_used = scene.source.get("format", fmt)
    if synth is None:  # robust depth statistics of the data set's views (synthetic depth is exact)
        warning = depth_outlier_warning(scene.views + scene.targets)
        if warning:
            record_summary(scene.source, warnings=[warning])
    if held:
        scene = hold_out(scene, held)
    if user_mesh is not None:
        scene.meshes["reconstructed"] = user_mesh
    n_views, n_targets = len(scene.views), len(scene.targets)
    scene.stages["import"] = {"key": key, "format": fmt_used, "views": n_views, "targets": n_targets,
                              **({"held_out": held} if held else {}),
                              "seconds": round(time.perf_counter() - t0, 4)}
    native.save(scene, output)
    seconds = time.perf_counter() - t0
    reason = "forced" if force else ("inputs changed" if record else "no scene yet")
    details = {"views": n_views, "targets": n_targets}
    for k in ("adapted", "warnings"):
        if scene.source.get(k):
            details[k] = list(scene.source[k])
    return StageResult("import", "ran", f"{reason}; {fmt_used}", seconds, details)


# A view's depth "has far outliers" when at least this share of its valid pixels lies beyond the
# view-selection outlier limit. 0.05 %: 7-Scenes' invalid codes are percents of a frame (0.1 % at
# 65.5 m made a frustum 20x deeper); Middlebury's ground truth has 3-12 stray pixels of quarter-pixel
# disparity per view (at most 0.0074 %, Cones), real and harmless once view selection drops them.
FAR_OUTLIER_SHARE = 5e-4


def depth_outlier_warning(views) -> str | None:
    """One line naming the views whose depth has far outliers (at least ``FAR_OUTLIER_SHARE`` of
    the valid values above twice the 99th percentile: ``render.view_selection.outlier_limits``, the
    rule view selection leaves them out by), or None. A sensor's invalid code read as depth (7-Scenes' 65535 mm = 65.5 m in a 3 m room)
    is the usual cause: the user learns it at import, with the options that mark it unknown."""
    hits = []  # (share of the view's valid pixels, name, largest value, the limit)
    n = 0
    for v in views:
        if not v.has_depth or v.camera.model != "pinhole":
            continue
        n += 1
        d = v.depth
        valid = d[np.isfinite(d) & (d > 0)]
        if valid.size == 0:
            continue
        high = outlier_limits(valid)[1]
        far = int(np.count_nonzero(valid > high))
        if far and far >= FAR_OUTLIER_SHARE * valid.size:
            hits.append((far / valid.size, v.name, float(valid.max()), high / 2))
    if not hits:
        return None
    share, name, top, p99 = max(hits)
    return (f"depth outliers in {len(hits)} of {n} views (worst: {name}, {100 * share:.2g} % of its depth beyond "
            f"twice its 99th percentile {p99:.4g}, up to {top:.4g}); view selection leaves them out; if they are "
            "a sensor's invalid code, mark it unknown (the rgbd importer's option invalid_depth=V or max_depth=M)")


def hold_out(scene: Scene, names: list[str]) -> Scene:
    """``scene`` with the input views ``names`` moved to its targets (their colour and depth the
    ground truth): no preprocessing stage reads targets, so a method scored on them sees unseen
    views (``ibr-render --holdout`` instead removes views from one render, after the stages ran on
    them). Names must be input views, not all of them, and not names of existing targets."""
    if scene.frames:
        raise _no_video_holdout()
    have = {v.name for v in scene.views}
    missing = [n for n in names if n not in have]
    if missing:
        shown = ", ".join(sorted(have)[:8]) + (", ..." if len(have) > 8 else "")
        raise BadValueError.about("holdout", f"no input view named {', '.join(missing)} (views: {shown})")
    if len(set(names)) >= len(scene.views):
        raise BadValueError.about("holdout", "every input view is held out; at least one must remain")
    clash = sorted(set(names) & {t.name for t in scene.targets})
    if clash:
        raise BadValueError.about("holdout", f"the scene already has targets named {', '.join(clash)}")
    keep = set(names)
    return replace(scene, views=[v for v in scene.views if v.name not in keep],
                   targets=[*scene.targets, *[v for v in scene.views if v.name in keep]])
