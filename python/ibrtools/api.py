"""The Python API: load, import, preprocess and save scenes; render one camera or a whole job; bench.

``load_scene(path)`` reads a native scene directory (what ``ibr-preprocess`` writes, docs/FORMAT.md);
``render(scene, camera, method="auto", **params)`` renders one camera with one of the novel-view
methods of :mod:`ibrtools.methods` and returns a :class:`RenderResult`. The method is
prepared (BVH builds, view-selection structures, ...) once per scene, method and parameters and
kept, so rendering many cameras of one scene pays the setup once:

>>> import tempfile
>>> import ibrtools
>>> from ibrtools import synth
>>> from ibrtools.formats import native
>>> folder = tempfile.mkdtemp()
>>> _ = native.save(synth.make_scene("objects", size=(64, 48), views=4, holdout_targets=1,
...                                  path_frames=2), folder + "/scene")
>>> scene = ibrtools.load_scene(folder + "/scene")
>>> [v.name for v in scene.views], [t.name for t in scene.targets]
(['v000', 'v001', 'v002', 'v003'], ['t000'])
>>> result = ibrtools.render(scene, "t000", method="dibr", inputs=2)   # a target's name
>>> result.method, result.color.shape, result.color.dtype, result.hole.shape
('dibr', (48, 64, 3), dtype('float32'), (48, 64))
>>> result.prepared                                          # this call prepared dibr
True
>>> again = ibrtools.render(scene, scene.paths["orbit"][0], method="dibr", inputs=2)   # a Camera
>>> again.prepared                                           # ... this one reused it
False
>>> sorted(again.times_ms)                  # the method's stages and the completion's, in ms
['background', 'blend', 'inpaint', 'select', 'total', 'warp']

A camera may also be a dict in the scene.json camera format, and ``look_at`` poses one:

>>> cam = ibrtools.Camera.from_fov(64, 48, 60.0, ibrtools.look_at((0.0, 1.5, 6.0), (0.0, 0.5, 0.0)))
>>> ibrtools.render(scene, cam.to_dict(), method="reference").color.shape
(48, 64, 3)

Bad input raises a typed error (:mod:`ibrtools.errors`) that names the argument:

>>> ibrtools.render(scene, "nowhere")
Traceback (most recent call last):
...
ibrtools.errors.BadValueError: camera 'nowhere': not a target or view of the scene (targets: t000; views: v000, v001, v002, v003)
>>> ibrtools.load_scene(folder + "/missing")
Traceback (most recent call last):
...
ibrtools.errors.MissingFileError: load_scene: .../missing: no such directory
>>> import shutil; shutil.rmtree(folder)
"""
from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence, Union

import numpy as np
import numpy.typing as npt

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, DtypeError, FormatError, MissingFileError
from ibrtools.formats.native import SCENE_FILE
from ibrtools.scene import LazyMeshes, Scene
from ibrtools import methods
from ibrtools.params import MethodParams
from ibrtools.synth import scene_spec as synth_scene_spec
from ibrtools.formats import native
from ibrtools.formats import yuv as yuv_format
from ibrtools.imageio import write_image
from ibrtools.metrics import DEFAULT_SCORES
from ibrtools.inpaint.complete import DEFAULT_INPAINT, check_inpaint, complete, completion, parse_background
from ibrtools.pipeline import job
from ibrtools.pipeline import plan as planning
from ibrtools.pipeline.importing import run_import
from ibrtools.pipeline.stages import preprocess as run_stages
from ibrtools.pipeline.sweep import sweep

if TYPE_CHECKING:
    from ibrtools.cache import StageResult

__all__ = ["CameraLike", "RenderResult", "bench", "clear_render_cache", "import_dataset", "load_scene", "preprocess",
           "render", "render_job", "resolve_camera", "save_scene"]

#: What :func:`render` accepts as a camera: a Camera, the name of one of the scene's
#: targets or views, or a dict in the scene.json camera format (docs/FORMAT.md).
CameraLike = Union[Camera, str, "dict[str, Any]"]

def load_scene(path: str | os.PathLike[str]) -> Scene:
    """Read a native ibrtools scene directory (or its ``scene.json``); images load lazily.

    Other data sets (COLMAP, NeRF, MPEG, Middlebury, RGB-D) are imported by
    ``ibr-preprocess`` or :func:`ibrtools.formats.load`, which return the same :class:`Scene`.

    Raises MissingFileError when ``path`` does not exist, FormatError when it is not a
    scene directory (a file, a directory without ``scene.json``) or the scene is malformed.

    >>> load_scene(__file__)
    Traceback (most recent call last):
    ...
    ibrtools.errors.FormatError: load_scene: .../api.py: a file, not a scene directory (expected a directory holding scene.json)
    """
    _check_path(path, "load_scene: path")
    p = Path(path)
    if not p.exists():
        raise MissingFileError(f"load_scene: {p}: no such directory")
    if p.is_file() and p.name != SCENE_FILE:
        raise FormatError(f"load_scene: {p}: a file, not a scene directory (expected a directory "
                          f"holding {SCENE_FILE})")
    if p.is_dir() and not (p / SCENE_FILE).is_file():
        raise FormatError(f"load_scene: {p}: no {SCENE_FILE} in this directory (not an ibrtools scene; "
                          "import other data sets with ibr-preprocess or ibrtools.formats.load)")

    scene: Scene = native.load(p)
    return scene


@dataclass(frozen=True, eq=False)
class RenderResult:
    """One rendered camera.

    ``color`` (H, W, 3) float32 linear RGB, C-contiguous, complete as the written images of
    ``ibr-render`` (the holes filled, or black with ``inpaint="none"``); ``depth`` (H, W) float32
    (0 = unknown, +inf = the background at infinity) and ``hole`` (H, W) bool (true = no input
    covers the pixel: the filled or black pixels) when the method gives them; ``selection`` (H, W, 3) float32 for
    the hybrid method (red PVM, green TM, blue ULR per pixel); ``alpha`` (H, W) float32 with
    ``background="transparent"`` (0 on the background at infinity); ``outputs`` every other array the
    method returned (dibr: "confidence"). ``times_ms`` the method's stage times plus "total"
    (wall time of this render); ``setup_ms`` the method's one-off preparation times;
    ``prepared`` whether this call paid them (False when the prepared method was reused).
    """

    color: npt.NDArray[np.float32]
    method: str
    camera: Camera
    depth: npt.NDArray[np.float32] | None = None
    hole: npt.NDArray[np.bool_] | None = None
    selection: npt.NDArray[np.float32] | None = None
    alpha: npt.NDArray[np.float32] | None = None
    outputs: dict[str, npt.NDArray[Any]] = field(default_factory=dict)
    times_ms: dict[str, float] = field(default_factory=dict)
    setup_ms: dict[str, float] = field(default_factory=dict)
    prepared: bool = False

    @property
    def coverage(self) -> float:
        """Fraction of pixels that are not holes (1.0 when the method reports no hole mask)."""
        return 1.0 if self.hole is None else float(1.0 - self.hole.mean())

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write ``color`` (with ``alpha`` when there is one) to ``path`` (PNG: 8-bit sRGB; EXR:
        linear float32), atomically."""
        p = Path(path)
        write_image(p, self.color if self.alpha is None else np.concatenate([self.color, self.alpha[..., None]], -1))
        return p


def resolve_camera(scene: Scene, camera: CameraLike) -> Camera:
    """The Camera that ``camera`` names: itself, a target or view of ``scene`` by name (targets
    first), or one read from a scene.json camera dict.

    >>> resolve_camera(Scene(), {"model": "pinhole", "width": 8, "cam_from_world": np.eye(4).tolist()})
    Traceback (most recent call last):
    ...
    ibrtools.errors.FormatError: camera: missing key 'height'
    """
    if isinstance(camera, Camera):
        return camera
    if isinstance(camera, str):
        for group in (scene.targets, scene.views):
            for v in group:
                if v.name == camera:
                    return v.camera
        raise BadValueError(f"camera {camera!r}: not a target or view of the scene (targets: "
                            f"{_some(t.name for t in scene.targets)}; views: {_some(v.name for v in scene.views)})")
    if isinstance(camera, dict):
        return Camera.from_dict(camera, "camera")
    raise DtypeError(f"camera: expected a Camera, a target or view name (str) or a scene.json camera "
                     f"dict, got {type(camera).__name__}")


def render(scene: Scene, camera: CameraLike, method: str = "auto", *, inpaint: str | None = None,
           background: Any = None, **params: Any) -> RenderResult:
    """Render ``camera`` of ``scene`` with ``method`` (:data:`ibrtools.methods.METHODS`;
    "auto" picks one from the scene's data) and the method's parameters (as ``ibr-render
    --param key=value``, e.g. ``inputs=2`` for dibr). Same as ``ibrtools.render(scene, ...)``. The image is
    complete as ``ibr-render`` writes it (inpaint/complete.py): the background at infinity where
    an input sees it, the holes filled by ``inpaint`` (``ibr-render --inpaint``; None = its
    default, "none" = black); ``background`` recolours the background at infinity as
    ``ibr-render --background`` does ("black", "white", (r, g, b) sRGB in [0, 1], or
    "transparent": ``alpha`` is then 0 there and ``color`` black).

    The method is prepared on the first call for a (method, parameters) pair and kept with the
    scene (it goes with the scene; a pickled or copied scene starts afresh) while the scene's views and meshes are the same
    objects; :func:`clear_render_cache` drops it. Calls on one scene are serialised (a lock):
    the prepared methods reuse their frame buffers.

    >>> render(Scene(), "t000", method="nerf")
    Traceback (most recent call last):
    ...
    ibrtools.errors.BadValueError: method: unknown method 'nerf' (expected one of auto, reference, dibr, warp, depthwarp, tm, ulr, pvm, hybrid)
    """
    if not isinstance(scene, Scene):
        raise DtypeError(f"scene: expected an ibrtools.Scene, got {type(scene).__name__}")
    if not isinstance(method, str):
        raise DtypeError(f"method: expected a method name (str), got {type(method).__name__}")
    if method not in methods.METHODS:
        raise BadValueError(f"method: unknown method {method!r} (expected one of {', '.join(methods.METHODS)})")
    inpaint = check_inpaint(DEFAULT_INPAINT if inpaint is None else inpaint)
    override = parse_background(background)
    cam = resolve_camera(scene, camera)
    name = methods.resolve(method, scene)
    cache = _cache_of(scene)
    with cache.lock:
        prepared, setup_ms, fresh = cache.method(scene, name, params)
        t0 = time.perf_counter()
        out, stage_ms = prepared.render(cam)
        done = complete(out, cam, *completion(prepared, scene, inpaint), override)  # as ibr-render writes its frames
        total_ms = (time.perf_counter() - t0) * 1e3
    color, hole, depth = done.color, done.hole, done.depth
    stage_ms = {**stage_ms, **done.stage_ms}
    selection = out.get("selection")
    rest = {k: v for k, v in out.items() if k not in ("color", "depth", "hole", "selection")}
    return RenderResult(
        color=color, method=name, camera=cam,
        depth=None if depth is None else np.ascontiguousarray(depth, np.float32), hole=hole,
        selection=None if selection is None else np.ascontiguousarray(selection, np.float32),
        alpha=done.alpha, outputs=rest, times_ms={**{k: float(v) for k, v in stage_ms.items()}, "total": total_ms},
        setup_ms=dict(setup_ms), prepared=fresh)


def save_scene(scene: Scene, path: str | os.PathLike[str]) -> Path:
    """Write ``scene`` as a native scene directory at ``path`` (scene.json, images, depth, meshes;
    docs/FORMAT.md), atomically; returns the directory. ``load_scene`` reads it back."""
    if not isinstance(scene, Scene):
        raise DtypeError(f"save_scene: scene: expected an ibrtools.Scene, got {type(scene).__name__}")
    _check_path(path, "save_scene: path")
    return Path(native.save(scene, path))


def import_dataset(source: str | os.PathLike[str], output: str | os.PathLike[str], *, format: str | None = None,
                   options: dict[str, Any] | None = None, holdout: list[str] | None = None,
                   mesh: str | os.PathLike[str] | None = None, downscale: float | None = None,
                   max_size: int | None = None, frames: str | None = None, synth: dict[str, Any] | None = None,
                   force: bool = False) -> Scene:
    """Import a data set (a directory or file of any supported layout: native, MPEG/RVS, COLMAP,
    NeRF, LLFF, Middlebury, RGB-D; ``synth:NAME`` for a synthetic scene; docs/importers.md) into a
    native scene at ``output`` and return it loaded. ``format`` names the layout (None: detected),
    ``options`` the importer's options (``ibr-preprocess --opt``), ``holdout`` input views to
    import as targets, ``mesh`` a reconstructed mesh of the capture, ``downscale`` / ``max_size``
    shrink the images, ``frames`` the frames of a video data set to import as a video scene ("A:B"
    for frames A to B - 1, "all", or "default": an RVS config's own); ``synth`` the keyword arguments of :func:`ibrtools.synth.make_scene` for a
    ``synth:NAME`` source (e.g. ``{"size": (64, 48), "views": 4}``; ``frames`` > 1 makes a video).
    Re-importing unchanged inputs does nothing (``force`` re-imports). The derived stages are
    :func:`preprocess`'s."""
    _check_path(source, "import_dataset: source")
    _check_path(output, "import_dataset: output")
    spec = os.fspath(source)
    made = None
    if isinstance(spec, str) and spec.startswith("synth:"):
        made = synth_scene_spec(spec, synth or {}, source_label="import_dataset: source",
                                options_label="import_dataset: synth")
    elif synth is not None:
        raise BadValueError(f"import_dataset: synth: only for a synth:NAME source, got source {spec!r}")
    run_import(str(spec), Path(output), fmt=format, options=options, synth=made, force=force, holdout=holdout,
               mesh=mesh, downscale=downscale, max_size=max_size, frames=frames)
    return load_scene(output)


def preprocess(scene: str | os.PathLike[str], *, methods: list[str] | None = None, stages: list[str] | None = None,
               stage_options: dict[str, dict[str, Any]] | None = None, threads: int = 0,
               workers: int = 0, scheduler: str | None = None,
               progress: Callable[[str], None] | None = None) -> list[StageResult]:
    """Run the derived stages (multi-view stereo, global mesh, depth, texture, per-view meshes,
    harmonisation, ...) that ``methods`` need (None: the methods that work from the views alone)
    on the scene directory ``scene`` (made by :func:`import_dataset` or :func:`save_scene`), or
    exactly ``stages``; up-to-date stages are not run again. ``stage_options`` are
    ``{stage: {key: value}}`` (``ibr-preprocess --set stage.key=value``). Returns one record per
    stage: its status (ran / up to date / skipped), the reason and the time (docs/preprocess.md)."""
    _check_path(scene, "preprocess: scene")
    if not (Path(scene) / SCENE_FILE).is_file():
        raise MissingFileError(f"preprocess: {scene}: no {SCENE_FILE} (import the data set first: import_dataset)")
    results: list[StageResult] = run_stages(os.fspath(scene), scene, methods=methods, stages=stages,
                                            stage_options=stage_options, threads=threads, workers=workers,
                                            scheduler=scheduler, progress=progress)
    return results


def render_job(scene: Scene, out_dir: str | os.PathLike[str], method: str = "auto", *,
               targets: list[str] | None = None, holdout: list[str] | None = None, path: str | None = None,
               path_frames: int | None = None, poses: str | os.PathLike[str] | None = None,
               params: Mapping[str, Any] | MethodParams | None = None,
               inpaint: str | None = None, background: str | None = None, float_out: bool = False,
               depth_out: bool = False, threads: int = 0, workers: int = 0,
               scheduler: str | None = None,
               yuv: str | os.PathLike[str] | Mapping[str, str | os.PathLike[str]] | None = None,
               yuv_bits: int | Mapping[str, int] = yuv_format.DEFAULT_BITS,
               metrics: str | Sequence[str] = DEFAULT_SCORES) -> dict[str, Any]:
    """Render many cameras as ``ibr-render`` does and write them to ``out_dir`` with report.json:
    the scene's targets (or ``targets`` by name), held-out input views scored against their own
    images (``holdout``), a camera path (``path``: stored in the scene, else generated:
    "interpolate", "spiral" or "orbit" of ``path_frames`` cameras, default 48; docs/render.md
    "Camera paths") or a pose file (``poses``: our camera list, a nerfstudio camera_path.json or
    a transforms.json); ``yuv``: also one raw YUV 4:2:0 file of every frame (``yuv_bits`` per
    sample; a name with ``{camera}``, or a mapping camera -> file: a file per camera;
    docs/render.md "YUV output"); ``metrics``: the scores of frames with ground truth ("all",
    "none", or names of psnr, ssim, flip; as ``ibr-render --metrics``). Returns the report (per-frame times per stage, metrics against ground truth when known;
    docs/render.md, docs/reports.md). All or nothing: an interrupt removes what the job wrote."""
    if not isinstance(scene, Scene):
        raise DtypeError(f"render_job: scene: expected an ibrtools.Scene, got {type(scene).__name__}")
    _check_path(out_dir, "render_job: out_dir")
    planned = planning.plan(scene, targets=targets, holdout=holdout, path=path, path_frames=path_frames,
                       poses=None if poses is None else os.fspath(poses))
    report: dict[str, Any] = job.run(planned, method, out_dir, params=params, float_out=float_out,
                                     depth_out=depth_out, threads=threads,
                                     inpaint=DEFAULT_INPAINT if inpaint is None else inpaint,
                                     background=background, scheduler=scheduler, workers=workers,
                                     yuv=yuv if yuv is None or isinstance(yuv, Mapping) else os.fspath(yuv),
                                     yuv_bits=yuv_bits, metrics=metrics)
    return report


def bench(scene: Scene, method: str, grid: dict[str, list[Any]], *, holdout: list[str] | None = None,
          base: dict[str, Any] | None = None, out_dir: str | os.PathLike[str] | None = None,
          inpaint: str | None = None) -> list[dict[str, Any]]:
    """Sweep ``method``'s parameters over ``grid`` ({parameter: [values]}, every combination, on
    top of ``base``) as ``ibr-bench`` does: each configuration renders the held-out views
    ``holdout`` (default: the scene's targets) after one warm-up; returns one row per
    configuration (parameters, median and per-stage times, mean metrics), also written as CSV /
    a table and a plot under ``out_dir`` when given (docs/sweep.md)."""
    if not isinstance(scene, Scene):
        raise DtypeError(f"bench: scene: expected an ibrtools.Scene, got {type(scene).__name__}")
    if not isinstance(grid, dict):
        raise DtypeError(f"bench: grid: expected a dict of parameter -> list of values, got {type(grid).__name__}")
    if out_dir is not None:
        _check_path(out_dir, "bench: out_dir")
    rows: list[dict[str, Any]] = sweep(scene, method, grid, holdout=holdout, base=base, out_dir=out_dir,
                                       inpaint=DEFAULT_INPAINT if inpaint is None else inpaint)
    return rows


def _check_path(value: Any, what: str) -> None:
    if not isinstance(value, (str, os.PathLike)):
        raise DtypeError(f"{what}: expected a str or os.PathLike, got {type(value).__name__}")



def clear_render_cache(scene: Scene) -> None:
    """Forget the methods :func:`render` prepared for ``scene`` (their memory is freed).
    Needed after changing a scene in place other than by replacing views or meshes."""
    scene.__dict__.pop(_ATTR, None)


# --- the prepared methods of each scene -------------------------------------------------------------
class _Cache:
    def __init__(self) -> None:
        self.lock = threading.RLock()
        # (method, frozen params) -> (signature of the scene's inputs, method, setup times)
        self.entries: dict[tuple[str, Any], tuple[tuple[Any, ...], Any, dict[str, float]]] = {}

    def method(self, scene: Scene, name: str, params: dict[str, Any]) -> tuple[Any, dict[str, float], bool]:
        key = (name, _freeze(params))
        # The objects themselves (held by the entry, so their ids cannot be reused meanwhile); a
        # scene's LazyMeshes by its identity and version, so that no mesh is read to compare.
        m = scene.meshes
        signature: tuple[Any, ...]
        if isinstance(m, LazyMeshes):
            signature = (tuple(scene.views), (("", m),), m.version, scene.root)
        else:
            signature = (tuple(scene.views), tuple(m.items()), None, scene.root)
        hashable = key[1] is not _UNHASHABLE
        entry = self.entries.get(key) if hashable else None
        if entry is not None and _same(entry[0], signature):
            return entry[1], entry[2], False
        prepared = methods.create(name, dict(params))
        setup = dict(prepared.prepare(scene))
        if hashable:
            self.entries[key] = (signature, prepared, setup)
        return prepared, setup, True

    def __reduce__(self) -> tuple[type[_Cache], tuple[()]]:
        # A pickled or copied scene (Dask scatters scenes to workers) starts with an empty cache:
        # prepared methods hold locks, BVHs and C++ objects that are not to be shipped.
        return (_Cache, ())


_CACHES_LOCK = threading.Lock()
_UNHASHABLE = object()
_ATTR = "_ibr_render_cache"


def _cache_of(scene: Scene) -> _Cache:
    """The scene's cache, kept as an attribute of the scene: it lives and dies with the scene
    (a prepared method may hold the scene: a side table keyed by the scene would keep it alive)."""
    with _CACHES_LOCK:
        cache = scene.__dict__.get(_ATTR)
        if not isinstance(cache, _Cache):
            cache = _Cache()
            scene.__dict__[_ATTR] = cache
        return cache


def _same(a: tuple[Any, ...], b: tuple[Any, ...]) -> bool:
    views_a, meshes_a, version_a, root_a = a
    views_b, meshes_b, version_b, root_b = b
    return (len(views_a) == len(views_b) and all(x is y for x, y in zip(views_a, views_b))
            and len(meshes_a) == len(meshes_b)
            and all(ka == kb and ma is mb for (ka, ma), (kb, mb) in zip(meshes_a, meshes_b))
            and version_a == version_b and root_a == root_b)


def _freeze(value: Any) -> Any:
    """A hashable, order-independent key for a parameter dict; _UNHASHABLE when there is none
    (the method is then prepared for this call only)."""
    if isinstance(value, dict):
        items = [(k, _freeze(v)) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))]
        return _UNHASHABLE if any(v is _UNHASHABLE for _, v in items) else ("dict", tuple(items))
    if isinstance(value, (list, tuple)):
        items2 = [_freeze(v) for v in value]
        return _UNHASHABLE if any(v is _UNHASHABLE for v in items2) else ("seq", tuple(items2))
    if isinstance(value, float) and math.isnan(value):
        return ("nan",)
    try:
        hash(value)
    except TypeError:
        return _UNHASHABLE
    return (type(value).__name__, value)


def _some(names: Any, k: int = 8) -> str:
    names = list(names)
    return ", ".join(names[:k]) + (f", ... ({len(names)} in all)" if len(names) > k else "") or "none"

