"""Scene model: views, named render targets, camera paths and meshes (on disk: docs/FORMAT.md).

In memory:
  View.color  (H, W, 3) float32 linear RGB, C-contiguous
  View.depth  (H, W) float32: z for pinhole, ray distance for equirect; 0 = unknown,
              +inf = at infinity (sky); never NaN or negative (checked on import)
  View.mask   (H, W) bool, true = pixel belongs to the scene content (optional)
  View.depth_stored  (H, W) float32, as View.depth: the depth as the data set stored it, present
              only when the importer filtered View.depth (the nerf importer's de-quantisation of
              8-bit codes); multi-view fusion reads it (``fusion_depth``)
Images are loaded lazily from their files the first time they are used.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Mapping, MutableMapping

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, DtypeError, InputError, ShapeError
from ibrtools.mesh import Mesh
from ibrtools.checks import check_depth


class _Lazy:
    """An array given directly or produced on first use by a loader (e.g. reading a file)."""

    def __init__(self, value: np.ndarray | None = None, loader: Callable[[], np.ndarray] | None = None,
                 source: str | None = None):
        self._value, self._loader, self.source = value, loader, source

    @property
    def present(self) -> bool:
        return self._value is not None or self._loader is not None

    def get(self) -> np.ndarray | None:
        if self._value is None and self._loader is not None:
            self._value = self._loader()
            self._loader = None
        return self._value


@dataclass(eq=False)
class View:
    """A camera with its colour and, optionally, depth and mask (lazily loaded)."""

    name: str
    camera: Camera
    _color: _Lazy = field(default_factory=_Lazy, repr=False)
    _depth: _Lazy = field(default_factory=_Lazy, repr=False)
    _mask: _Lazy = field(default_factory=_Lazy, repr=False)
    _depth_stored: _Lazy = field(default_factory=_Lazy, repr=False)

    @classmethod
    def create(cls, name: str, camera: Camera, color=None, depth=None, mask=None, depth_stored=None) -> "View":
        """A view from arrays, or from callables that load them, or None."""
        def lazy(v, what):
            if v is None:
                return _Lazy()
            if callable(v):
                return _Lazy(loader=v, source=getattr(v, "source", None))
            return _Lazy(value=_check_image(v, f"view {name!r} {what}", camera, what))

        if depth_stored is not None and depth is None:
            raise BadValueError(f"view {name!r}: depth_stored given without depth")
        return cls(name, camera, lazy(color, "color"), lazy(depth, "depth"), lazy(mask, "mask"),
                   lazy(depth_stored, "depth_stored"))

    def _get(self, which: str) -> np.ndarray | None:
        lazy: _Lazy = getattr(self, "_" + which)
        if lazy._value is None and lazy._loader is not None:
            # Kept only once checked: a value that fails its check is not cached, so every later
            # use fails the same way (before, the second use got the unchecked array).
            try:
                value = lazy._loader()
                lazy._value = _check_image(value, f"view {self.name!r} {which}"
                                           + (f" ({lazy.source})" if lazy.source else ""), self.camera, which)
            except InputError as e:
                # Marked as the scene's data being bad (a file found corrupt when first read), not
                # the frame being rendered: render jobs stop on it instead of failing frame by frame.
                e.scene_data = True  # type: ignore[attr-defined]
                raise
        return lazy._value

    def release(self) -> None:
        """Forget the decoded images that can be loaded again from their files (the next use
        reads them anew); images given as arrays stay. A video's renderer releases each scene
        frame once its frames are done, so a long sequence holds about two frames' images."""
        for which in ("color", "depth", "mask", "depth_stored"):
            lazy: _Lazy = getattr(self, "_" + which)
            if lazy._loader is not None:
                lazy._value = None

    def load(self) -> None:
        """Decode every image of the view now (what its first use would do)."""
        for which in ("color", "depth", "mask", "depth_stored"):
            self._get(which)

    def check_files(self) -> None:
        """Check, from their headers alone (no pixel is decoded), the files this view loads lazily:
        readable images of the camera's size (loaders that know it: ``FileLoader`` with ``size``).
        Pixels (truncated data, NaN) are checked when first loaded."""
        for which in ("color", "depth", "mask", "depth_stored"):
            lazy: _Lazy = getattr(self, "_" + which)
            probe = getattr(lazy._loader, "probe", None)
            if lazy._value is None and probe is not None:
                probe()

    @property
    def color(self) -> np.ndarray | None:
        return self._get("color")

    @property
    def depth(self) -> np.ndarray | None:
        return self._get("depth")

    @property
    def mask(self) -> np.ndarray | None:
        return self._get("mask")

    @property
    def depth_stored(self) -> np.ndarray | None:
        return self._get("depth_stored")

    @property
    def has_depth_stored(self) -> bool:
        return self._depth_stored.present

    @property
    def fusion_depth(self) -> np.ndarray | None:
        """The depth multi-view fusion reads: as the data set stored it when the importer filtered
        ``depth``, else ``depth``. A per-view filter (de-quantisation) makes each view's error
        follow the surface's shape, alike in every view, where the stored codes' rounding error
        differs from view to view and averages out in the fusion (docs/preprocess.md
        "Fusion")."""
        return self.depth_stored if self.has_depth_stored else self.depth

    @property
    def has_color(self) -> bool:
        return self._color.present

    @property
    def has_depth(self) -> bool:
        return self._depth.present

    def with_depth(self, depth: np.ndarray) -> "View":
        """This view (the same colour and mask, loaded or not) with ``depth`` as its depth: a
        stage's depth (multi-view stereo, the mesh rendered) for a view the data set gave none."""
        return View(self.name, self.camera, self._color,
                    _Lazy(value=_check_image(depth, f"view {self.name!r} depth", self.camera, "depth")),
                    self._mask)

    @property
    def has_mask(self) -> bool:
        return self._mask.present

    def __repr__(self) -> str:
        """One line: the name, the camera's model and size, which images the view has (no
        array is loaded or printed)."""
        c = self.camera
        has = [k for k, p in (("color", self.has_color), ("depth", self.has_depth), ("mask", self.has_mask)) if p]
        return f"View({self.name!r}, {c.model} {c.width}x{c.height}, {'+'.join(has) or 'no images'})"


def _check_image(v: np.ndarray, name: str, camera: Camera, what: str) -> np.ndarray:
    hw = (camera.height, camera.width)
    if not isinstance(v, np.ndarray):
        raise DtypeError(f"{name}: expected a numpy array, got {type(v).__name__}")
    if what == "color":
        if v.dtype != np.float32:
            raise DtypeError(f"{name}: expected float32 linear RGB, got {v.dtype}")
        if v.shape != hw + (3,):
            raise ShapeError(f"{name}: expected shape (H, W, 3) = {hw + (3,)} to match the camera, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise BadValueError(f"{name}: colour contains NaN or infinity")
        return np.ascontiguousarray(v)
    if what in ("depth", "depth_stored"):
        return np.ascontiguousarray(check_depth(v, name, hw))
    if v.dtype != np.bool_:
        raise DtypeError(f"{name}: expected a bool mask, got {v.dtype}")
    if v.shape != hw:
        raise ShapeError(f"{name}: expected shape (H, W) = {hw} to match the camera, got {v.shape}")
    return np.ascontiguousarray(v)


class LazyMeshes(MutableMapping[str, Mesh]):
    """Meshes by kind, each read the first time it is asked for (``loaders``: kind -> a callable
    that returns the Mesh, picklable for Dask workers): a scene loaded from disk reads no mesh a
    method, stage or save does not ask for (the frames of a video rendered by DIBR never read
    their ground-truth meshes). Otherwise a dict of meshes: keys in order, meshes set and deleted."""

    def __init__(self, loaders: Mapping[str, Callable[[], Mesh]]):
        self._items: dict[str, Mesh | Callable[[], Mesh]] = dict(loaders)
        self.version = 0  # counts the meshes set and deleted (not the ones read): caches compare it

    def __getitem__(self, kind: str) -> Mesh:
        item = self._items[kind]
        if isinstance(item, Mesh):
            return item
        mesh = item()  # two threads asking at once read it twice, and keep one: harmless
        self._items[kind] = mesh
        return mesh

    def __setitem__(self, kind: str, mesh: Mesh) -> None:
        self._items[kind] = mesh
        self.version += 1

    def __delitem__(self, kind: str) -> None:
        del self._items[kind]
        self.version += 1

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        state = {k: ("read" if isinstance(v, Mesh) else "not read yet") for k, v in self._items.items()}
        return f"LazyMeshes({state})"


@dataclass(eq=False)
class Scene:
    """Input views, named targets (cameras to render, with ground truth when known), camera
    paths, meshes by kind ("ground_truth", "reconstructed"), lights, units and provenance."""

    views: list[View] = field(default_factory=list)
    targets: list[View] = field(default_factory=list)
    paths: dict[str, list[Camera]] = field(default_factory=dict)
    # A dict, or LazyMeshes (a scene loaded from disk: each mesh read when first asked for).
    meshes: MutableMapping[str, Mesh] = field(default_factory=dict)
    units: str = "unknown"
    source: dict = field(default_factory=dict)
    # Lights the views were rendered with (synthetic scenes), as scene.json stores them:
    # {"kind": "point"|"directional", "vector": [x, y, z], "color": [r, g, b], "shadows": bool};
    # plus "ambient" and "background" in ``shading``. The reference method renders with them.
    lights: list[dict] = field(default_factory=list)
    shading: dict = field(default_factory=dict)
    # Records of the preprocessing stages that produced this scene (pipeline/stages.py): name -> record.
    stages: dict = field(default_factory=dict)
    root: Path | None = None
    # A video scene (docs/FORMAT.md "Frames"): the names of its frames, in time order; frame F is
    # a still scene of its own (views, meshes, targets with ground truth at that instant) in
    # root/frames/F/, loaded by :meth:`frame`. Empty for a still scene (a one-frame scene).
    frames: list[str] = field(default_factory=list)
    # How a frame's directory becomes a Scene: set by the loader that read this scene
    # (ibrtools.formats.native.load), so that the model does not depend on the formats.
    load_frame: Callable[[Path], "Scene"] | None = field(default=None, repr=False, compare=False)

    def __repr__(self) -> str:
        """A few lines summing the scene up: views (count, image sizes, how many with depth),
        targets, meshes (kind and faces), paths (name and cameras), frames, stages recorded.
        Never an array, never a file read (lazy images stay unloaded)."""
        def sizes(vs: list[View]) -> str:
            got: dict[str, int] = {}
            for v in vs:
                k = f"{v.camera.width}x{v.camera.height}"
                got[k] = got.get(k, 0) + 1
            return ", ".join(k if len(got) == 1 else f"{n} at {k}" for k, n in list(got.items())[:3]) + (
                ", ..." if len(got) > 3 else "")

        views = f"{len(self.views)} views" + (f" ({sizes(self.views)}; {sum(v.has_depth for v in self.views)} "
                                              "with depth)" if self.views else "")
        lines = [f"Scene({views}, {len(self.targets)} targets"
                 + (f" ({sum(t.has_color for t in self.targets)} with ground truth)" if self.targets else "")
                 + f", units {self.units!r}" + (f", root {str(self.root)!r}" if self.root is not None else "")]
        if self.meshes:
            lines.append("meshes: " + ", ".join(f"{k} ({len(m.faces)} faces)" for k, m in self.meshes.items()))
        if self.paths:
            lines.append("paths: " + _some(f"{k} ({len(p)})" for k, p in self.paths.items()))
        if self.frames:
            lines.append(f"frames: {len(self.frames)} ({_some(self.frames, 3)})")
        if self.stages:
            lines.append("stages: " + _some(self.stages, 10))
        return "\n  ".join(lines) + ")"

    def release(self) -> None:
        """View.release() of every input view and target (decoded images that can be read again)."""
        for v in (*self.views, *self.targets):
            v.release()

    def load(self) -> None:
        """Decode every input view's images now (View.load)."""
        for v in self.views:
            v.load()

    def view(self, name: str) -> View:
        for v in self.views:
            if v.name == name:
                return v
        raise BadValueError(f"view {name!r}: not in the scene (views: {_some(v.name for v in self.views)})")

    def target(self, name: str) -> View:
        for v in self.targets:
            if v.name == name:
                return v
        raise BadValueError(f"target {name!r}: not in the scene (targets: {_some(v.name for v in self.targets)})")

    @property
    def mesh(self) -> Mesh | None:
        """The mesh methods should use: the reconstructed one when the scene has one (it is
        what a real capture gives), else the ground truth."""
        return self.meshes.get("reconstructed") or self.meshes.get("ground_truth")

    def bounds(self) -> np.ndarray:
        """(2, 3) axis-aligned bounds of meshes, camera centres and the depth of the views."""
        pts = [v.camera.centre[None] for v in self.views + self.targets]
        for m in self.meshes.values():
            pts.append(m.bounds().astype(np.float64))
        for v in self.views:
            if v.has_depth and v.depth is not None:
                d = v.depth
                ok = np.isfinite(d) & (d > 0)
                if ok.any():
                    step = max(1, int(np.sqrt(d.size / 4096)))
                    w = v.camera.unproject(np.where(ok, d, 0))[::step, ::step][ok[::step, ::step]]
                    if len(w):
                        pts.append(np.stack([w.min(0), w.max(0)]))
        allp = np.concatenate(pts, 0)
        return np.stack([allp.min(0), allp.max(0)])

    def frame(self, name: str) -> "Scene":
        """Frame ``name`` of a video scene, as a still scene (loaded from root/frames/<name>/)."""
        if name not in self.frames:
            have = _some(self.frames) if self.frames else "none: a still scene"
            raise BadValueError(f"frame {name!r}: not in the scene (frames: {have})")
        if self.root is None:
            raise BadValueError(f"frame {name!r}: the video scene has no directory to load its frames from")
        if self.load_frame is None:
            raise BadValueError(f"frame {name!r}: the video scene was not loaded from disk (ibrtools.load_scene)")
        return self.load_frame(Path(self.root) / "frames" / name)

    def validate(self) -> None:
        """Check what loading lazily would otherwise find late: names unique, views present, and
        the header of every image file the views load (readable, of its camera's size:
        :meth:`View.check_files`), so that a bad file stops a command before any work rather
        than failing each frame that uses it."""
        if not self.views and not self.targets and not self.frames:
            raise BadValueError("scene: empty (no views and no targets)")
        names = [v.name for v in self.views] + [t.name for t in self.targets]
        seen: set[str] = set()
        dup = sorted({n for n in names if n in seen or seen.add(n)})
        if dup:
            raise BadValueError(f"scene: duplicate view/target names {dup[:5]}")
        for v in self.views + self.targets:
            v.check_files()


def _some(names, k: int = 8) -> str:
    names = list(names)
    return ", ".join(names[:k]) + (f", ... ({len(names)} in all)" if len(names) > k else "") or "none"


def path_str(p: str | os.PathLike) -> str:
    return str(Path(p))
