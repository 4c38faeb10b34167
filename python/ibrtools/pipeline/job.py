"""A render job: the frames of a plan (:mod:`ibrtools.pipeline.plan`) rendered with a method,
the images and ``report.json`` written (fields in docs/render.md).

Outputs in the output directory: ``<frame>.png`` (8-bit sRGB, complete: inpaint/complete.py),
``<frame>.exr`` with ``float_out``, ``<frame>.depth.exr`` with ``depth_out`` (+inf on the
background at infinity), ``<frame>.hole.png`` (white = a pixel no input covers: filled, or black
with inpaint "none") when the frame has holes, ``<frame>.method.png`` for the hybrid methods (the
per-pixel method choice: red PVM, green TM, blue ULR), and ``report.json``. Every file is written atomically and
``report.json`` last, so a reader that finds it finds every image it names.
"""
from __future__ import annotations

import glob
import json
import os
import tempfile
import threading
import time
import uuid
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from dataclasses import dataclass
from typing import Any, Callable, Collection, Mapping

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, InputError, InternalError
from ibrtools.imageio import atomic_path
from ibrtools.imageio import write_depth as _write_depth
from ibrtools.imageio import write_image as _write_image
from ibrtools.outputs import OutputDir, check_output_dir, file_stem, is_plain_name, temp_prefix
from ibrtools.scene import Scene, View
from ibrtools.pipeline import distributed as D
from ibrtools.pipeline.plan import (FRAME_SUFFIXES, Frame, Job, check_memory, holdout_note, plan, renamed_frames,
                                    report_files, stale_note)
from ibrtools import methods
from ibrtools.params import MethodParams
from ibrtools.inpaint.complete import (DEFAULT_INPAINT, INPAINT_FILLS, NOTHING_TO_FILL, check_inpaint, complete, completion,
                       parse_background)
from ibrtools.formats import native
from ibrtools.formats.yuv import DEFAULT_BITS as DEFAULT_YUV_BITS, rgb_to_yuv
from ibrtools.formats.yuv import write_frame as write_yuv_frame
from ibrtools.imageio import linear_to_srgb
from ibrtools.metrics import DEFAULT_SCORES, SCORES, compare, parse_scores, psnr


def _frame_metrics(color: np.ndarray, hole: np.ndarray | None, filled: bool, truth: View | None,
                   scores: Collection[str] = SCORES) -> dict:
    """The frame's scores (those of ``scores``): "psnr", "ssim", "flip" of the image as written,
    "psnr_covered" / "ssim_covered" over the pixels the method or the background covered,
    "coverage" (that fraction) and "filled" (the fraction the inpainting filled)."""
    m: dict = {}
    if truth is not None and truth.has_color and scores:
        m = compare(color, truth.color, hole_mask=hole, mask=truth.mask if truth.has_mask else None,
                    scores=tuple(scores))
    elif hole is not None:
        m = {"coverage": float(1.0 - hole.mean())}
    if hole is not None:
        m["filled"] = float(hole.mean()) if filled else 0.0
    # JSON has no inf: an exact match (PSNR = inf) is written as null, like an empty mask.
    return {k: (float(v) if v is not None and np.isfinite(v) else None) for k, v in m.items()}


def warm_up(method, camera: Camera) -> float:
    """Render ``camera`` at a quarter of its size once, untimed by the frames, so that the
    engine's first-use costs (thread pool start, tables, buffers) are not in the first frame's
    time; returns its ms (report.json "setup_ms" "warm_up"). Methods whose frames depend on the
    frames before them are not warmed up (their state would change)."""
    t0 = time.perf_counter()
    method.render(camera.scaled(max(8, camera.width // 4), max(8, camera.height // 4)))
    return (time.perf_counter() - t0) * 1e3


# Methods whose frames depend on the frames before them (depthwarp warps from the previous
# frame): a distributed run gives all their frames to one task, in order.
SEQUENTIAL = frozenset({"depthwarp"})


def run(job: Job, method_name: str, out_dir: str | os.PathLike, *, params: Mapping | MethodParams | None = None,
        float_out: bool = False, depth_out: bool = False, threads: int = 0, inpaint: str = DEFAULT_INPAINT,
        background: str | None = None, foveate: tuple[float, float] | None = None, pooling: float | None = None,
        progress: Callable[[int, int, str], None] | None = None,
        scheduler: str | None = None, workers: int = 0,
        yuv: str | os.PathLike | Mapping[str, str | os.PathLike] | None = None,
        yuv_bits: int | Mapping[str, int] = DEFAULT_YUV_BITS, metrics: Any = DEFAULT_SCORES) -> dict:
    """Render every frame of ``job``; write images and report.json; return the report.

    Every frame is completed (inpaint/complete.py): the background at infinity where an input
    sees it, then the holes filled by ``inpaint`` ("auto", the default, "pushpull", "metameric"
    with seed 0, the same noise for every frame as Walton et al. 2021, or "none": black), timed
    as stages "background" and "inpaint"; the hole mask is still written and "psnr_holes" scores
    the filled pixels when ground truth exists. Frames without a hole are not touched (the report
    says "inpaint": "skipped: no hole"). ``background`` (None, "black", "white", "R,G,B" sRGB in
    [0, 1], or "transparent": RGBA images with alpha 0 on the background) recolours the
    background at infinity (complete.parse_background).

    ``metrics`` ("all", "none" or names of psnr, ssim, flip: :func:`ibrtools.metrics.parse_scores`)
    are the scores computed for frames with ground truth; "coverage" and "filled" always are.

    ``foveate`` ((x, y) fixation in [0, 1]^2, or None) post-processes every frame, after the
    inpainting, into a foveated ventral metamer (:func:`ibrtools.metamers.foveate.foveate`, seed 0 and
    ``pooling`` or its default), timed as stage "foveate"; metrics then score the metamer.

    ``workers`` N > 0 renders on a local Dask cluster of N processes, ``scheduler`` ADDRESS on an
    existing Dask cluster; each task uses ``threads`` engine threads (default 1: a Dask worker
    thread is a core); the files are the same, bit for bit, as a local run's
    (docs/distributed.md). The job's scene must be on disk (its ``root``).

    A frame whose rendering raises is left out and listed in the report's "failed" ({"name",
    "error"}); the other frames are written. An interrupt (KeyboardInterrupt, SIGTERM through
    the commands) removes every file the run wrote: all or nothing."""
    from ibrtools import _core
    if isinstance(params, MethodParams):  # the typed form: the report and the Dask tasks hold its values
        params = params.as_dict()
    D.check_options(scheduler, workers)
    check_inpaint(inpaint)
    scores = list(parse_scores(metrics))

    fov_kw: dict = {}
    if foveate is not None:
        from ibrtools.metamers.foveate import POOLING, _check_geometry

        fov_kw = {"fixation": foveate, "pooling": POOLING if pooling is None else pooling}
        _check_geometry(fov_kw["fixation"], fov_kw["pooling"], 90.0)  # bad values fail before rendering
    out_dir = check_output_dir(out_dir)
    sink = YuvSink(yuv, yuv_bits, job)  # bad --yuv values fail before anything is written
    if yuv is not None and D.wanted(scheduler, workers):
        raise BadValueError.about("yuv", "not with workers or a scheduler (the frames are written by the workers)")
    name = methods.resolve(method_name, job.scene)
    check_memory(job, name)
    parse_background(background)  # a bad value fails before anything is written
    frame_kw = {"inpaint": inpaint, "fov_kw": fov_kw, "float_out": float_out, "depth_out": depth_out,
                "background": background, "scores": scores}
    method = methods.create(name, params)  # bad parameters fail here, before anything is written
    # The output directory is this job's until it ends (a second job is refused, before any
    # work), its dead jobs' temporaries are swept, and the files an earlier job left there are
    # known: a killed job's journal (od.previous) and what a finished one's report.json names.
    stems = {Path(f.stem + s).stem for f in job.frames for s in FRAME_SUFFIXES} | {"report"}
    with OutputDir(out_dir, stems=stems) as od:
        distributed = D.wanted(scheduler, workers)
        if distributed:
            root = job.scene.root
            if root is not None and job.scenes is not None:
                root = Path(root).parents[1]  # a video scene's frame lives in <video>/frames/<frame>/
            if root is None or not (Path(root) / "scene.json").is_file():
                raise BadValueError.about(("workers", "scheduler"), "the workers load the scene from disk; this "
                                          "job's scene has no scene directory (save it with ibrtools.save_scene "
                                          "first)")
            if job.spec is None:
                raise BadValueError.about(("workers", "scheduler"), "the workers rebuild the job with "
                                          "ibrtools.pipeline.plan.plan(); this job was not made by plan() with "
                                          "JSON-able arguments")
            # Engine threads per task: -j, else 1 (a Dask worker thread is a core; pipeline/distributed.py).
            spec = {"root": str(Path(root).resolve()), "stamp": D.scene_stamp(root), "plan": job.spec,
                    "method": name, "params": dict(params or {}), "frame": frame_kw, "threads": int(threads)}
        else:
            if threads:
                _core.set_num_threads(threads)
            setup = method.prepare(job.scene)
            prepared_for = job.frames[0].scene_frame if job.frames else None
            if job.frames and name not in SEQUENTIAL:
                setup["warm_up"] = warm_up(method, job.frames[0].camera)
        previous = od.previous | report_files(out_dir / "report.json")
        # report.json marks a complete run: a stale one must not describe the images written now.
        (out_dir / "report.json").unlink(missing_ok=True)
        written: list[Path] = []
        n = len(job.frames)
        entries: list[dict | None] = [None] * n
        failures: list[dict | None] = [None] * n
        extra: dict = {}
        try:
            if not distributed:
                # Frame i's files are encoded and written by one background thread while frame i + 1
                # renders (PNG encoding takes about as long as a 1080p DIBR frame; OpenImageIO
                # releases the GIL). At most one frame's files are in flight; a write error is raised
                # here, at the next frame or at the end. A video's next scene frame is decoded by
                # another thread meanwhile (VideoStream), so the sustained rate is the render rate.
                t_loop = time.perf_counter()
                with ThreadPoolExecutor(1, thread_name_prefix="ibr-write") as writer, \
                        VideoStream(job) as stream, sink:
                    stream.entered(prepared_for)
                    in_flight: list[Future] = []
                    for i, frame in enumerate(job.frames):
                        if progress:
                            progress(i, n, frame.name)
                        if frame.scene_frame != prepared_for:  # a video's next scene frame: prepared anew
                            method = None  # the previous frame's preparation is freed first
                            stream.leave(prepared_for)
                            scene_now = stream.enter(frame.scene_frame)
                            method = methods.create(name, params)
                            method.prepare(scene_now)
                            prepared_for = frame.scene_frame
                        entries[i], failures[i], outputs = render_frame(method, frame, frame_scene(job, frame),
                                                                        **frame_kw)
                        for f in in_flight:
                            f.result()
                        in_flight = []
                        for rel, kind, array in outputs:
                            od.record(rel)
                            written.append(out_dir / rel)
                            # a copy: the method may reuse its output buffers for the next frame
                            in_flight.append(writer.submit(write_output, out_dir, rel, kind, np.array(array)))
                            if sink.files and entries[i] is not None and rel == entries[i].get("image"):
                                in_flight.append(writer.submit(sink.add, frame.camera_name, np.array(array[..., :3])))
                    for f in in_flight:
                        f.result()
                if sink.files:
                    written += sink.paths  # all or nothing: an interrupt from here on removes them too
                    extra["yuv"] = sink.describe()
                if job.scenes is not None:
                    extra["sequence"] = sequence_report(entries, time.perf_counter() - t_loop, stream.wait_ms)
                used_threads = int(_core.get_num_threads())
            else:
                done = 0

                def on_frame(i: int, entry, failure, files: dict[str, bytes]) -> None:
                    nonlocal done
                    for rel, data in files.items():
                        od.record(rel)
                        written.append(out_dir / rel)
                        with atomic_path(out_dir / rel) as tmp:
                            tmp.write_bytes(data)
                    entries[i], failures[i] = entry, failure
                    done += 1
                    if progress:
                        progress(done, n, job.frames[i].name)

                # One task per job frame (a video: frame-major, so a worker mostly keeps its scene frame).
                sequential = name in SEQUENTIAL
                chunks = [list(range(n))] if sequential else [[i] for i in range(n)]
                if progress:
                    progress(0, n, "")
                with D.open_client(scheduler, workers, threads_per_worker=1) as client:
                    info = run_frames(client, job, spec, chunks, on_frame)
                    extra["distributed"] = {**D.describe(client, scheduler), "tasks": len(chunks)}
                setup, used_threads = info["setup_ms"] or {}, int(info["threads"] or 0)
            if progress:
                progress(n, n, "")
            frames_report = [e for e in entries if e is not None]
            # Files of an earlier job here that this one did not write would sit beside a report
            # that does not describe them: removed, and the report says so.
            new = {p.name for p in written}
            removed = sorted(f for f in previous - new if (out_dir / f).is_file())
            for f in removed:
                (out_dir / f).unlink(missing_ok=True)
            output = {k: v for k, v in (("renamed", renamed_frames(job.frames)), ("swept", od.swept),
                                        ("replaced", sorted(previous & new)), ("removed", removed)) if v}
            note, stale = holdout_note(job.scene, job.held_out, name), stale_note(job.scene, name)
            report = {"method": name, "params": dict(params or {}), "inpaint": inpaint,
                      **({"background": background} if background is not None else {}),
                      **({"holdout_note": note} if note else {}), **({"stale_note": stale} if stale else {}),
                      **({"foveate": {"fixation": list(fov_kw["fixation"]), "pooling": fov_kw["pooling"]}}
                         if fov_kw else {}),
                      "threads": used_threads, **extra, **({"output": output} if output else {}),
                      "inputs": len(job.scene.views), "frames": frames_report,
                      "failed": [f for f in failures if f is not None],
                      "summary": _summary(frames_report, setup)}
            with atomic_path(out_dir / "report.json") as tmp:
                tmp.write_text(json.dumps(report, indent=1, allow_nan=False))
            return report
        except BaseException:
            # Interrupted (SIGINT, SIGTERM through the commands' handler) or failed outside a frame's
            # rendering: the run is all or nothing, so the frames it wrote go too (each was written
            # atomically).
            for f in written:
                if not f.is_dir():  # a directory in a frame file's place was the write's obstacle, not ours
                    f.unlink(missing_ok=True)
                # and its temporary, when the interrupt came while atomic_path was creating it (a
                # signal handled in another thread raises in this one at any bytecode).
                for t in f.parent.glob(f"{glob.escape(temp_prefix(f.stem))}*{glob.escape(f.suffix)}"):
                    t.unlink(missing_ok=True)
            raise


# zlib level of the frames' PNGs: 1, as OpenCV writes PNGs by default (a 1080p frame encodes in
# 77 ms instead of 204 ms at zlib's default 6, for 1000 KB instead of 773 KB; the same pixels),
# and one row filter, "sub", instead of libpng's per-row trial of all five (86 -> 40 ms of CPU
# for a 1080p frame of the video bench, 1122 -> 1140 KB).
FRAME_PNG_LEVEL = 1
FRAME_PNG_FILTER = "sub"


def write_output(out_dir: Path, rel: str, kind: str, array: np.ndarray) -> Path:
    """Write one output file of a frame (atomically): ``kind`` "depth" (single-channel float EXR)
    or "image" (by extension: 8-bit sRGB PNG at zlib level FRAME_PNG_LEVEL and filter
    FRAME_PNG_FILTER, linear float EXR).
    The one writer of local runs and of Dask workers (which send the bytes back: encode_outputs)."""
    if not is_plain_name(rel):
        raise InternalError(f"write_output: {rel!r} is not a plain file name")  # names go through file_stem
    path = out_dir / rel
    if kind == "depth":
        _write_depth(path, array)
    else:
        _write_image(path, array, png_level=FRAME_PNG_LEVEL, png_filter=FRAME_PNG_FILTER)
    return path


class YuvSink:
    """``--yuv FILE``: every rendered frame's colour appended, in frame order, to one raw YUV 4:2:0
    file (formats/yuv.py: BT.709, limited range, 8-bit samples or little-endian 16-bit words for
    9..16 bits, as RVS writes and reads them); a FILE with ``{camera}`` in its name, or a mapping
    camera name -> file (an RVS config's ``OutputFiles``), writes one file per camera, as RVS does,
    each with its frames in order (``bits`` an int, or camera name -> bits). Each file is written
    to a temporary beside it and renamed when the job ends (an interrupted job leaves no
    half-written video). Failed frames are not in it (report.json "yuv" counts the frames
    written). add() runs on the writer thread, which keeps the frame order."""

    def __init__(self, path: str | os.PathLike | Mapping[str, str | os.PathLike] | None,
                 bits: int | Mapping[str, int], job: "Job"):
        self.files: dict[str | None, _YuvFile] = {}
        if path is None:
            return
        cameras = list(dict.fromkeys(f.camera_name for f in job.frames))
        if isinstance(path, Mapping):  # the cameras this job renders (a file per camera not rendered: none)
            targets = {str(k): Path(v) for k, v in path.items() if str(k) in cameras}
        elif "{camera}" in os.fspath(path):
            targets = {c: Path(os.fspath(path).replace("{camera}", file_stem(c))) for c in cameras}
        else:
            targets = {None: Path(path)}
        missing = [c for c in cameras if None not in targets and c not in targets]
        if missing:
            raise BadValueError.about("yuv", f"no output file for camera {missing[0]!r} (files for: "
                                             f"{', '.join(sorted(str(k) for k in targets))})")
        if len(set(targets.values())) != len(targets):
            raise BadValueError.about("yuv", "two cameras write the same file")
        for key, file in targets.items():
            b = bits.get(key, DEFAULT_YUV_BITS) if isinstance(bits, Mapping) else bits
            if isinstance(b, bool) or not isinstance(b, (int, np.integer)) or not 8 <= b <= 16:
                raise BadValueError.about("yuv_bits", f"expected a bit depth of 8..16, got {b!r}")
            if file.is_dir():
                raise BadValueError.about("yuv", "is a directory (expected a file name, e.g. out.yuv)", str(file))
            if not file.parent.is_dir():
                raise BadValueError.about("yuv", f"its folder {file.parent} does not exist", str(file))
            sizes = sorted({(f.camera.width, f.camera.height) for f in job.frames if key in (None, f.camera_name)})
            if len(sizes) > 1:
                raise BadValueError.about("yuv", f"one file holds frames of one size; these frames are "
                                                 f"{', '.join(f'{w}x{h}' for w, h in sizes[:4])}")
            self.files[key] = _YuvFile(file, int(b), sizes[0] if sizes else None)

    @property
    def paths(self) -> list[Path]:
        return [f.path for f in self.files.values()]

    def __enter__(self) -> "YuvSink":
        for f in self.files.values():
            f.cm = atomic_path(f.path)
            f.file = open(f.cm.__enter__(), "wb")
        return self

    def __exit__(self, *exc) -> bool:
        suppress = False
        for f in self.files.values():
            if f.cm is None:
                continue
            f.file.close()
            cm, f.cm = f.cm, None
            suppress = bool(cm.__exit__(*exc)) or suppress
        return suppress

    def add(self, camera: str, color: np.ndarray) -> None:
        f = self.files[None if None in self.files else camera]
        write_yuv_frame(f.file, rgb_to_yuv(color, f.bits))
        f.frames += 1

    def describe(self) -> dict | list[dict]:
        """report.json "yuv": the file written (one dict), or one dict per camera's file."""
        out = []
        for key, f in self.files.items():
            w, h = f.size or (0, 0)
            out.append({**({"camera": key} if key is not None else {}), "path": str(f.path), "frames": f.frames,
                        "width": w, "height": h, "chroma": "420", "bits": f.bits, "matrix": "bt709",
                        "range": "limited"})
        return out[0] if None in self.files else out


@dataclass
class _YuvFile:
    path: Path
    bits: int
    size: tuple[int, int] | None
    frames: int = 0
    cm: Any = None
    file: Any = None


class VideoStream:
    """The input side of a video job's render loop: while the frames of scene frame k render, a
    background thread decodes the input images of scene frame k + 1 (Scene.load; OpenImageIO
    releases the GIL), and the images of a scene frame whose frames are done are released
    (Scene.release), so a sequence of any length holds about two scene frames' images. A still
    job (no scene frames) does nothing. A decoding error is raised by enter(), where the
    frame's first use would have raised it."""

    def __init__(self, job: "Job"):
        self.job = job
        self.order: list[str] = []
        for f in job.frames:
            if f.scene_frame is not None and (not self.order or self.order[-1] != f.scene_frame):
                self.order.append(f.scene_frame)
        self.wait_ms = 0.0  # time enter() waited for a decode (the stream was behind the renderer)
        self._pending: dict[str, Future] = {}
        self._pool: ThreadPoolExecutor | None = None

    def __enter__(self) -> "VideoStream":
        if self.job.scenes is not None and len(self.order) > 1:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="ibr-decode")
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:
            for f in self._pending.values():
                f.cancel()
            self._pool.shutdown(wait=True)

    def _prefetch_after(self, name: str | None) -> None:
        if self._pool is None or name not in self.order:
            return
        k = self.order.index(name) + 1
        if k < len(self.order) and self.order[k] not in self._pending:
            self._pending[self.order[k]] = self._pool.submit(self.job.scenes[self.order[k]].load)

    def entered(self, name: str | None) -> None:
        """The loop starts on scene frame ``name`` (prepared already): decode the next one."""
        self._prefetch_after(name)

    def enter(self, name: str) -> Scene:
        """Scene frame ``name``, decoded (waiting for its decode if it is still running)."""
        fut = self._pending.pop(name, None)
        if fut is not None:
            t0 = time.perf_counter()
            fut.result()
            self.wait_ms += (time.perf_counter() - t0) * 1e3
        self._prefetch_after(name)
        return self.job.scenes[name]

    def leave(self, name: str | None) -> None:
        """Scene frame ``name``'s frames are done: its decoded images are released."""
        if self._pool is not None and name is not None:
            self.job.scenes[name].release()


def sequence_report(entries: list[dict | None], wall_s: float, wait_ms: float) -> dict:
    """report.json "sequence" of a video job: the sustained rate over the whole loop (decode,
    render, completion and writing, as a user's sequence runs) and the mean per-stage split."""
    done = [e for e in entries if e is not None]
    stages: dict[str, list[float]] = {}
    for e in done:
        for k, v in e["time_ms"].items():
            stages.setdefault(k, []).append(float(v))
    return {"frames": len(done), "wall_ms": round(wall_s * 1e3, 3),
            "fps": round(len(done) / wall_s, 3) if wall_s > 0 else 0.0,
            "decode_wait_ms": round(wait_ms, 3),
            "stage_ms_mean": {k: round(float(np.mean(v)), 3) for k, v in stages.items()}}


def frame_scene(job: "Job", frame: Frame) -> Scene:
    """The scene a frame is rendered from (a video's frame: its scene frame's)."""
    return job.scene if frame.scene_frame is None or job.scenes is None else job.scenes[frame.scene_frame]


def render_frame(method, frame: Frame, scene: Scene, *, inpaint: str, fov_kw: dict, float_out: bool,
                 depth_out: bool, background: str | None = None, scores: Collection[str] = SCORES
                 ) -> tuple[dict | None, dict | None, list[tuple[str, str, np.ndarray]]]:
    """Render one frame with a ``method`` prepared on ``scene`` and post-process it: NaN guard,
    the background at infinity and the holes (inpaint/complete.py), foveation, metrics. Returns (report entry, None, outputs) with outputs the files
    to write [(file name, "image" | "depth", array)], or (None, {"name", "error"}, []) when the
    rendering or its post-processing raised (the frame failed; the job goes on), except for bad
    scene data found while rendering (an input image that decodes to NaN): raised, the job stops. Writes nothing:
    the caller does (the local loop, or the client of a distributed run)."""
    try:
        return _render_frame(method, frame, scene, inpaint=inpaint, fov_kw=fov_kw, float_out=float_out,
                             depth_out=depth_out, background=background, scores=scores)
    except Exception as e:  # noqa: BLE001 - reported by name in report.json "failed"
        if isinstance(e, InputError) and getattr(e, "scene_data", False):
            raise  # an input file found bad when first read (scene.View): the job stops, exit 2
        return None, {"name": frame.name, "error": f"{type(e).__name__}: {e}"}, []


def _render_frame(method, frame: Frame, scene: Scene, *, inpaint, fov_kw, float_out, depth_out, background=None,
                  scores: Collection[str] = SCORES):
    outputs: list[tuple[str, str, np.ndarray]] = []
    t0 = time.perf_counter()
    out, stage_ms = method.render(frame.camera)
    done = complete(out, frame.camera, *completion(method, scene, inpaint), parse_background(background))
    color, hole = done.color, done.hole
    stage_ms = {**stage_ms, **done.stage_ms}
    if fov_kw:
        from ibrtools.metamers.foveate import foveate as foveate_image

        t1 = time.perf_counter()
        color = foveate_image(np.ascontiguousarray(color, np.float32), fov_kw["fixation"],
                              pooling=fov_kw["pooling"])
        stage_ms = {**stage_ms, "foveate": (time.perf_counter() - t1) * 1e3}
    total_ms = (time.perf_counter() - t0) * 1e3
    image = f"{frame.stem}.png"
    written = color if done.alpha is None else np.concatenate([color, done.alpha[..., None]], -1)
    outputs.append((image, "image", written))
    entry: dict = {"name": frame.name, "image": image,
                   "time_ms": {"total": round(total_ms, 3), **{k: round(v, 3) for k, v in stage_ms.items()}},
                   "metrics": _frame_metrics(color, hole, done.filled, frame.truth, scores), **frame.info}
    if done.note is not None:
        entry["inpaint"] = done.note
        if done.filled and frame.truth is not None and frame.truth.has_color and "psnr" in scores:
            entry["metrics"]["psnr_holes"] = _psnr_in(color, frame.truth.color, hole)
    # Method-specific facts about the frame (dibr: the selected input views, best first,
    # their similarity, and how many candidates were skipped for not overlapping).
    if hasattr(method, "frame_report"):
        entry.update(method.frame_report())
    # Method-specific scores of the frame (depthwarp: depth PSNR/SSIM against the reference).
    if hasattr(method, "frame_metrics"):
        entry["metrics"].update(method.frame_metrics())
    warnings = frame_warnings(entry, hole, done.note)
    if warnings:
        entry["warnings"] = warnings
    if float_out:
        outputs.append((f"{frame.stem}.exr", "image", written))
        entry["image_float"] = f"{frame.stem}.exr"
    if depth_out and done.depth is not None:
        outputs.append((f"{frame.stem}.depth.exr", "depth", done.depth))
        entry["depth"] = f"{frame.stem}.depth.exr"
    selection = out.get("selection")
    if selection is not None:
        # Hybrid methods: the per-pixel method choice (RGB: red PVM, green TM, blue ULR; hybrid/method.py).
        outputs.append((f"{frame.stem}.method.png", "image", np.asarray(selection, np.float32)))
        entry["method_mask"] = f"{frame.stem}.method.png"
    if hole is not None and hole.any():
        # The holes (white): black in the image with --inpaint none, the filled pixels otherwise.
        outputs.append((f"{frame.stem}.hole.png", "image", hole.astype(np.float32)))
        entry["hole_mask"] = f"{frame.stem}.hole.png"
    return entry, None, outputs


# Below this fraction of pixels covered by the inputs (the method and the background at infinity)
# a frame is mostly guessed: its report entry says so (frame_warnings).
LOW_COVERAGE = 0.5


def frame_warnings(entry: dict, hole: np.ndarray | None, note: str | None) -> list[str]:
    """What is wrong with a rendered frame, for its report entry "warnings" and the ``warning:``
    lines of ibr-render: no input overlaps the target, or the inputs cover less than
    LOW_COVERAGE of it (what was done with the rest), or there was nothing to fill from."""
    out = []
    if entry.get("selected") == []:
        out.append("no input view overlaps the target (every candidate was skipped)")
    if hole is not None and hole.any():
        cov = float(1.0 - hole.mean())
        if cov == 0.0:
            if not out:
                out.append("no input covers any pixel of the target")
        elif cov < LOW_COVERAGE:
            rest = "filled" if entry.get("inpaint") in INPAINT_FILLS else "black"
            out.append(f"the inputs cover {100 * cov:.1f} % of the target (below {100 * LOW_COVERAGE:.0f} %); "
                       f"the rest is {rest}")
    if note == NOTHING_TO_FILL and not out:
        out.append(note)
    return out


def _psnr_in(color: np.ndarray, truth: np.ndarray, region: np.ndarray) -> float | None:
    """PSNR (sRGB, peak 1) inside the filled holes; None when not finite (JSON has no inf)."""
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


# ---------------------------------------------------------------------------------------------
# The worker side of a distributed run (docs/distributed.md): module-level functions, so that Dask
# workers import them by name.

_PREPARED: dict[str, tuple] = {}


# A prepared method holds per-frame state (frame_report), so the tasks of one worker process run
# one at a time even when the worker has several Dask threads (give those cores to -j instead).
_LOCK = threading.Lock()


def _prepared(spec: dict, scene_frame: str | None = None):
    """(job, method, setup_ms, prepared_now) for ``spec`` (and, in a video scene, its frame
    ``scene_frame``) on this worker, prepared once."""
    from ibrtools import _core

    frame_stamp = D.scene_stamp(Path(spec["root"]) / "frames" / scene_frame) if scene_frame else None
    key = json.dumps([spec["root"], spec["stamp"], spec["plan"], spec["method"], spec["params"],
                      spec["threads"], scene_frame, frame_stamp], sort_keys=True, default=str)
    hit = _PREPARED.get(key)
    if hit is not None:
        return (*hit, False)
    _PREPARED.clear()  # one preparation per worker: the inputs of another job are freed
    _core.set_num_threads(D.engine_threads(spec["threads"]))
    scene = native.load(spec["root"])
    job = plan(scene, **spec["plan"])
    method = methods.create(spec["method"], spec["params"])
    setup = method.prepare(job.scene if scene_frame is None else job.scenes[scene_frame])
    _PREPARED[key] = (job, method, setup)
    return job, method, setup, True


def encode_outputs(outputs: list[tuple[str, str, object]]) -> dict[str, bytes]:
    """A frame's outputs [(file name, kind, array)] as file bytes, written by the very writer
    of a local run (:func:`ibrtools.pipeline.job.write_output`) into a scratch directory."""

    files: dict[str, bytes] = {}
    with tempfile.TemporaryDirectory(prefix="ibr-task-") as d:
        for rel, kind, array in outputs:
            path = write_output(Path(d), rel, kind, array)
            files[rel] = path.read_bytes()
            path.unlink()
    return files


def render_task(spec: dict, indices: list[int], names: list[str], scene_frames: list[str | None]) -> dict:
    """A Dask task: render frames ``indices`` of the job ``spec`` describes. Returns {"frames":
    [(index, entry or None, failure or None, files)], "setup_ms" (of the worker's preparation),
    "prepared" (whether this task made it), "threads"}, or {"error": exception} when the scene
    or the method cannot be prepared."""
    with _LOCK:
        return _render_task(spec, indices, names, scene_frames)


def _render_task(spec: dict, indices: list[int], names: list[str], scene_frames: list[str | None]) -> dict:
    from ibrtools import _core

    out = []
    fresh_any = False
    for i, name, scene_frame in zip(indices, names, scene_frames):
        try:  # cached after the first frame (of each scene frame, in a video)
            job, method, setup, fresh = _prepared(spec, scene_frame)
            got = job.frames[i].name if i < len(job.frames) else None
            if got != name:
                raise BadValueError(f"the worker planned other frames than the client ({got} != {name}): "
                                    "the scene changed on disk, or the workers see another scene at "
                                    f"{spec['root']}")
        except Exception as e:  # noqa: BLE001 - sent back and raised on the client (one error, no retries)
            return {"error": e}
        fresh_any |= fresh
        frame = job.frames[i]
        entry, failure, outputs = render_frame(method, frame, frame_scene(job, frame), **spec["frame"])
        out.append((i, entry, failure, encode_outputs(outputs) if outputs else {}))
    return {"frames": out, "setup_ms": setup, "prepared": fresh_any, "threads": int(_core.get_num_threads())}


def run_frames(client, job, spec: dict, chunks: list[list[int]], on_frame: Callable) -> dict:
    """Submit one task per chunk of frame indices; call ``on_frame(index, entry, failure, files)``
    on the client as frames complete (completion order). Returns {"setup_ms", "threads"} of
    the workers. Futures are cancelled on any way out (an interrupt included)."""
    from distributed import as_completed

    token = uuid.uuid4().hex[:10]
    futures = [client.submit(render_task, spec, c, [job.frames[i].name for i in c],
                             [job.frames[i].scene_frame for i in c], key=f"ibr-render-{token}-{k}",
                             retries=D.RETRIES, pure=False) for k, c in enumerate(chunks)]
    info: dict = {"setup_ms": None, "threads": None}
    try:
        for fut in as_completed(futures, loop=client.loop):
            res = fut.result()
            fut.release()
            if "error" in res:
                raise res["error"]
            if info["setup_ms"] is None or res["prepared"]:
                info["setup_ms"] = res["setup_ms"]  # a preparation of this job, else the reused one
            info["threads"] = res["threads"]
            for i, entry, failure, files in res["frames"]:
                on_frame(i, entry, failure, files)
    finally:
        client.cancel([f for f in futures if not f.done()])
    return info
