"""The scene's cache of preprocessing results: the stage table (what each derived stage reads,
writes and is for), the records of scene.json ``stages`` (content keys and output hashes) and
the readers the methods use (``stage_output``, ``load_npz``, the views' stage depth).

The planner and the runners that write the cache are :mod:`ibrtools.pipeline.stages`; this
module is what a renderer may read without depending on the pipeline (docs/FORMAT.md "Cache").
"""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ibrtools.errors import BadValueError, InputError, MissingFileError
from ibrtools.formats.native import SCENE_FILE
from ibrtools.scene import Scene
from ibrtools.imageio import atomic_path


_HASH_CHUNK = 1 << 20


def hash_inputs(path: Path, params: dict) -> str:
    """Content hash of a file or a directory tree (relative names and bytes) and ``params``."""
    h = hashlib.blake2b(digest_size=16)
    h.update(json.dumps(params, sort_keys=True, default=str).encode())
    path = Path(path)
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        rel = f.name if f == path else f.relative_to(path).as_posix()
        h.update(rel.encode() + b"\0")
        with open(f, "rb") as fh:
            while chunk := fh.read(_HASH_CHUNK):
                h.update(chunk)
    return h.hexdigest()


def existing_record(output: Path, stage: str) -> dict | None:
    f = output / "scene.json"
    if not f.is_file():
        return None
    try:
        with open(f, encoding="utf-8") as fh:
            return (json.load(fh).get("stages") or {}).get(stage)
    except (OSError, ValueError, AttributeError):
        return None  # unreadable: treat as absent and rebuild


CACHE_DIR = "cache"




@dataclass(frozen=True)
class Stage:
    """One derived stage: what it reads, writes and is for.

    ``inputs``: upstream stages whose outputs it reads (their keys enter its key; "scene" is the
    imported scene's content: scene.json less its stage records, plus every file it names).
    ``outputs``: files it writes under ``SCENE/cache/<name>/``. ``methods``: the render methods
    that need it. ``params``: its parameters (hashed). ``version``: bump when the code changes
    what it writes."""

    name: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    methods: frozenset[str]
    description: str
    version: int = 1


STAGES: dict[str, Stage] = {s.name: s for s in (
    Stage("mvs", ("scene",), ("mvs.npz",), frozenset({"dibr", "warp", "tm", "ulr", "pvm", "hybrid"}),
          "per-view depth, normal and confidence by PatchMatch multi-view stereo, for the views without depth "
          "(photographs and cameras; docs/mvs.md)", version=2),
    Stage("mesh", ("scene", "mvs"), ("mesh.npz",), frozenset({"tm", "ulr", "pvm", "hybrid"}),
          "global mesh: reconstructed mesh, else TSDF fusion of the depth maps, else ground truth; "
          "dense (per-vertex statistics) and render (G-buffer, atlas) versions of the same surface",
          version=3),  # 3: fusion by open3d's sparse VoxelBlockGrid (was the dense UniformTSDFVolume)
    Stage("depth", ("scene", "mesh"), ("depth.npz",), frozenset({"dibr", "warp", "ulr", "pvm", "hybrid"}),
          "per-view depth rendered from the global mesh, for views without depth"),
    Stage("texture", ("scene", "mesh", "depth"), ("texture.npz",), frozenset({"tm", "hybrid"}),
          "texture atlas and per-vertex colour of the render mesh by ULR-weighted blending of the "
          "gain-compensated views", version=8),
    Stage("variance", ("scene", "mesh", "depth"), ("variance.npz",), frozenset({"hybrid"}),
          "per-vertex photometric standard deviation across the views that see it"),
    Stage("harmonise", ("scene", "mesh", "variance"), ("harmonise.npz",), frozenset({"hybrid"}),
          "diffuse harmonisation (exposure gains, or the paper's local ratio field and Poisson re-injection), "
          "graph-cut view-dependent masks", version=5),
    Stage("pvm", ("scene", "mesh", "depth"), ("tiles.npz",), frozenset({"pvm", "hybrid"}),
          "per-view meshes (depth within mesh_snap voxels of the global mesh's snapped to it, merge tolerance "
          "matched to the depth noise) sorted into a two-level voxel grid of tiles (cubic cells; triangles "
          "whole)",
          version=5),  # 4: mesh_snap; 5: clip "large" (triangles whole, not clipped to the cells)
    Stage("mix", ("scene", "mesh", "depth", "texture", "harmonise", "pvm"), ("mix.npz",), frozenset({"hybrid"}),
          "the hybrid composite's PVM weight floor (pvm_floor), fitted on leave-one-out renders of input views",
          version=4),  # 2: the G-buffer of a mesh dense for the frame ray cast (hybrid/method.py RASTER_MAX_FACES);
    # 3: tol_db 0 (the best floor; was the smallest within 0.01 dB of it); 4: PVM colours with the stretch term
    # (hybrid/pvm_render.py stretch_weight)
)}


ORDER = tuple(STAGES)


ALL_METHODS = ("reference", "dibr", "warp", "depthwarp", "tm", "ulr", "pvm", "hybrid")


def available_stages() -> list[str]:
    """Stages whose code exists in this build: variance and harmonise come from
    ibrtools.hybrid.variance / .harmonise and are absent from the table until those land."""
    import importlib.util

    out = []
    for name in ORDER:
        if name in ("variance", "harmonise"):
            mod = "ibrtools.hybrid." + name
            try:
                if importlib.util.find_spec(mod) is None:
                    continue
            except ImportError:
                continue
        out.append(name)
    return out


def file_hash(path: Path) -> str:
    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as fh:
        while chunk := fh.read(_HASH_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def _file_stat(path: Path) -> list[int]:
    st = path.stat()
    return [int(st.st_size), int(st.st_mtime_ns)]


def output_stats(cache: Path, rels) -> dict[str, list[int]]:
    """The record's ``stat``: each output's size and modification time (ns)."""
    return {rel: _file_stat(cache / rel) for rel in rels}


def output_intact(path: Path, rec: dict, rel: str) -> bool:
    """True when output ``rel`` of the stage record ``rec`` is at ``path`` with the content the
    record names: its size and modification time as recorded when the stage wrote it (outputs are
    written whole, then renamed), else (a copied scene, an older record without them, a changed
    file) its hash. A change that keeps both the size and the modification time to the nanosecond
    is not detected (as make and rsync); every other one, a torn write included, is."""
    if not path.is_file():
        return False
    if _file_stat(path) == (rec.get("stat") or {}).get(rel):
        return True
    return file_hash(path) == rec["outputs"][rel]


def scene_content_key(root: Path) -> str:
    """Content hash of an imported scene: scene.json without its stage records, and the bytes
    of every file it names (views, targets, meshes)."""
    if not (root / SCENE_FILE).is_file():
        raise MissingFileError(f"{root / SCENE_FILE}: no such file (not an imported scene)")
    with open(root / SCENE_FILE, encoding="utf-8") as fh:
        doc = json.load(fh)
    doc.pop("stages", None)
    h = hashlib.blake2b(digest_size=16)
    h.update(json.dumps(doc, sort_keys=True).encode())
    rels = []
    for group in ("views", "targets"):
        for e in doc.get(group, []):
            rels += [e[k] for k in ("color", "depth", "mask", "depth_stored") if isinstance(e, dict) and e.get(k)]
    mesh_files = [root / m["path"] for m in (doc.get("meshes") or {}).values() if isinstance(m, dict) and "path" in m]
    cache = (root / CACHE_DIR).resolve()
    for d in sorted({f.parent for f in mesh_files}):
        # Meshes with their sidecars, materials and textures: their whole directory, unless it is
        # the scene root (then the mesh file and its "<name>.*" sidecars), never the cache.
        files = (sorted(d.rglob("*")) if d.resolve() != root.resolve() else
                 sorted(p for f in mesh_files if f.parent == d for p in [f, *d.glob(f.name + ".*")]))
        rels += [p.relative_to(root).as_posix() for p in files
                 if p.is_file() and cache not in p.resolve().parents]
    for rel in rels:
        f = root / rel
        h.update(rel.encode() + b"\0")
        h.update(file_hash(f).encode() if f.is_file() else b"missing")
    return h.hexdigest()


def stage_key(stage: Stage, params: dict, upstream: dict[str, str]) -> str:
    h = hashlib.blake2b(digest_size=16)
    h.update(json.dumps({"stage": stage.name, "version": stage.version, "params": params,
                         "inputs": {k: upstream.get(k) for k in stage.inputs}}, sort_keys=True).encode())
    return h.hexdigest()


def read_doc(root: Path) -> dict:
    with open(root / SCENE_FILE, encoding="utf-8") as fh:
        return json.load(fh)


def write_stage_record(root: Path, name: str, record: dict | None) -> None:
    """Update scene.json's ``stages`` entry atomically (temporary file, then rename)."""
    doc = read_doc(root)
    stages = dict(doc.get("stages") or {})
    if record is None:
        stages.pop(name, None)
    else:
        stages[name] = record
    doc["stages"] = stages
    with atomic_path(root / SCENE_FILE) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(doc, fh, indent=1)


def save_npz(path: Path, **arrays) -> Path:
    """np.savez (uncompressed: fast to write and read) to a temporary name, then rename."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
    return path


def load_npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def mvs_key(kind: str, view: str) -> str:
    """The key of one view's array of one kind ("depth", "normal", "confidence") in mvs.npz."""
    return f"{kind}:{view}"


def mvs_arrays(arrays: dict[str, np.ndarray], kind: str = "depth") -> dict[str, np.ndarray]:
    """{view: array} of one kind ("depth", "normal", "confidence") of the mvs stage's mvs.npz."""
    prefix = mvs_key(kind, "")
    return {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}


def with_stage_depth(scene: Scene, prefer: tuple[str, ...] = ("mvs", "depth")) -> Scene:
    """``scene`` with a depth map for every view that has none of its own, from the first stage of
    ``prefer`` that made one for it: multi-view stereo (``mvs``: measured from the photographs;
    unknown where nothing matched) or the global mesh rendered (``depth``). Views with their own
    depth, and views no stage made depth for, are as they were. The scene is the same object when
    nothing was added."""
    missing = [v.name for v in scene.views if not v.has_depth]
    if not missing or scene.root is None:
        return scene
    found: dict[str, np.ndarray] = {}
    for stage in prefer:
        try:
            path = stage_output(scene.root, stage)
        except InputError:
            continue
        with np.load(path, allow_pickle=False) as z:  # only the missing views' depth is read
            for n in missing:
                key = mvs_key("depth", n) if stage == "mvs" else n
                if n not in found and key in z.files:
                    d = z[key]
                    if np.any(d > 0):  # (a view in which nothing matched stays without depth)
                        found[n] = d
    if not found:
        return scene
    views = [v.with_depth(found[v.name]) if v.name in found else v for v in scene.views]
    return replace(scene, views=views)


def missing_depth_error(method: str, scene: Scene, names: list[str]) -> InputError:
    """The error of a depth-image method (dibr, warp) whose input views ``names`` have no depth,
    naming the command that makes it (the mvs stage: multi-view stereo of the photographs)."""
    where = scene.root if scene.root is not None else "SCENE"
    some = f"{', '.join(names[:5])}{' ...' if len(names) > 5 else ''} ({len(names)} of {len(scene.views)})"
    if scene.meshes:  # the mvs stage is skipped for such a scene: the depth stage renders its mesh
        how = f"render it from the scene's mesh: ibr-preprocess {where} -o {where} --stages depth"
    else:
        how = f"compute it from the photographs: ibr-preprocess {where} -o {where} --methods {method}"
    return InputError.about("method", f"needs depth for every input view; without depth: {some}; {how}", method)


def view_depths(views, load_rendered) -> dict[str, np.ndarray]:
    """Each view's depth: its own, else the depth stage's rendering of the global mesh
    (``load_rendered()`` gives the depth stage's arrays; called once, and only when some view has
    no depth). KeyError naming the view when the depth stage has none for it."""
    rendered = None
    out = {}
    for v in views:
        if v.has_depth:
            out[v.name] = v.depth
            continue
        if rendered is None:
            rendered = load_rendered()
        out[v.name] = rendered[v.name]
    return out


def stale_reasons(records: dict, stage: str, scene_key: str | None = None) -> list[str]:
    """Why the output recorded for ``stage`` in ``records`` (scene.json's ``stages``) is not what this
    build would make now: its code's version changed, or a stage it reads re-ran (or lost its
    output) after it ran, or (``scene_key`` given: the imported scene's content key now) the scene
    changed. Empty when it is current, when there is no output, and for records written before
    records carried ``version`` and ``inputs`` (older records; nothing to compare)."""
    rec = records.get(stage) or {}
    st = STAGES[stage]
    out = []
    if "version" in rec and rec["version"] != st.version:
        out.append(f"written by version {rec['version']} of its code, this build's is {st.version}")
    used = rec.get("inputs")
    if not isinstance(used, dict):
        return out
    for k in st.inputs:
        if k == "scene":
            if scene_key is not None and used.get(k) != scene_key:
                out.append("the scene's files changed after it ran")
            continue
        now = (records.get(k) or {}).get("key", "not needed")
        if used.get(k) != now:
            out.append(f"stage {k!r} has no output now" if now == "not needed" else f"stage {k!r} re-ran after it")
    return out


def stage_output(root: str | os.PathLike, stage: str, *, verify: bool = True) -> Path:
    """Path of a derived stage's output in the scene at ``root`` (for the render methods), after
    checking that scene.json records it and (``verify``) that the file still has its recorded
    content (``output_intact``: its recorded size and modification time, else its hash). Raises
    MissingFileError naming the command that makes it."""
    root = Path(root)
    if stage not in STAGES:
        raise BadValueError(f"stage {stage!r}: unknown (expected one of {', '.join(STAGES)})")
    rec = (read_doc(root).get("stages") or {}).get(stage) if (root / SCENE_FILE).is_file() else None
    if not rec or not rec.get("outputs"):
        why = f" ({rec['skipped']})" if rec and rec.get("skipped") else ""
        raise MissingFileError(f"{root}: no output of stage {stage!r}{why}; run: ibr-preprocess {root} -o {root} "
                               f"--stages {stage}")
    rel = next(iter(rec["outputs"]))
    f = root / CACHE_DIR / stage / rel
    if not (output_intact(f, rec, rel) if verify else f.is_file()):
        raise MissingFileError(f"{f}: missing or changed since stage {stage!r} wrote it; run: ibr-preprocess {root} "
                               f"-o {root} --stages {stage} --force")
    return f


VIEW_ONLY_METHODS = ("reference", "dibr", "warp", "depthwarp")


def default_methods() -> list[str]:
    """``--methods`` default (``auto``): the methods that work from the views alone (reference,
    dibr, warp, depthwarp), so that a plain ``ibr-preprocess`` is the import alone and stays fast
    (``make demo``). tm / ulr / pvm / hybrid are prepared when named (or with ``all``); their
    render methods say which stage to run when its output is missing."""
    return list(VIEW_ONLY_METHODS)


@dataclass
class StageResult:
    name: str
    status: str  # "ran" | "up to date" | "skipped" | "failed"
    reason: str
    seconds: float = 0.0
    details: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"stage": self.name, "status": self.status, "reason": self.reason,
                "seconds": round(self.seconds, 4), **self.details}
