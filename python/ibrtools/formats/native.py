"""The native scene format: a directory with ``scene.json`` (docs/FORMAT.md), images, depth
maps and meshes. It is what every importer writes and what the render commands read.

Converts from: nothing (this is the engine's own convention, see camera.py and scene.py).
Colour is stored as 8-bit sRGB PNG by default (``color_format="exr"`` keeps linear float32),
depth as float32 EXR, masks as 8-bit PNG, meshes as PLY (vertex colours) or OBJ+MTL (textures).
A save is atomic: the scene is written to a temporary directory beside the target and renamed
into place, so a reader never sees a half-written scene.
"""
from __future__ import annotations

import functools
import json
import math
import os
import shutil
from pathlib import Path

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, FormatError, MissingFileError
from ibrtools.imageio import read_depth, read_image, read_mask, write_depth, write_image
from ibrtools.outputs import mkdtemp_beside
from ibrtools.scene import LazyMeshes, Scene, View
from ibrtools.formats._common import document_errors, FileLoader, read_json

NAME = "native"
DESCRIPTION = "ibrtools scene directory (scene.json, docs/FORMAT.md)"
FORMAT_TAG = "ibrtools-scene"
VERSION = 1
VIDEO_VERSION = 2  # a video scene (scene.json "frames"): a reader of version 1 would see no views
FRAMES_DIR = "frames"
SCENE_FILE = "scene.json"


def detect(path: Path) -> bool:
    """A directory with a scene.json (or that file): load() then says precisely what is wrong
    with it, rather than "unknown format"."""
    path = Path(path)
    f = path / SCENE_FILE if path.is_dir() else path
    return f.name == SCENE_FILE and f.is_file()


def _json_safe(value):
    """JSON cannot hold inf/NaN as numbers: write them as strings."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def _safe_name(name: str) -> str:
    bad = set('/\\:*?"<>|') | {"\0"}
    return "".join("_" if c in bad else c for c in name)


def _write_view(root: Path, view: View, kind: str, color_format: str) -> dict:
    entry: dict = {"name": view.name, "camera": view.camera.to_dict()}
    stem = _safe_name(view.name)
    if view.has_color:
        rel = f"{kind}/{stem}.{'exr' if color_format == 'exr' else 'png'}"
        write_image(root / rel, view.color)
        entry["color"] = rel
    if view.has_depth:
        rel = f"{kind}/{stem}.depth.exr"
        write_depth(root / rel, view.depth)
        entry["depth"] = rel
    if view.has_depth_stored:
        rel = f"{kind}/{stem}.depth_stored.exr"
        write_depth(root / rel, view.depth_stored)
        entry["depth_stored"] = rel
    if view.has_mask:
        rel = f"{kind}/{stem}.mask.png"
        write_image(root / rel, view.mask.astype("float32"))
        entry["mask"] = rel
    return entry


def save(scene: Scene, path: str | os.PathLike, *, color_format: str = "png",
         overwrite: bool = True) -> Path:
    """Write ``scene`` as a native scene directory at ``path`` (atomically)."""
    path = Path(path)
    if color_format not in ("png", "exr"):
        raise BadValueError(f"color_format: expected 'png' or 'exr', got {color_format!r}")
    if path.exists() and not overwrite:
        raise BadValueError(f"{path}: exists (pass overwrite=True to replace it)")
    if path.exists() and not (path.is_dir() and (path / SCENE_FILE).exists() or path.is_dir() and not any(path.iterdir())):
        raise BadValueError(f"{path}: exists and is not a scene directory; refusing to replace it")
    scene.validate()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = mkdtemp_beside(path)
    try:
        doc: dict = {"format": FORMAT_TAG, "version": VERSION, "units": scene.units,
                     "source": _json_safe(scene.source),
                     "views": [_write_view(tmp, v, "images", color_format) for v in scene.views],
                     "targets": [_write_view(tmp, v, "targets", color_format) for v in scene.targets],
                     "paths": {name: [c.to_dict() for c in cams] for name, cams in scene.paths.items()},
                     "meshes": {}}
        if scene.lights:
            doc["lights"] = _json_safe(scene.lights)
        if scene.shading:
            doc["shading"] = _json_safe(scene.shading)
        if scene.stages:
            doc["stages"] = _json_safe(scene.stages)
        for kind, mesh in scene.meshes.items():
            from ibrtools.meshio import write_mesh

            textured = bool(mesh.textures) and mesh.uvs is not None
            rel = f"mesh/{kind}.{'obj' if textured else 'ply'}"
            write_mesh(tmp / rel, mesh)
            doc["meshes"][kind] = {"path": rel}
        _install(tmp, path, doc)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    scene.root = path
    return path


def _install(tmp: Path, path: Path, doc: dict) -> None:
    """Write ``doc`` as the scene.json of the finished directory ``tmp`` and put it at ``path``: an
    existing scene is moved aside first and removed after the rename, so ``path`` is never a
    half-written scene."""
    with open(tmp / SCENE_FILE, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1)
    if path.exists():
        old = mkdtemp_beside(path, ".old")
        os.replace(path, old / "scene")
        os.replace(tmp, path)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, path)


def save_video(video: Scene, frames: dict[str, Scene], path: str | os.PathLike, *,
               color_format: str = "png") -> Path:
    """Write a video scene (docs/FORMAT.md "Frames") atomically: ``frames`` (name -> still scene,
    in time order) under ``path``/frames/<name>/, and scene.json (version 2) with their names and
    ``video``'s shared parts (units, source, stage records, paths, targets without images)."""
    path = Path(path)
    if not frames:
        raise BadValueError("save_video: no frames")
    bad = [n for n in frames if not n or _safe_name(n) != n or n in (".", "..")]
    if bad:
        raise BadValueError(f"save_video: frame names must be plain file names, got {bad[:3]}")
    if path.exists() and not (path.is_dir() and ((path / SCENE_FILE).exists() or not any(path.iterdir()))):
        raise BadValueError(f"{path}: exists and is not a scene directory; refusing to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = mkdtemp_beside(path)
    try:
        for name, scene in frames.items():
            save(scene, tmp / FRAMES_DIR / name, color_format=color_format)
            scene.release()  # a long video holds one frame's decoded images at a time
        doc: dict = {"format": FORMAT_TAG, "version": VIDEO_VERSION, "units": video.units,
                     "source": _json_safe(video.source), "frames": list(frames), "views": [],
                     "targets": [{"name": t.name, "camera": t.camera.to_dict()} for t in video.targets],
                     "paths": {name: [c.to_dict() for c in cams] for name, cams in video.paths.items()},
                     "meshes": {}}
        if video.stages:
            doc["stages"] = _json_safe(video.stages)
        _install(tmp, path, doc)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    video.root, video.frames = path, list(frames)
    return path


def _read_view(root: Path, entry, where: str, need_color: bool) -> View:
    if not isinstance(entry, dict) or "name" not in entry:
        raise FormatError(f"{where}: expected an object with 'name' and 'camera'")
    name = entry["name"]
    if not isinstance(name, str) or not name:
        # str() would turn anything (null, 3, a list) into a name; the render side maps any
        # string, "/" and ".." included, to a safe output file name, so only the type is refused.
        raise FormatError(f"{where}.name: expected a non-empty string, got {json.dumps(name)[:60]}")
    camera = Camera.from_dict(entry.get("camera"), f"{where}.camera")
    size = (camera.width, camera.height)  # every image is checked against it from its header
    loaders = {}
    for key, fn in (("color", read_image), ("depth", read_depth), ("mask", read_mask), ("depth_stored", read_depth)):
        rel = entry.get(key)
        if rel is None:
            if key == "color" and need_color:
                raise FormatError(f"{where}: missing 'color'")
            continue
        if not isinstance(rel, str) or not rel:
            raise FormatError(f"{where}.{key}: expected a file path relative to the scene, got {json.dumps(rel)[:60]}")
        f = root / rel
        if not f.is_file():
            raise MissingFileError(f"{f}: no such file (named by {where}.{key})")
        loaders[key] = FileLoader(f, fn, f, size=size)
    return View.create(name, camera, **loaders)


@document_errors
def load(path: Path, options: dict | None = None) -> Scene:
    """Read a native scene directory (or its scene.json)."""
    path = Path(path)
    f = path / SCENE_FILE if path.is_dir() else path
    root = f.parent
    if not f.is_file():
        raise MissingFileError(f"{f}: no such file")
    doc = read_json(f)
    if not isinstance(doc, dict) or doc.get("format") != FORMAT_TAG:
        raise FormatError(f"{f}: not an ibrtools scene (expected \"format\": \"{FORMAT_TAG}\")")
    version = doc.get("version")
    if version not in (VERSION, VIDEO_VERSION):
        raise FormatError(f"{f}: scene format version {version!r} is not supported (this ibrtools reads "
                          f"{VERSION} and {VIDEO_VERSION})")
    frames = doc.get("frames")
    if (version == VIDEO_VERSION) != (frames is not None):
        raise FormatError(f"{f}: version {version} " + ("needs a 'frames' list (a video scene)" if frames is None
                                                        else "cannot hold 'frames' (video scenes are version 2)"))
    if frames is not None:
        if (not isinstance(frames, list) or not frames or not all(isinstance(n, str) and n for n in frames)
                or len(set(frames)) != len(frames)):
            raise FormatError(f"{f}: 'frames': expected a non-empty list of distinct frame names")
        for n in frames:
            if _safe_name(n) != n or n in (".", "..") or not (root / FRAMES_DIR / n / SCENE_FILE).is_file():
                raise MissingFileError(f"{root / FRAMES_DIR / n / SCENE_FILE}: no such file (frame {n!r} of {f})")
    views = [_read_view(root, e, f"{f}: views[{i}]", True) for i, e in enumerate(doc.get("views", []))]
    targets = [_read_view(root, e, f"{f}: targets[{i}]", False) for i, e in enumerate(doc.get("targets", []))]
    paths = {}
    for name, cams in (doc.get("paths") or {}).items():
        if not isinstance(cams, list) or not cams:
            raise FormatError(f"{f}: paths.{name}: expected a non-empty list of cameras")
        paths[name] = [Camera.from_dict(c, f"{f}: paths.{name}[{i}]") for i, c in enumerate(cams)]
    loaders = {}
    for kind, m in (doc.get("meshes") or {}).items():
        if not isinstance(m, dict) or "path" not in m:
            raise FormatError(f"{f}: meshes.{kind}: expected an object with 'path'")
        from ibrtools.meshio import check_mesh_path, read_mesh

        check_mesh_path(root / m["path"])  # a missing file or unknown format stops the load; the rest is read on use
        loaders[kind] = functools.partial(read_mesh, root / m["path"], kind=kind)
    meshes = LazyMeshes(loaders)
    scene = Scene(views=views, targets=targets, paths=paths, meshes=meshes,
                  units=str(doc.get("units", "unknown")), source=dict(doc.get("source") or {}),
                  lights=list(doc.get("lights") or []), shading=dict(doc.get("shading") or {}),
                  stages=dict(doc.get("stages") or {}), root=root, frames=list(frames or []), load_frame=load)
    scene.validate()
    return scene
