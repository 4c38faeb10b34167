"""A render job: which cameras to render (targets, held-out views, a path, a pose file),
rendering them with a method, writing the images and ``report.json`` (DESIGN.md "Contracts").

Outputs in the output directory: ``<frame>.png`` (8-bit sRGB; holes black), ``<frame>.exr``
with ``float_out``, ``<frame>.depth.exr`` with ``depth_out``, ``<frame>.mask.png`` (white =
hole) when the frame has holes (for the hybrid method: its per-pixel selection, red PVM, blue
ULR, green TM, with the holes in ``<frame>.hole.png``), and ``report.json``. Every file is written atomically and
``report.json`` last, so a reader that finds it finds every image it names.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..camera import Camera
from ..errors import BadValueError, FormatError, MissingFileError
from ..formats._common import read_json
from ..imageio import atomic_path, write_depth, write_image
from ..scene import Scene, View
from . import methods


@dataclass
class Frame:
    name: str
    camera: Camera
    truth: View | None = None  # ground truth (colour, maybe depth) when known


@dataclass
class Job:
    scene: Scene          # the inputs the method may use (held-out views removed)
    frames: list[Frame] = field(default_factory=list)


def read_poses(path: str | os.PathLike) -> list[Frame]:
    """A pose file: a JSON list of cameras in the scene.json camera format, each optionally
    with a "name" (default pose_000, pose_001, ...)."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"--poses {path}: no such file")
    doc = read_json(path)
    if isinstance(doc, dict) and "cameras" in doc:
        doc = doc["cameras"]
    if not isinstance(doc, list) or not doc:
        raise FormatError(f"--poses {path}: expected a non-empty JSON list of cameras")
    frames = []
    for i, d in enumerate(doc):
        cam = Camera.from_dict(d, f"--poses {path.name}[{i}]")
        frames.append(Frame(str(d.get("name", f"pose_{i:03d}")), cam))
    return frames


def plan(scene: Scene, *, targets: list[str] | None = None, holdout: list[str] | None = None,
         path: str | None = None, poses: str | None = None) -> Job:
    """Resolve the cameras to render. With nothing asked, render every target of the scene."""
    frames: list[Frame] = []
    held = list(dict.fromkeys(holdout or []))
    for name in held:
        v = scene.view(name)
        frames.append(Frame(v.name, v.camera, v))
    inputs = [v for v in scene.views if v.name not in set(held)]
    if held and not inputs:
        raise BadValueError("--holdout: every input view is held out; at least one must remain")
    for name in targets or []:
        t = scene.target(name)
        frames.append(Frame(t.name, t.camera, t if t.has_color else None))
    if path is not None:
        if path not in scene.paths:
            raise BadValueError(f"--path {path!r}: not in the scene (paths: {', '.join(scene.paths) or 'none'})")
        frames += [Frame(f"{path}_{i:04d}", c) for i, c in enumerate(scene.paths[path])]
    if poses is not None:
        frames += read_poses(poses)
    if not (held or targets or path or poses):
        frames = [Frame(t.name, t.camera, t if t.has_color else None) for t in scene.targets]
        if not frames:
            raise BadValueError("nothing to render: the scene has no targets; give --target, --holdout, "
                                "--path or --poses")
    names = [f.name for f in frames]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise BadValueError(f"frames: the same name is asked for twice: {dup[:5]}")
    sub = Scene(views=inputs, targets=scene.targets, paths=scene.paths, meshes=scene.meshes,
                units=scene.units, source=scene.source, lights=scene.lights, shading=scene.shading,
                stages=scene.stages, root=scene.root)
    return Job(sub, frames)


def _frame_metrics(out: dict, truth: View | None) -> dict:
    from ..metrics import compare

    if truth is None or not truth.has_color:
        hole = out.get("hole")
        return {"coverage": float(1.0 - hole.mean())} if hole is not None else {}
    m = compare(out["color"], truth.color, hole_mask=out.get("hole"),
                mask=truth.mask if truth.has_mask else None)
    # JSON has no inf: an exact match (PSNR = inf) is written as null, like an empty mask.
    return {k: (float(v) if v is not None and np.isfinite(v) else None) for k, v in m.items()}


def run(job: Job, method_name: str, out_dir: str | os.PathLike, *, params: dict | None = None,
        float_out: bool = False, depth_out: bool = False, threads: int = 0, inpaint: str = "none",
        foveate: tuple[float, float] | None = None, pooling: float | None = None,
        progress: Callable[[int, int, str], None] | None = None) -> dict:
    """Render every frame of ``job``; write images and report.json; return the report.

    ``inpaint`` ("none", "pushpull" or "metameric", :mod:`ibrtools.inpaint`) post-processes frames
    whose method returns a "hole" mask: the holes are filled (depth-aware when the method returns
    depth; metameric with seed 0, the same noise for every frame as Walton et al. 2021), the
    time is reported as stage "inpaint", the mask is still written and "psnr_holes" scores the
    filled pixels when ground truth exists. Frames without a hole are not touched (the report
    says "inpaint": "skipped: no hole").

    ``foveate`` ((x, y) fixation in [0, 1]^2, or None) post-processes every frame, after the
    inpainting, into a foveated ventral metamer (:func:`ibrtools.foveate.foveate`, seed 0 and
    ``pooling`` or its default), timed as stage "foveate"; metrics then score the metamer."""
    from .. import _core
    from ..inpaint import METHODS as INPAINT_METHODS
    from ..inpaint import NOT_BUILT as INPAINT_NOT_BUILT
    from ..inpaint import inpaint as fill_holes

    if inpaint in INPAINT_NOT_BUILT:
        from ..errors import NotBuiltError

        raise NotBuiltError(f"--inpaint {inpaint}: {INPAINT_NOT_BUILT[inpaint]} is not built yet")
    if inpaint not in INPAINT_METHODS:
        raise BadValueError(f"--inpaint: expected one of {', '.join(INPAINT_METHODS)}, got {inpaint!r}")

    fov_kw: dict = {}
    if foveate is not None:
        from ..foveate import POOLING, _check_geometry

        fov_kw = {"fixation": foveate, "pooling": POOLING if pooling is None else pooling}
        _check_geometry(fov_kw["fixation"], fov_kw["pooling"], 90.0)  # bad values fail before rendering
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise BadValueError(f"-o {out_dir}: exists and is not a directory")
    name = methods.resolve(method_name, job.scene)
    method = methods.create(name, params)
    if threads:
        _core.set_num_threads(threads)
    setup = method.prepare(job.scene)
    out_dir.mkdir(parents=True, exist_ok=True)
    frames_report = []
    for i, frame in enumerate(job.frames):
        if progress:
            progress(i, len(job.frames), frame.name)
        t0 = time.perf_counter()
        out, stage_ms = method.render(frame.camera)
        color = np.nan_to_num(out["color"], nan=0.0, posinf=0.0, neginf=0.0)
        hole = out.get("hole")
        if hole is not None:
            color = np.where(hole[..., None], 0.0, color).astype(np.float32)
        inpaint_note = None
        if inpaint != "none":
            if hole is None or not hole.any():
                inpaint_note = "skipped: no hole"  # DESIGN.md: inpainting does nothing where there is no hole
            else:
                t1 = time.perf_counter()
                color = fill_holes(np.ascontiguousarray(color, np.float32), hole, inpaint,
                                   depth=_inpaint_depth(out.get("depth"), hole))
                stage_ms = {**stage_ms, "inpaint": (time.perf_counter() - t1) * 1e3}
                inpaint_note = inpaint
        if fov_kw:
            from ..foveate import foveate as foveate_image

            t1 = time.perf_counter()
            color = foveate_image(np.ascontiguousarray(color, np.float32), fov_kw["fixation"],
                                  pooling=fov_kw["pooling"])
            stage_ms = {**stage_ms, "foveate": (time.perf_counter() - t1) * 1e3}
        total_ms = (time.perf_counter() - t0) * 1e3
        image = f"{frame.name}.png"
        write_image(out_dir / image, color)
        entry: dict = {"name": frame.name, "image": image,
                       "time_ms": {"total": round(total_ms, 3), **{k: round(v, 3) for k, v in stage_ms.items()}},
                       "metrics": _frame_metrics({**out, "color": color}, frame.truth)}
        if inpaint_note is not None:
            entry["inpaint"] = inpaint_note
            if inpaint_note == inpaint and frame.truth is not None and frame.truth.has_color:
                entry["metrics"]["psnr_holes"] = _psnr_in(color, frame.truth.color, hole)
        # Method-specific facts about the frame (dibr: the selected input views, best first,
        # their similarity, and how many candidates were skipped for not overlapping).
        if hasattr(method, "frame_report"):
            entry.update(method.frame_report())
        # Method-specific scores of the frame (depthwarp: depth PSNR/SSIM against the reference).
        if hasattr(method, "frame_metrics"):
            entry["metrics"].update(method.frame_metrics())
        if float_out:
            write_image(out_dir / f"{frame.name}.exr", color)
            entry["image_float"] = f"{frame.name}.exr"
        if depth_out and "depth" in out:
            write_depth(out_dir / f"{frame.name}.depth.exr", out["depth"])
            entry["depth"] = f"{frame.name}.depth.exr"
        selection = out.get("selection")
        if selection is not None:
            # Hybrid methods: the per-pixel method selection (RGB) is the frame's mask image
            # (render/hybrid.py); its holes, if any, go to <frame>.hole.png.
            write_image(out_dir / f"{frame.name}.mask.png", np.asarray(selection, np.float32))
            entry["mask"] = f"{frame.name}.mask.png"
            if hole is not None and hole.any():
                write_image(out_dir / f"{frame.name}.hole.png", hole.astype(np.float32))
                entry["hole_mask"] = f"{frame.name}.hole.png"
        elif hole is not None and hole.any():
            write_image(out_dir / f"{frame.name}.mask.png", hole.astype(np.float32))
            entry["mask"] = f"{frame.name}.mask.png"
        frames_report.append(entry)
    if progress:
        progress(len(job.frames), len(job.frames), "")
    report = {"method": name, "params": dict(params or {}), "inpaint": inpaint,
              **({"foveate": {"fixation": list(fov_kw["fixation"]), "pooling": fov_kw["pooling"]}} if fov_kw else {}),
              "threads": int(_core.get_num_threads()),
              "inputs": len(job.scene.views), "frames": frames_report,
              "summary": _summary(frames_report, setup)}
    with atomic_path(out_dir / "report.json") as tmp:
        tmp.write_text(json.dumps(report, indent=1, allow_nan=False))
    return report


def _inpaint_depth(depth: np.ndarray | None, hole: np.ndarray) -> np.ndarray | None:
    """The frame's depth for depth-aware push-pull (float32, C-contiguous), or None (classic) when
    the method gives none or no pixel outside the holes has a known depth."""
    if depth is None or depth.shape != hole.shape:
        return None
    depth = np.ascontiguousarray(depth, np.float32)
    known = np.isfinite(depth) & (depth > 0) & ~hole
    return depth if known.any() else None


def _psnr_in(color: np.ndarray, truth: np.ndarray, region: np.ndarray) -> float | None:
    """PSNR (sRGB, peak 1) inside the filled holes; None when not finite (JSON has no inf)."""
    from ..imageio import linear_to_srgb
    from ..metrics import psnr

    if truth.shape != color.shape:
        return None
    v = psnr(linear_to_srgb(color), linear_to_srgb(np.asarray(truth, np.float32)), 1.0, mask=region)
    return float(v) if v is not None and np.isfinite(v) else None


def _summary(frames: list[dict], setup_ms: dict) -> dict:
    s: dict = {"frames": len(frames), "setup_ms": {k: round(v, 3) for k, v in setup_ms.items()}}
    totals = [f["time_ms"]["total"] for f in frames]
    if totals:
        s["time_ms"] = {"total": round(float(np.sum(totals)), 3), "median": round(float(np.median(totals)), 3)}
    keys = sorted({k for f in frames for k, v in f["metrics"].items() if isinstance(v, (int, float))})
    for k in keys:
        vals = [f["metrics"][k] for f in frames if isinstance(f["metrics"].get(k), (int, float))
                and np.isfinite(f["metrics"][k])]
        if vals:
            s[f"mean_{k}"] = round(float(np.mean(vals)), 6)
    return s
