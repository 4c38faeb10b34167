"""Preprocessing stages and their planner (work that cannot change the result is skipped, with the reason).

A stage declares what it reads and what it is for; the planner runs it only when its
output is missing or its inputs or parameters changed (a content hash, stored in the
scene's ``scene.json`` under ``stages``), and reports every stage as ran / up to date /
skipped, with the reason and the time. ``import`` makes the scene; the derived stages of
hybrid IBR (global mesh, per-view depth from it, texture, variance, harmonisation,
per-view meshes and tiles) are declared in ``STAGES`` with their inputs, outputs and the
methods that need them, write under ``SCENE/cache/<stage>/`` and record their key and output
hashes in scene.json ``stages`` (docs/FORMAT.md "Cache", docs/preprocess.md).
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from ibrtools.cache import (available_stages, CACHE_DIR, default_methods, file_hash, StageResult,
                            load_npz, mvs_key, ORDER, output_intact, output_stats, read_doc, save_npz,
                            scene_content_key, stage_key, STAGES, stale_reasons, view_depths, with_stage_depth,
                            VIEW_ONLY_METHODS, write_stage_record)
from ibrtools.errors import BadValueError, InputError
from ibrtools.scene import Scene
from ibrtools.formats import native
from ibrtools.formats.resize import check_factors
from ibrtools.hybrid import atlas as A, harmonise as H
from ibrtools.hybrid.gainmodel import exposure_gains
from ibrtools.hybrid.globalmesh import (GlobalMeshOptions, build_global_mesh, build_render_mesh, check_fusion_memory,
                                       choose_source, depth_from_mesh, vertex_colors)
from ibrtools.hybrid.pvm import PvmOptions, build_tiles, view_mesh
from ibrtools.hybrid import variance as V
from ibrtools.mesh import Mesh
from ibrtools.outputs import scene_lock
from ibrtools.pipeline import distributed as D
from ibrtools.pipeline.distributed import check_options, set_task_threads
from ibrtools.pipeline.importing import run_import
from ibrtools.pipeline.mix import MIX_DEFAULTS, fit_pvm_floor


# ---------------------------------------------------------------------------------------------
# The preprocessing stages after import: declared once, planned per run.

# Methods and the stages they read (DESIGN.md "Commands"): reference/dibr/warp/depthwarp work
# from the views alone; tm needs the textured global mesh; ulr the global mesh as geometry proxy
# and per-view depth; pvm the per-view meshes (and the global mesh to pick voxels at render
# time); hybrid all of it plus the harmonised images.


# The stages that read _Context.vertex_statistics (released once none is left to run).
_READS_STATISTICS = frozenset({"texture", "variance"})


class _Context:
    """What the stages of one run share: the scene, its root, outputs already in memory, and
    the Dask cluster of a distributed run (``cluster``: a distributed.LazyClient, or None)."""

    def __init__(self, root: Path, options: dict, cluster=None):
        self.root = root
        self.scene: Scene = native.load(root)
        self.options = options
        self.memo: dict[str, dict] = {}
        self.cluster = cluster
        self.view_only = False  # _run_planned: only depth-image methods (dibr, warp, ...) asked for
        self._stats: dict[str, dict] = {}
        self._mvs_scene: Scene | None = None

    def cache(self, stage: str) -> Path:
        return self.root / CACHE_DIR / stage

    def mvs_scene(self) -> Scene:
        """The scene with the mvs stage's depth for the views without their own (read once per
        run, by the first stage after the mvs stage that asks: the mesh stage and its checks)."""
        if self._mvs_scene is None:
            self._mvs_scene = with_stage_depth(self.scene, ("mvs",))
        return self._mvs_scene

    def get(self, stage: str) -> dict:
        if stage not in self.memo:
            self.memo[stage] = load_npz(self.cache(stage) / STAGES[stage].outputs[0])
        return self.memo[stage]

    # -- inputs the stages share ---------------------------------------------------------------
    def cameras(self) -> dict:
        return {v.name: v.camera for v in self.scene.views}

    def depths(self, names: list[str] | None = None) -> dict:
        """Each view's depth (of the views ``names``, default all): its own, or the one the depth
        stage rendered from the mesh."""
        views = self.scene.views if names is None else [self.scene.view(n) for n in names]
        return view_depths(views, lambda: self.get("depth"))

    def mesh(self):
        """The dense global mesh (per-vertex statistics)."""
        d = self.get("mesh")
        return Mesh(d["vertices"], d["faces"], object_ids=d["object_ids"], kind="reconstructed")

    def vertex_statistics(self, render: bool) -> dict:
        """``variance.vertex_statistics`` of the views on the render mesh (``render``, the texture
        stage's gains) or the dense mesh (the variance stage), computed once per run: when the mesh
        stage stored no separate render mesh (a fused mesh, lego's) the two stages share one pass."""
        key = "render" if render and "render_vertices" in self.get("mesh") else "dense"
        if key not in self._stats:
            self._stats[key] = V.vertex_statistics(self.scene, self.render_mesh() if key == "render" else self.mesh())
        return self._stats[key]

    def release_statistics(self) -> None:
        self._stats.clear()

    def render_mesh(self):
        """The render mesh (G-buffer, atlas): the dense mesh when the mesh stage stored no other."""
        d = self.get("mesh")
        if "render_vertices" not in d:
            return self.mesh()
        return Mesh(d["render_vertices"], d["render_faces"], object_ids=d["render_object_ids"], kind="reconstructed")


def _params(name: str, options: dict) -> dict:
    if name in ("mesh", "texture", "depth"):
        o = GlobalMeshOptions(**options.get("mesh", {})).to_dict()
        if name == "mesh":
            return {k: o[k] for k in ("source", "resolution", "trunc_voxels", "max_edge_voxels", "max_faces",
                                      "render_edge_voxels")}
        if name == "texture":
            return {k: o[k] for k in ("k_views", "depth_tol", "atlas_texel", "atlas_max_texels", "atlas_adaptive",
                                      "gain_model", "gain_max_ratio", "bake_normal_rounds",
                                      "bake_label_weight", "fused_k_views", "fused_normal_rounds")}
        return {}
    if name == "pvm":
        return PvmOptions(**options.get("pvm", {})).to_dict()
    if name == "mvs":
        from ibrtools.mvs import MvsOptions

        return MvsOptions(**options.get("mvs", {})).to_dict()
    return dict(options.get(name, {}))


def _run_mesh(ctx: _Context) -> dict:
    opts = GlobalMeshOptions(**ctx.options.get("mesh", {}))
    scene = ctx.mvs_scene()  # photographs: their multi-view stereo depth is fused
    mesh, rec = build_global_mesh(scene, opts)
    arrays = {"vertices": mesh.vertices, "faces": mesh.faces, "object_ids": mesh.object_ids}
    render = build_render_mesh(scene, mesh, rec["source"], opts)
    if render is not mesh:
        arrays.update(render_vertices=render.vertices, render_faces=render.faces, render_object_ids=render.object_ids)
    rec["render_faces"] = int(len(render.faces))
    save_npz(ctx.cache("mesh") / "mesh.npz", **arrays)
    ctx.memo["mesh"] = arrays
    return rec


def _mvs_needed(ctx: _Context) -> str | None:
    if all(v.has_depth for v in ctx.scene.views):
        return "every view has depth"
    if ctx.scene.meshes:
        kind = "reconstructed" if "reconstructed" in ctx.scene.meshes else next(iter(ctx.scene.meshes))
        return f"the scene has a {kind} mesh (the depth stage renders it for the views without depth)"
    return None


def _run_mvs(ctx: _Context) -> dict:
    from ibrtools.mvs import MvsOptions, run_mvs

    opts = MvsOptions(**ctx.options.get("mvs", {}))
    names = [v.name for v in ctx.scene.views if not v.has_depth]
    res = run_mvs(ctx.scene.views, opts, names=names, run_pass=None if ctx.cluster is None else _mvs_on_workers(ctx),
                  bounds=ctx.scene.source.get("depth_bounds"),
                  background=(ctx.scene.shading or {}).get("background") is not None)
    if not any(np.any(np.isfinite(r.depth) & (r.depth > 0)) for r in res.values()):
        raise BadValueError(f"mvs: multi-view stereo matched no pixel in any of the {len(res)} views without depth "
                            "(textureless images, or cameras that do not see the same surfaces); give the views "
                            "depth or the scene a reconstructed mesh (ibr-preprocess ... --mesh FILE)")
    arrays = {}
    for n, r in res.items():
        arrays.update({mvs_key("depth", n): r.depth, mvs_key("normal", n): r.normal,
                       mvs_key("confidence", n): r.confidence})
    save_npz(ctx.cache("mvs") / "mvs.npz", **arrays)
    first = next(iter(res.values()))
    return {"views": len(res), "kept": round(float(np.mean([r.stats["kept"] for r in res.values()])), 4),
            "background_pixels": sum(r.stats["background"] for r in res.values()),
            "seconds": first.stats["seconds"], "evaluations_per_second": first.stats["evaluations_per_second"],
            "sources": {n: r.sources for n, r in res.items()},
            "depth_range": {n: [round(x, 6) for x in r.depth_range] for n, r in res.items()}}


_MVS_EXCHANGE = "photometric.npz"  # the photometric pass's results, for the geometric pass's tasks


def _mvs_on_workers(ctx: _Context):
    """run_mvs's ``run_pass`` on the Dask cluster: chunks of views per task (:func:`_mvs_task`);
    the geometric pass's tasks read the photometric results from a file in the stage's cache,
    removed afterwards."""
    def run_pass(which: str, names: list[str], previous: dict | None) -> dict:
        if previous is None:
            return ctx.cluster.map_views(_mvs_task, ctx.root, names, ctx.options, which)
        f = ctx.cache("mvs") / _MVS_EXCHANGE
        arrays = {mvs_key("known", m): d for m, d in previous["known"].items() if d is not None}
        for n, r in previous["results"].items():
            arrays.update({mvs_key("depth", n): r[0], mvs_key("normal", n): r[1]})
        save_npz(f, **arrays)
        try:
            return ctx.cluster.map_views(_mvs_task, ctx.root, names, ctx.options, which)
        finally:
            f.unlink(missing_ok=True)

    return run_pass


def _mvs_task(root: str, names: list[str], options: dict, which: str, threads: int) -> dict:
    """Dask task of the mvs stage: pass ``which`` ("photometric", or "geometric" from the
    photometric results the stage put in its cache) of views ``names``."""
    from ibrtools.mvs import MvsOptions
    from ibrtools.mvs.stereo import MvsRun

    set_task_threads(threads)
    ctx = _Context(Path(root), options)
    views = ctx.scene.views
    run = MvsRun(views, MvsOptions(**options.get("mvs", {})), [v.name for v in views if not v.has_depth],
                 ctx.scene.source.get("depth_bounds"))
    if which == "photometric":
        return {n: run.photometric(n) for n in names}
    first = load_npz(ctx.cache("mvs") / _MVS_EXCHANGE)
    known = {m: first.get(mvs_key("known", m)) for n in names for m in run.sources[n]}
    return {n: run.geometric(n, (first[mvs_key("depth", n)], first[mvs_key("normal", n)]), known) for n in names}


def _depth_needed(ctx: _Context) -> str | None:
    missing = [v.name for v in ctx.scene.views if not v.has_depth]
    return None if missing else "every view has depth"


def _served_by_views(ctx: _Context) -> str | None:
    """The mesh and depth stages when only depth-image methods are asked for: they serve those
    the depth of views without any, so they are not needed when every view has depth of its own
    or from the mvs stage (a scene with a mesh and views without depth: they run)."""
    if ctx.view_only and all(v.has_depth for v in ctx.mvs_scene().views):
        return "every view has depth"
    return None


def _run_depth(ctx: _Context) -> dict:
    cams = {v.name: v.camera for v in ctx.scene.views if not v.has_depth}
    if ctx.cluster is not None:  # per view: chunks of views on the workers, each loads the mesh
        deps = ctx.cluster.map_views(_depth_task, ctx.root, list(cams), ctx.options)
    else:
        deps = depth_from_mesh(ctx.mesh(), cams)
    save_npz(ctx.cache("depth") / "depth.npz", **deps)
    ctx.memo["depth"] = deps
    return {"views": len(deps)}


def _run_texture(ctx: _Context) -> dict:
    opts = GlobalMeshOptions(**ctx.options.get("mesh", {}))
    # A fused mesh blends more views on smoothed normals (GlobalMeshOptions.texture_options).
    opts = opts.texture_options(choose_source(ctx.scene, opts.source))
    mesh, cams, deps = ctx.render_mesh(), ctx.cameras(), ctx.depths()
    # The views with their global per-channel gain divided out (variance.vertex_statistics on the
    # render mesh: the gains, geometric mean 1 over the views, as the variance stage estimates them
    # on the dense mesh): the atlas then has one exposure, the one the harmonised images ULR blends
    # are brought to, instead of a blend-weighted mix of the views' exposures (docs/texture.md
    # "Atlas").
    # Only the part of the gains that looks like exposure (hybrid/gainmodel.py, gain_model): a
    # gain that follows the viewing direction smoothly is shading, which the texture keeps.
    st = ctx.vertex_statistics(render=True)
    gains = st["gains"]
    spread = round(float(np.ptp(np.log([np.asarray(g) for g in gains.values()]))), 4) if gains else 0.0
    # What is not global (the halves of a view's image disagree) is shrunk away (gainmodel.py).
    gains, gain_rec = exposure_gains(gains, cams, mode=opts.gain_model, max_ratio=opts.gain_max_ratio,
                                     half_gains=st["half_gains"] or None)
    colors = {v.name: (v.color / np.asarray(gains.get(v.name, np.ones(3)), np.float32)[None, None]).astype(np.float32)
              for v in ctx.scene.views}
    col, seen = vertex_colors(mesh, cams, colors, deps, opts)
    rec = {"vertices": int(len(col)), "unseen": int((seen == 0).sum()), "gain_spread": spread,
           "gain_model": gain_rec["model"], "gain_ratio": gain_rec["ratio"], "gain_shrink": gain_rec["shrink"],
           "k_views": opts.k_views,
           "normal_rounds": opts.bake_normal_rounds}
    arrays = {"vertex_colors": col, "seen": seen}
    # The atlas: per-texel colour at about the input views' resolution; a mesh with too
    # many faces for atlas_max_texels keeps the per-vertex colour only (TM renders that).
    try:
        texel = opts.atlas_texel * A.texel_size(cams, deps)
        scale = A.face_footprint_scale(mesh, cams, texel) if opts.atlas_adaptive else None
        lay = A.layout(mesh, texel, opts.atlas_max_texels, face_scale=scale)
    except BadValueError as e:
        rec["atlas"] = f"none ({e})"
    else:
        img, unseen = A.bake(mesh, lay, cams, colors, deps, col, opts)
        # Stored as 8-bit sRGB RGBA (A.to_srgb8): a third of the bytes of float32 RGB, which is what
        # the TM read is bound by (cache misses; cpp/kernels/hybrid/atlas8.h); 8-bit sRGB is the inputs' own
        # precision.
        arrays.update(atlas=A.to_srgb8(img), uv=lay.uv)
        rec.update(atlas=f"{img.shape[1]}x{img.shape[0]}", texel=float(f"{lay.texel:.4g}"),
                   unseen_texels=round(unseen, 4))
    save_npz(ctx.cache("texture") / "texture.npz", **arrays)
    ctx.memo["texture"] = arrays
    return rec


def _run_variance(ctx: _Context) -> dict:
    # One statistics pass gives the variance mesh and the gain-compensated vertex means, which
    # the harmonise stage uses as its T (saves it a second pass over the views).
    st = ctx.vertex_statistics(render=False)
    std = np.asarray(st["std"], np.float32)
    mean = np.asarray(st["mean"], np.float32)
    save_npz(ctx.cache("variance") / "variance.npz", std=std, mean=mean)
    ctx.memo["variance"] = {"std": std, "mean": mean}
    return {"vertices": int(len(std)), "mean_std": round(float(std.mean()), 5) if len(std) else 0.0}


def _run_harmonise(ctx: _Context) -> dict | str:
    opts = ctx.options.get("harmonise") or {}
    params = H.HarmoniseParams(**opts) if opts and hasattr(H, "HarmoniseParams") else None
    var = ctx.get("variance")
    # T = the gain-compensated vertex means the variance stage computed (t_source "views"; an
    # older cache entry without them: harmonise computes them itself).
    views_t = (params is None or params.t_source == "views") and "mean" in var
    res = H.harmonise(ctx.scene, ctx.mesh(), var["std"], params=params, colors=var["mean"] if views_t else None)
    if getattr(res, "skipped_reason", None):
        return str(res.skipped_reason)
    arrays = {}
    for n, img in res.images.items():
        arrays[f"image/{n}"] = np.asarray(img, np.float32)
    for n, m in res.masks.items():
        arrays[f"mask/{n}"] = np.asarray(m, bool)
    arrays["vd_texture"] = np.asarray(res.vd_texture, np.float32)
    render = ctx.render_mesh()
    if len(render.vertices) != len(res.vd_texture) or not np.array_equal(render.vertices, ctx.mesh().vertices):
        arrays["vd_render"] = H.vd_at_points(ctx.mesh().vertices, res.vd_texture, render.vertices)
    save_npz(ctx.cache("harmonise") / "harmonise.npz", **arrays)
    stats = {k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in (res.stats or {}).items()
             if isinstance(v, (int, float, str))}
    return {"views": len(res.images), **stats}


def _depth_task(root: str, names: list[str], options: dict, threads: int) -> dict:
    """Dask task of the depth stage: depth of views ``names`` rendered from the stage's mesh."""
    set_task_threads(threads)
    ctx = _Context(Path(root), options)
    return depth_from_mesh(ctx.mesh(), {n: ctx.scene.view(n).camera for n in names})


def _pvm_task(root: str, names: list[str], options: dict, threads: int) -> dict:
    """Dask task of the pvm stage: the per-view meshes of views ``names``."""
    set_task_threads(threads)
    ctx = _Context(Path(root), options)
    opts = PvmOptions(**options.get("pvm", {}))
    deps = ctx.depths(names)
    snap = _pvm_snap(ctx, opts)
    mesh_deps = _pvm_mesh_depths(ctx, names, snap)
    return {n: view_mesh(ctx.scene.view(n).camera, deps[n], opts, mesh_depth=mesh_deps.get(n), snap=snap)
            for n in names}


def _pvm_mesh_depths(ctx: _Context, names: list[str], snap: float) -> dict:
    """The global mesh's depth in each of the views ``names`` that has its own depth, for snapping
    the per-view meshes (hybrid/pvm.py view_mesh; {} when ``snap`` is 0). Views without their own
    depth have the mesh's already (the depth stage)."""
    own = [n for n in names if ctx.scene.view(n).has_depth]
    if snap <= 0 or not own:
        return {}
    return depth_from_mesh(ctx.mesh(), {n: ctx.scene.view(n).camera for n in own})


def _pvm_snap(ctx: _Context, opts) -> float:
    """``mesh_snap`` voxels of the mesh stage's record in world units (0: off, or no voxel recorded)."""
    voxel = (((read_doc(ctx.root).get("stages") or {}).get("mesh") or {}).get("details") or {}).get("voxel")
    return float(opts.mesh_snap * voxel) if isinstance(voxel, (int, float)) and voxel > 0 else 0.0


def _run_pvm(ctx: _Context) -> dict:
    opts = PvmOptions(**ctx.options.get("pvm", {}))
    cams = ctx.cameras()
    snap = _pvm_snap(ctx, opts)
    if ctx.cluster is not None:  # the per-view meshes on the workers, the slicing here
        meshes = ctx.cluster.map_views(_pvm_task, ctx.root, list(cams), ctx.options)
        tiles = build_tiles(cams, {}, opts, view_meshes=meshes)
    else:
        tiles = build_tiles(cams, ctx.depths(), opts, mesh_depths=_pvm_mesh_depths(ctx, list(cams), snap), snap=snap)
    tiles.save(ctx.cache("pvm") / "tiles.npz")
    s = tiles.stats
    if not any(v.has_depth for v in ctx.scene.views):
        snapped: float | str = "not needed: no view has its own depth"
    else:
        snapped = float(f"{snap:.4g}") if snap > 0 else "off"
    return {"pvm_faces": s["pvm_faces"], "tiles": s["tiles"], "tile_faces": s["tile_faces"], "snap": snapped}


def _run_mix(ctx: _Context) -> dict | str:
    opts = {**MIX_DEFAULTS, **ctx.options.get("mix", {})}
    res = fit_pvm_floor(ctx.scene, views=opts["views"], tol_db=opts["tol_db"])
    if isinstance(res, str):
        return res
    save_npz(ctx.cache("mix") / "mix.npz", **{k: np.asarray(v) for k, v in res.items()})
    mean = res["psnr"].mean(axis=0)
    return {"pvm_floor": res["pvm_floor"], "views": len(res["views"]),
            "psnr_gain_db": round(float(mean[list(res["floors"]).index(res["pvm_floor"])] - mean[0]), 4)}


_RUN = {"mvs": _run_mvs, "mesh": _run_mesh, "depth": _run_depth, "texture": _run_texture, "variance": _run_variance,
        "harmonise": _run_harmonise, "pvm": _run_pvm, "mix": _run_mix}
_APPLIES = {"mvs": _mvs_needed, "depth": _depth_needed}
# Stages that the methods asked for need only on some scenes (their records are kept when not).
_SERVES = {"mesh": _served_by_views, "depth": _served_by_views}


def _check_mesh(ctx: _Context) -> None:
    """Before the mesh stage is announced: TSDF fusion's memory estimate (a refusal is then the
    command's only line; build_global_mesh checks it again for the Python API)."""
    opts = GlobalMeshOptions(**ctx.options.get("mesh", {}))
    scene = ctx.mvs_scene()
    if choose_source(scene, opts.source) == "fusion":
        views = scene.views
        check_fusion_memory({v.name: v.camera for v in views}, {v.name: v.fusion_depth for v in views}, opts)


def _check_mvs(ctx: _Context) -> None:
    """Before the mvs stage is announced: its memory estimate (a refusal is the command's only line)."""
    from ibrtools.mvs.stereo import check_memory

    check_memory(ctx.scene.views)


# Checks of a stage that is about to run, before its progress line (a refusal is one line).
_PRECHECK = {"mesh": _check_mesh, "mvs": _check_mvs}


def _closure(selected: list[str]) -> list[str]:
    """``selected`` and every stage they read, in pipeline order."""
    need = set(selected)
    changed = True
    while changed:
        changed = False
        for s in list(need):
            for i in STAGES[s].inputs:
                if i in STAGES and i not in need:
                    need.add(i)
                    changed = True
    return [s for s in ORDER if s in need]


def run_stages(root: str | os.PathLike, *, methods: list[str] | None = None, stages: list[str] | None = None,
               force: bool = False, options: dict | None = None, progress=None,
               scheduler: str | None = None, workers: int = 0, threads: int = 0) -> list[StageResult]:
    """Plan and run the derived stages of the scene at ``root`` for ``methods`` (default:
    :func:`default_methods`), or exactly ``stages`` (plus what they read). Every available stage
    gets a row: ran / up to date / skipped (with the reason) / failed.

    ``workers`` N (a local Dask cluster) or ``scheduler`` ADDRESS: the per-view work of the
    stages that are per view (depth: each view's depth rendered from the mesh; pvm: each view's
    mesh) runs on the workers, which load the scene by path; the global stages (mesh fusion,
    texture, variance, harmonise, the PVM tiling) run here. The cluster is started only when such
    a stage runs; outputs are the same, bit for bit (docs/distributed.md). ``threads``: engine
    threads per task (default 1: a Dask worker thread is a core)."""
    D.check_options(scheduler, workers)
    root = Path(root)
    options = dict(options or {})
    methods = list(methods) if methods is not None else default_methods()
    avail = available_stages()
    if stages is not None:
        wanted = _closure([s for s in stages])
        why = {s: ("selected" if s in stages else
                   "read by " + ", ".join(t for t in stages if s in _closure([t]) and t != s)) for s in wanted}
    else:
        wanted = _closure([s for s in avail if STAGES[s].methods & set(methods)])
        why = {s: "needed by " + ", ".join(m for m in methods if m in STAGES[s].methods) for s in wanted}
        for s in wanted:
            if why[s] == "needed by ":
                why[s] = "read by a needed stage"
    wanted = [s for s in wanted if s in avail]
    if not wanted:  # nothing to plan: no scene load, no hashing (the plain import stays fast)
        reason = ("not selected" if stages is not None else
                  f"not needed by methods {', '.join(methods) or 'none'}")
        return [StageResult(name, "skipped", reason) for name in ORDER if name in avail]
    with D.LazyClient(scheduler, workers, threads) as cluster:
        return _run_planned(root, options, wanted, why, avail, stages, methods, force, progress,
                            cluster if D.wanted(scheduler, workers) else None)


def _run_planned(root: Path, options: dict, wanted: list[str], why: dict, avail: list[str], stages, methods,
                 force: bool, progress, cluster) -> list[StageResult]:
    ctx = _Context(root, options, cluster)
    # Only depth-image methods asked for (not --stages): the mesh and depth stages serve them only
    # the depth of views that have none (_served_by_views).
    ctx.view_only = stages is None and set(methods) <= set(VIEW_ONLY_METHODS)
    upstream: dict[str, str] = {}

    def scene_key() -> str:
        """The imported scene's content key, hashed on first need only: a run whose stages are all
        skipped by their checks (a plain import of views with depth) hashes nothing."""
        if "scene" not in upstream:
            upstream["scene"] = scene_content_key(root)
        return upstream["scene"]

    records = dict(read_doc(root).get("stages") or {})
    results: list[StageResult] = []
    planned = [s for s in ORDER if s in avail]
    for i, name in enumerate(planned):
        if not _READS_STATISTICS & set(planned[i:]).intersection(wanted):
            ctx.release_statistics()  # no later stage reads them (lego: 0.3 GB off the run's peak)
        st = STAGES[name]
        unserved = _SERVES[name](ctx) if name in wanted and name in _SERVES else None
        if name not in wanted or unserved:
            reason = ("not selected" if stages is not None else
                      f"not needed by methods {', '.join(methods) or 'none'}")
            if unserved:
                reason += f" ({unserved})"
            if records.get(name):  # the stages that ran before it in this run are on disk now
                stale = stale_reasons(read_doc(root).get("stages") or {}, name, scene_key())
                if stale:
                    reason += f"; its output is out of date ({'; '.join(stale)})"
            results.append(StageResult(name, "skipped", reason))
            continue
        not_needed = _APPLIES[name](ctx) if name in _APPLIES else None
        rec = records.get(name)
        if not_needed:
            upstream[name] = "not needed"  # readers' keys do not depend on what it would read
            results.append(StageResult(name, "skipped", not_needed))
            if rec is not None:
                write_stage_record(root, name, None)
            continue
        scene_key()
        params = _params(name, options)
        key = stage_key(st, params, upstream)
        upstream[name] = key
        provenance = {"version": st.version, "inputs": {k: upstream.get(k) for k in st.inputs}}
        if not force and rec and rec.get("key") == key:
            # A record from before records carried the version and input keys: the key matched, so they
            # are this run's; recorded below.
            unrecorded = any(rec.get(k) != v for k, v in provenance.items())
            if rec.get("skipped"):
                if unrecorded:
                    write_stage_record(root, name, {**rec, **provenance})
                results.append(StageResult(name, "skipped", f"{rec['skipped']} (inputs unchanged)"))
                continue
            bad = [rel for rel in rec.get("outputs") or {} if not output_intact(ctx.cache(name) / rel, rec, rel)]
            if not bad and rec.get("outputs"):
                stat = output_stats(ctx.cache(name), rec["outputs"])
                # Hashed intact (copied, or recorded without them), or unrecorded provenance: record them.
                if rec.get("stat") != stat or unrecorded:
                    write_stage_record(root, name, {**rec, "stat": stat, **provenance})
                results.append(StageResult(name, "up to date", "inputs and parameters unchanged",
                                           0.0, dict(rec.get("details") or {})))
                continue
            reason = f"output {bad[0]} missing or corrupt"
        else:
            reason = "forced" if force else ("inputs or parameters changed" if rec else "no output yet")
        if name in _PRECHECK:
            _PRECHECK[name](ctx)
        if progress is not None:
            progress(f"{name}: running ({reason}) - {st.description}")
        t0 = time.perf_counter()
        # Outputs are replaced atomically; a stale record is removed first so that a failure
        # part-way never leaves a record naming an old output as current.
        if rec is not None:
            write_stage_record(root, name, None)
        details = _RUN[name](ctx)
        seconds = time.perf_counter() - t0
        if isinstance(details, str):  # the stage decided it has nothing to do (e.g. harmonise)
            write_stage_record(root, name, {"key": key, "skipped": details, "params": params, **provenance})
            results.append(StageResult(name, "skipped", details, seconds))
            continue
        outputs = {rel: file_hash(ctx.cache(name) / rel) for rel in st.outputs}
        write_stage_record(root, name, {"key": key, **provenance, "params": params, "outputs": outputs,
                                         "stat": output_stats(ctx.cache(name), st.outputs),
                                         "seconds": round(seconds, 4), "details": details,
                                         "why": why.get(name, "")})
        results.append(StageResult(name, "ran", f"{reason}; {why.get(name, '')}", seconds, details))
    return results


def preprocess(input_spec: str, output: str | os.PathLike, *, fmt: str | None = None,
               options: dict | None = None, synth: dict | None = None, force: bool = False,
               methods: list[str] | None = None, stages: list[str] | None = None,
               stage_options: dict | None = None, progress=None, scheduler: str | None = None,
               workers: int = 0, threads: int = 0, holdout: list[str] | None = None,
               mesh: str | os.PathLike | None = None, downscale: float | None = None,
               max_size: int | None = None, frames: str | None = None) -> list[StageResult]:
    """Import (or find up to date) the scene, then run the derived stages ``methods`` need (or
    exactly ``stages``); returns the stage table. ``scheduler`` / ``workers`` / ``threads``: the
    per-view stages on Dask (:func:`run_stages`). ``holdout``: input views imported as targets,
    ``mesh``: a user's reconstructed mesh imported with the views, ``downscale`` / ``max_size``: the
    views resized on import, ``frames`` the frames of a video data set ("A:B", "all", "default";
    :func:`run_import`)."""
    check_options(scheduler, workers)
    check_factors(downscale, max_size)  # usage errors before the scene directory is touched
    if stages is not None:
        stages = [s for s in stages if s != "import"]
    if stage_options:
        _check_stage_options(stage_options)
    if str(output).strip() == "":
        raise BadValueError("-o: empty; give the scene directory to write")
    # The scene is this run's until it ends (a second run on it is refused), and what a killed
    # run left (temporaries, half-written scene directories) is swept first (ibrtools.outputs).
    with scene_lock(output) as lock:
        results = [run_import(input_spec, Path(output), fmt=fmt, options=options, synth=synth, force=force,
                              holdout=holdout, mesh=mesh, downscale=downscale, max_size=max_size,
                              frames=frames)]
        if lock.swept:
            results[0].details["swept"] = len(lock.swept)
        if stages == []:
            return results
        doc = read_doc(Path(output))
        for frame in doc.get("frames") or [None]:  # a video scene: the stages of every frame, in order
            rows = run_stages(Path(output) if frame is None else Path(output) / "frames" / frame, methods=methods,
                              stages=stages, force=force, options=stage_options, progress=progress,
                              scheduler=scheduler, workers=workers, threads=threads)
            for r in rows:
                r.name = r.name if frame is None else f"{frame}/{r.name}"
            results += rows
    return results


def _check_stage_options(options: dict) -> None:
    """Fail on unknown parameters before any work is done."""
    from ibrtools.mvs import MvsOptions

    classes = {"mesh": GlobalMeshOptions, "pvm": PvmOptions, "mvs": MvsOptions}
    if "harmonise" in options and "harmonise" in available_stages():
        from ibrtools.hybrid import harmonise as H

        if hasattr(H, "HarmoniseParams"):
            classes["harmonise"] = H.HarmoniseParams
    if "mix" in options:
        from ibrtools.pipeline.mix import check_mix_options

        check_mix_options(options["mix"])
    import dataclasses

    for stage, kw in options.items():
        cls = classes.get(stage)
        if cls is None:
            continue
        known = [f.name for f in dataclasses.fields(cls)] if dataclasses.is_dataclass(cls) else None
        unknown = sorted(set(kw) - set(known)) if known is not None else []
        if unknown:
            raise BadValueError.about("stage_options", f"unknown parameter of stage {stage!r} "
                                                       f"(parameters: {', '.join(known)})", f"{stage}.{unknown[0]}")
        try:
            cls(**kw)
        except InputError as e:  # a bad value (or type): name the --set that gave it
            key = max((k for k in kw if k in str(e).split(":", 1)[0]), key=len, default=None)
            given = f"{stage}.{key}={kw[key]}" if key is not None else f"{stage}.*"
            raise BadValueError.about("stage_options", str(e), given) from None
        except TypeError as e:  # a class that is not a dataclass: its own words
            raise BadValueError.about("stage_options", str(e), f"{stage}.*") from None
