"""Planning a render job: the cameras to render (targets, held-out views, camera paths, pose
files, light fields; every scene frame of a video), their output names, the notes on held-out
and out-of-date inputs, and the memory a job will need, checked before anything is allocated.
:mod:`ibrtools.pipeline.job` runs the plan (docs/render.md)."""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from ibrtools.cache import STAGES, stale_reasons
from ibrtools.camera import Camera
from ibrtools.errors import BadValueError
from ibrtools.formats import poses
from ibrtools.memory import available_memory
from ibrtools.outputs import file_stem, is_plain_name
from ibrtools.paths import GENERATED, camera_path
from ibrtools.scene import Scene, View


@dataclass
class Frame:
    name: str
    camera: Camera
    truth: View | None = None  # ground truth (colour, maybe depth) when known
    info: dict = field(default_factory=dict)  # facts copied into the frame's report entry (light field: row, col)
    scene_frame: str | None = None  # video scenes: the frame of the scene it renders (Job.scenes)

    @property
    def stem(self) -> str:
        """The stem of the frame's file names: its name made one plain path component
        (ibrtools.outputs.file_stem: "train/r_0" -> "train_r_0", "../x" -> "_._x")."""
        return file_stem(self.name)

    @property
    def camera_name(self) -> str:
        """The camera the frame renders: its name without a video's "<scene frame>_" prefix."""
        if self.scene_frame is not None and self.name.startswith(self.scene_frame + "_"):
            return self.name[len(self.scene_frame) + 1:]
        return self.name


# The files a frame may write: <stem><suffix> (render_frame), and the keys of its report entry
# that name them.
FRAME_SUFFIXES = (".png", ".exr", ".depth.exr", ".method.png", ".hole.png")


FRAME_FILE_KEYS = ("image", "image_float", "depth", "method_mask", "hole_mask")


def report_files(report: Path) -> set[str]:
    """The files an earlier run's report.json names (its frames' images, masks, depth)."""
    try:
        doc = json.loads(report.read_text())
    except (OSError, ValueError):
        return set()
    frames = doc.get("frames", []) if isinstance(doc, dict) else []
    return {v for f in frames if isinstance(f, dict) for k in FRAME_FILE_KEYS
            for v in [f.get(k)] if isinstance(v, str) and is_plain_name(v)}


@dataclass
class Job:
    scene: Scene          # the inputs the method may use (held-out views removed)
    frames: list[Frame] = field(default_factory=list)
    # plan()'s keyword arguments (JSON-able): plan(native.load(scene.root), **spec) makes the same
    # job again, which is how Dask workers rebuild it (ibrtools.pipeline.distributed). None: not planned.
    spec: dict | None = None
    # Video scenes: every scene frame's inputs by frame name (``scene`` is the first's); None
    # for a still scene.
    scenes: dict[str, Scene] | None = None
    # The input views plan(holdout=) took out of the scene (rendered as frames with ground truth).
    held_out: list[str] = field(default_factory=list)


def _plan_video(scene: Scene, args: dict, spec: dict | None) -> Job:
    """plan() of a video scene: each scene frame planned as a still scene with the same arguments."""
    frames: list[Frame] = []
    scenes: dict[str, Scene] = {}
    for fr in scene.frames:
        sub = plan(scene.frame(fr), **args)
        scenes[fr] = sub.scene
        frames += [Frame(f"{fr}_{f.name}", f.camera, f.truth, {"frame": fr, **f.info}, scene_frame=fr)
                   for f in sub.frames]
    return Job(scenes[scene.frames[0]], frames, spec, scenes, held_out=sub.held_out)


def read_poses(path: str | os.PathLike) -> list[Frame]:
    """A pose file (ibrtools.formats.poses: a JSON list of cameras in the scene.json camera
    format, each optionally with a "name", default pose_000, pose_001, ...; a nerfstudio
    camera_path.json; a transforms.json)."""
    return [Frame(name, cam) for name, cam in poses.load(path)]


def plan(scene: Scene, *, targets: list[str] | None = None, holdout: list[str] | None = None,
         path: str | None = None, path_frames: int | None = None, poses: str | None = None,
         lightfield: tuple[int, int, float, str | None] | None = None) -> Job:
    """Resolve the cameras to render. With nothing asked, render every target of the scene.
    ``path``: a path stored in the scene, else a generated one (ibrtools.paths: interpolate,
    spiral, orbit) of ``path_frames`` cameras (default ibrtools.paths.DEFAULT_FRAMES); frames
    <path>_0000, ... ``lightfield`` = (columns, rows, baseline, centre name or None): a camera grid
    (:mod:`ibrtools.pipeline.batches`), frames lf_0000, ... row-major.

    The job records these keyword arguments as ``job.spec`` (every one of them, whatever is
    added later; a relative ``poses`` path made absolute) for the workers of a distributed run.

    A video scene (``scene.frames``; docs/FORMAT.md "Frames"): the cameras are resolved in
    every scene frame alike and the job renders each of them at every frame, frame-major; job
    frames are named ``<frame>_<camera>`` (e.g. f001_t000) with "frame" in their report entry."""
    args = {k: v for k, v in locals().items() if k != "scene"}
    if poses is not None:
        args["poses"] = str(Path(poses).resolve())
    spec = dict(args)
    try:
        spec = json.loads(json.dumps(spec))  # tuples to lists: what travels
    except (TypeError, ValueError):
        spec = None  # not JSON-able (an argument given as an object): a local run only
    if scene.frames:
        return _plan_video(scene, args, spec)
    frames: list[Frame] = []
    held = list(dict.fromkeys(holdout or []))
    for name in held:
        v = scene.view(name)
        frames.append(Frame(v.name, v.camera, v))
    inputs = [v for v in scene.views if v.name not in set(held)]
    if held and not inputs:
        raise BadValueError.about("holdout", "every input view is held out; at least one must remain")
    for name in targets or []:
        t = scene.target(name)
        frames.append(Frame(t.name, t.camera, t if t.has_color else None))
    if path is not None:
        # generated from every view of the scene, held out or not: the same path whatever --holdout
        frames += [Frame(f"{path}_{i:04d}", c) for i, c in enumerate(camera_path(scene, path, path_frames))]
    elif path_frames is not None:
        raise BadValueError.about("path_frames", f"only with a path (a generated path: {', '.join(GENERATED)})")
    if poses is not None:
        frames += read_poses(poses)
    if lightfield is not None:
        from ibrtools.pipeline.batches import lightfield_cameras

        _, grid = lightfield_cameras(scene, *lightfield)
        frames += [Frame(n, c, info={"row": r, "col": k}) for n, r, k, c in grid]
    if not (held or targets or path or poses or lightfield):
        frames = [Frame(t.name, t.camera, t if t.has_color else None) for t in scene.targets]
        if not frames:
            raise BadValueError.about(("targets", "holdout", "path", "poses"),
                                      "nothing to render: the scene has no targets; give one of these")
    names = [f.name for f in frames]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise BadValueError(f"frames: the same name is asked for twice: {dup[:5]}")
    check_file_names(frames)
    sub = Scene(views=inputs, targets=scene.targets, paths=scene.paths, meshes=scene.meshes,
                units=scene.units, source=scene.source, lights=scene.lights, shading=scene.shading,
                stages=scene.stages, root=scene.root)
    return Job(sub, frames, spec, held_out=held)


def check_file_names(frames: list[Frame]) -> None:
    """Refuse frames whose output files would be the same file (``a`` and ``a.mask`` both
    write a.mask.png; ``x/y`` and ``x_y`` both map to x_y.png), naming both."""
    owner: dict[str, str] = {}
    for f in frames:
        for suffix in FRAME_SUFFIXES:
            file = f.stem + suffix
            other = owner.setdefault(file, f.name)
            if other != f.name:
                raise BadValueError(f"frames {other!r} and {f.name!r} would both write {file}: rename one "
                                    "(names become file names: path separators and a leading dot are replaced by _)")


def renamed_frames(frames: list[Frame]) -> dict[str, str]:
    """{name: file stem} of the frames whose name is not a plain file name (report "renamed")."""
    return {f.name: f.stem for f in frames if f.stem != f.name}


# --- memory: estimate before allocating -----------------------------------------------------------
def holdout_note(scene: Scene, held: list[str], method: str) -> str | None:
    """One line when views ``held`` out of ``scene`` (``plan(holdout=)``) are scored with a method
    that reads preprocessing stages (tm, ulr, pvm, hybrid): ``ibr-preprocess`` ran those stages on
    every view of the scene, the held-out ones too (a mesh fused from their depth, a texture baked
    from their colours), so the figures on them are optimistic. None otherwise. The render report
    and ibr-bench's JSON carry it as "holdout_note" and the commands print it."""
    held = list(held)
    read = [n for n, st in STAGES.items()
            if method in st.methods and "outputs" in (scene.stages.get(n) or {})]
    if not held or not read:
        return None
    views = (f"held-out views {', '.join(held[:4])}{', ...' if len(held) > 4 else ''} were inputs" if len(held) > 1
             else f"held-out view {held[0]} was an input")
    stages = read[0] if len(read) == 1 else ", ".join(read[:-1]) + " and " + read[-1]
    return (f"{views} of the {stages} stage{'s' if len(read) > 1 else ''} (ibr-preprocess ran on every view): "
            f"the {method} method's figures on {'them' if len(held) > 1 else 'it'} are optimistic; to score unseen "
            "views, import them as targets (ibr-preprocess INPUT -o SCENE --holdout NAME ...) and render the targets")


def stale_note(scene: Scene, method: str) -> str | None:
    """One line when a preprocessing stage ``method`` reads is out of date in ``scene``
    (``cache.stale_reasons``: its code's version changed, or a stage it reads re-ran after it,
    e.g. ``ibr-preprocess --stages mesh`` alone), naming the command that brings it up to date.
    The output still loads and is used as it is. None otherwise. The render report and
    ibr-bench's JSON carry it as "stale_note" and the commands print it as a warning."""
    stale = {n: r for n, st in STAGES.items() if method in st.methods
             for r in [stale_reasons(scene.stages, n)] if r}
    if not stale:
        return None
    where = scene.root if scene.root is not None else "SCENE"
    what = "; ".join(f"{n} ({', '.join(r)})" for n, r in stale.items())
    many = len(stale) > 1
    return (f"the output{'s' if many else ''} of stage{'s' if many else ''} {what} {'are' if many else 'is'} out of "
            f"date and used as {'they are' if many else 'it is'}: run ibr-preprocess {where} -o {where} "
            f"--methods {method}")


# Bytes held per pixel while rendering, fitted to the peak RSS measured with /usr/bin/time -v at
# 1920x1080 and 3840x2160 (tools/measure_memory.py; docs/robustness.md "Peak memory") and rounded
# up so that the estimate stays 1.3-1.5x above every measurement. INPUT: every pixel of every
# input view the method loads (colour float32 x3, depth, mask and the method's per-view buffers);
# FRAME: every pixel of the largest frame (output colour, depth, hole mask, metrics' copies,
# per-frame scratch); reference and tm read no view, only the mesh. tm/ulr/pvm/hybrid: fitted to
# 4 views at 1080p and 4K and 8 views at 1080p (the per-view slope: ulr 12.5, pvm 12.8, hybrid
# 16.8 bytes per input pixel measured, INPUT set ~1.5x above it for jobs with many views).
_INPUT_BPP = {"reference": 0, "dibr": 24, "warp": 24, "depthwarp": 16, "tm": 0, "ulr": 20, "pvm": 20,
              "hybrid": 24}


_FRAME_BPP = {"reference": 120, "dibr": 64, "warp": 64, "depthwarp": 120, "tm": 120, "ulr": 124,
              "pvm": 288, "hybrid": 428}


_TRIANGLE_BYTES = 160   # mesh arrays + Embree BVH per triangle
_MESHLESS = ("dibr", "warp")  # methods that never read the scene's meshes (nor count them)


_BASE_BYTES = 400 << 20  # the interpreter, numpy, OpenImageIO, open3d, the engine, loaded once


def estimate_memory(job: Job, method: str) -> dict:
    """A coarse upper estimate of the peak bytes of rendering ``job`` with ``method``, from the
    camera sizes alone (no image is loaded) and the faces of the meshes the method reads:
    {"total", "inputs", "frame", "mesh", "base"}."""
    in_px = sum(v.camera.width * v.camera.height for v in job.scene.views)
    out_px = max((f.camera.width * f.camera.height for f in job.frames), default=0)
    meshes = {} if method in _MESHLESS else (job.scene.meshes or {})  # LazyMeshes: read here only if used
    tris = sum(len(m.faces) for m in meshes.values() if hasattr(m, "faces"))
    est = {"inputs": in_px * _INPUT_BPP.get(method, 64), "frame": out_px * _FRAME_BPP.get(method, 600),
           "mesh": tris * _TRIANGLE_BYTES, "base": _BASE_BYTES}
    est["total"] = sum(est.values())
    return est


def check_memory(job: Job, method: str) -> dict:
    """Refuse, before anything is allocated, a job whose estimate exceeds the available memory
    (a clear error instead of the kernel's OOM killer part-way through)."""
    est = estimate_memory(job, method)
    avail = available_memory()
    if est["total"] > avail:
        gib = 1 << 30
        big = max(job.frames, key=lambda f: f.camera.width * f.camera.height)
        raise BadValueError.about(
            "method",
            f"this job needs about {est['total'] / gib:.1f} GiB "
            f"({len(job.scene.views)} input views: {est['inputs'] / gib:.1f} GiB; largest frame "
            f"{big.camera.width}x{big.camera.height}: {est['frame'] / gib:.1f} GiB; mesh "
            f"{est['mesh'] / gib:.1f} GiB), only {avail / gib:.1f} GiB is available"
            f"{' (IBR_MEMORY_LIMIT)' if os.environ.get('IBR_MEMORY_LIMIT') else ''}: render smaller frames, "
            "use fewer input views (dibr: parameter inputs), or free memory", method)
    return est
