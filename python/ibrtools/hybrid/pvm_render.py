"""Rendering per-view meshes (PVM) with clustered depth filtering (Prakash et al. 2021, sec. 5.1-5.2,
Eq. 1-2). docs/pvm_render.md; C++: cpp/kernels/hybrid/pvm_render.h (five stages, GIL released).

:class:`PvmRenderer` loads the PVM tiles of the ``pvm`` preprocessing stage (tiles.npz) and the
input images (the ``harmonise`` stage's images when that stage ran, else the originals). Tiles of
views that are not in the scene given (held-out views) are never used. :meth:`PvmRenderer.render`
gives a :class:`PvmResult`:

* visible coarse voxels from ``gbuffer_depth`` (the global mesh's z per pixel, 0 = no hit; the
  coarse cells of its surface points plus a ``margin`` of 1 cell) or, with None, every coarse cell
  in the camera frustum;
* per visible fine voxel its tiles ranked by the ULR penalty of their view (voxel centre, novel
  camera), the best ``max_tiles`` = 12 kept;
* those tiles rasterised into per-pixel candidate lists (<= 12: depth, view; the colour is the
  view's image at the candidate's surface point), one per view (nearest fragment);
* where ``gbuffer_depth`` has no surface, lists of fewer than ``min_views`` = 2 views emptied (a
  surface the global mesh lacks needs two views to vouch for it; 1 = the paper, any candidate);
* per pixel 2-means on the candidate depths, ULR-weighted colour per cluster (ours: a candidate whose
  triangle is magnified in the target, against its area in its own view, gets a larger penalty:
  ``stretch_weight``), the spatial filter of
  Eq. 1 and the gamma-power blend (``filtered=True``), or the foreground cluster's colour
  (``filtered=False``: the unfiltered PVM-H-like baseline);
* depth by the vote of Eq. 2 (``tau_depth``) for the hybrid method's geometric test.

Two-phase use (the hybrid method): :meth:`PvmRenderer.depth_pass` gives depth / vote / valid /
inside_grid everywhere without sampling any image, then :meth:`PvmRenderer.resolve` computes the
colours of a pixel mask only, from the kept candidate lists (same result as ``render`` with
that mask).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from ibrtools import _core
from ibrtools.camera import PINHOLE, Camera
from ibrtools.errors import BadValueError, DtypeError, InputError, MissingFileError, NotBuiltError, ParamError, ShapeError
from ibrtools import params as P
from ibrtools.scene import Scene
from ibrtools.hybrid.pvm import PvmTiles
from ibrtools import cache

# Defaults: sigma, alpha, gamma, tau_depth from the paper's sweep (sec. 7); max_tiles 12 (sec. 5.1);
# max_candidates 12 (per-pixel list); ulr_k 3 (weight 0 at the 3rd: two candidates blended per
# cluster; the ULR method keeps 4): chosen on the selection scenes, lego validation and synth seed 1,
# where 3 beat 1 / 2 / 4 / 6 in PSNR, SSIM and FLIP for PVM and hybrid (docs/pvm_render.md);
# merge_rel 0.02: two clusters closer than 2 % of the depth are one surface (below the PVM stage's
# 3 % discontinuity cut, above the 0.5 % depth noise of the synthetic scenes); radius_sigmas 2:
# the Eq. 1 window is (2 * ceil(2 sigma) + 1)^2 = 13 x 13 px for sigma = 3 (Gaussian weight at
# its edge 0.135); margin 1 coarse cell around the G-buffer's cells; near 1e-3 scene units;
# max_angle 55 degrees: views seeing a fine voxel from more than 55 degrees away from the novel
# camera are not ranked for it; with a sparse capture "the top 12" otherwise includes views from
# the far side of an object, which see the background behind it and outvote the foreground in
# Eq. 1 and Eq. 2 (docs/pvm_render.md "max_angle": 180 / 90 / 60 / 50 / 40 degrees on synth:objects).
# 55 chosen for the hybrid on the 36 lego views outside the held-out
# set and synth seed 1 (docs/pvm_render.md "max_angle"); 50 scored better on lego but lost a thin
# object missing from the global mesh in a 10-view ring (tests/hybrid/test_pvm_render.py).
# ray_stride 8: the coarse cells in front of the G-buffer's surface on every 8th ray of every 8th
# row are looked up too (an object the global mesh lacks, more than one coarse cell in front of
# the surface behind it, would otherwise be missed; on
# synth:objects at 256x192 the thin object's pixels with a candidate at its depth went from 60 %
# to the frustum lookup's 93-98 %; at 1280x720 stride 8 costs 57 ms against 153 ms for stride 4,
# same tiles). filter_step 2: Eq. 1 sums every 2nd neighbour per axis (7 x 7 of 13 x 13), 3.4x
# fewer terms (docs/pvm_render.md, "Speed"); min_views 2: where the G-buffer has no surface, a
# one-view candidate list is emptied (silhouette overshoot of a per-view mesh): chosen on the
# selection scenes, where it beat 1 (the paper) in every metric for hybrid and PVM alone, and 3 in
# PSNR and SSIM (FLIP equal) (docs/pvm_render.md "min_views"). free_space_point_tol 0.005 (ULR's
# depth_tol): a view whose depth at the foreground point is the point's own sees it and does not
# count as seeing past it; chosen on the selection scenes (docs/pvm_render.md "Free space").
# tau_empty 2: a one-cluster pixel seen past by >= 2 x n_fg views without a candidate there is
# emptied (a sheet across a gap); chosen on the selection scenes over 0 (off) / 1.5 / 2 / 2.5 / 3 / 4
# (docs/pvm_render.md "Seen through"). resample "cubic": the candidates' colours are read with
# Catmull-Rom, as the ULR blend's (cpp/ibr/resample.h; "bilinear" the plain read).
# stretch_weight 0.1, stretch_free 0 (ours): a candidate's ULR penalty gains
# 0.1 x log2 of its triangle's magnification in the target (its area there over its area in its own
# view) when above 1; chosen on the selection scenes (the 36 lego views outside the held-out set
# and synth seed 1) over weights 0.05 / 0.1 / 0.2 / 0.4 / 0.8 and free octaves 0 / 1 / 2
# (docs/pvm_render.md "Stretch"); 0 = the paper's ULR weights.
_D = _core.PVM_DEFAULTS  # the defaults, defined once, in the C++ options (cpp/kernels/hybrid/pvm_render.h)

# How the views' colours are read at sub-pixel positions (the ULR method takes the same values).
RESAMPLE = ("cubic", "bilinear")

STAGE_NAMES = {"voxel_lookup": "voxel lookup", "tile_sort": "tile sort",
               "per_view_depth_pass": "per-view depth pass", "cluster_blend": "cluster & blend",
               "spatial_filter": "spatial filter"}


@dataclass(frozen=True)
class PvmParams(P.MethodParams):
    """Parameters of the PVM renderer (``--method pvm``; the hybrid passes its PVM ones on).
    Bounds: ulr_k, max_tiles, max_candidates and min_views are the kernel's fixed-size lists;
    ray_stride 65536 is past any frame side; the others stay finite in float32 (FINITE_MAX) or
    bound a window the kernel allocates (sigma * radius_sigmas <= 64 px, margin <= 32 cells)."""

    method: ClassVar[str] = "pvm"
    sigma: float = P.number(_D["sigma"], 0.0, strict=True, maximum=32.0)
    alpha: float = P.number(_D["alpha"], 0.0, maximum=P.FINITE_MAX)
    gamma: float = P.number(_D["gamma"], 0.0, strict=True, maximum=P.FINITE_MAX)
    tau_depth: float = P.number(_D["tau_depth"], 0.0, maximum=P.FINITE_MAX)
    max_tiles: int = P.integer(_D["max_tiles"], 1, 255)
    max_candidates: int = P.integer(_D["max_candidates"], 1, 16)
    ulr_k: int = P.integer(_D["ulr_k"], 1, _core.ULR_MAX_K)
    merge_rel: float = P.number(_D["merge_rel"], 0.0, maximum=P.FINITE_MAX)
    radius_sigmas: float = P.number(_D["radius_sigmas"], 0.0, maximum=64.0)
    margin: int = P.integer(_D["margin"], 0, 32)
    near: float = P.number(_D["near"], 0.0, strict=True, maximum=P.FINITE_MAX)
    cull_back: bool = P.boolean(_D["cull_back"])
    max_angle: float = P.number(_D["max_angle"], 0.0, strict=True, maximum=180.0)
    ray_stride: int = P.integer(_D["ray_stride"], 0, 1 << 16)
    filter_step: int = P.integer(_D["filter_step"], 1, 16)
    filtered: bool = P.boolean(_D["filtered"])
    free_space: bool = P.boolean(_D["free_space"])
    free_space_tol: float = P.number(_D["free_space_tol"], 0.0, maximum=1.0, strict_max=True)
    free_space_point_tol: float = P.number(_D["free_space_point_tol"], 0.0, maximum=P.FINITE_MAX)
    tau_empty: float = P.number(_D["tau_empty"], 0.0, maximum=P.FINITE_MAX)
    min_views: int = P.integer(_D["min_views"], 1, 16)
    stretch_weight: float = P.number(_D["stretch_weight"], 0.0, maximum=P.FINITE_MAX)
    stretch_free: float = P.number(_D["stretch_free"], 0.0, maximum=P.FINITE_MAX)
    resample: str = P.choice(_D["resample"], RESAMPLE)

    def check(self) -> None:
        if self.sigma * self.radius_sigmas > 64:
            raise ParamError("sigma * radius_sigmas", f"expected <= 64 pixels, got {self.sigma:g} * "
                                                      f"{self.radius_sigmas:g}")


@dataclass
class PvmResult:
    """One PVM frame (arrays (H, W[, 3])): color f32 linear; depth f32 z of the cluster picked by
    the vote of Eq. 2 (0 where invalid); valid bool (some candidate); vote f32 the winning
    cluster's share of the candidates; inside_grid bool (the pixel's ray meets the PVM grid's
    box); times_ms per stage; stats (visible coarse cells, kept tiles, rasterised triangles, whether
    the free-space count ran)."""

    color: np.ndarray
    depth: np.ndarray
    valid: np.ndarray
    vote: np.ndarray
    inside_grid: np.ndarray
    times_ms: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)


def _preprocess_hint(scene: Scene) -> str:
    root = scene.root if scene.root is not None else "SCENE"
    return f"ibr-preprocess {root} -o {root} --methods pvm"


def load_tiles(scene: Scene) -> PvmTiles:
    """The scene's PVM tiles (stage ``pvm``); InputError naming the command when it has none."""
    if scene.root is None:
        raise InputError(f"PVM rendering needs the scene's pvm stage (tiles.npz); the scene has no directory: "
                         f"save it and run {_preprocess_hint(scene)}")
    try:
        path = cache.stage_output(scene.root, "pvm")
    except MissingFileError as e:
        raise InputError(f"PVM rendering needs the pvm stage: {e}; run {_preprocess_hint(scene)}") from None
    return PvmTiles.load(path)


def harmonised_images(arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """{view name: image} of the harmonise stage's arrays (its npz, or the dict loaded from it)."""
    return {k[len("image/"):]: arrays[k] for k in list(arrays) if k.startswith("image/")}


def load_images(scene: Scene, harmonise: Mapping[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Input images: the harmonise stage's when it ran, else the views' own colour.
    ``harmonise``: that stage's arrays when the caller has loaded them (read again otherwise)."""
    harmonised: dict[str, np.ndarray] = {}
    if harmonise is not None:
        harmonised = harmonised_images(harmonise)
    elif scene.root is not None:
        try:
            path = cache.stage_output(scene.root, "harmonise")
        except (MissingFileError, BadValueError):
            path = None  # skipped (views agree) or not run: the original images
        if path is not None:
            with np.load(path, allow_pickle=False) as z:
                harmonised = harmonised_images(z)
    out = {}
    for v in scene.views:
        img = harmonised.get(v.name)
        if img is None:
            if not v.has_color:
                raise InputError(f"PVM rendering needs colour for every input view; {v.name} has none")
            img = v.color
        out[v.name] = np.ascontiguousarray(img, np.float32)
    return out


def load_depths(scene: Scene) -> dict[str, np.ndarray] | None:
    """Each input view's depth as the pvm stage read it (``cache.view_depths``: its own, else the
    depth stage's render of the global mesh; before the stage's snap to the global mesh, which moves
    depth by at most ``mesh_snap`` voxels, far below the free-space tolerances), for the free-space
    count; None when some view has neither."""
    def rendered() -> dict[str, np.ndarray]:
        if scene.root is None:
            raise MissingFileError("the scene has no directory with a depth stage")
        return cache.load_npz(cache.stage_output(scene.root, "depth"))

    try:
        return cache.view_depths(scene.views, rendered)
    except (KeyError, MissingFileError, BadValueError):
        return None


class PvmRenderer:
    """PVM renderer of a scene (see the module doc). ``tiles`` / ``images`` / ``depths`` override
    what is loaded from the scene (tests build tiles in memory with hybrid.pvm.build_tiles).
    ``free_space`` (attribute): whether the free-space count runs (the parameter is on and every
    view has a depth map)."""

    def __init__(self, scene: Scene, params: Mapping | PvmParams | None = None, *, tiles: PvmTiles | None = None,
                 images: dict[str, np.ndarray] | None = None, depths: dict[str, np.ndarray] | None = None):
        from ibrtools import _core

        if not isinstance(scene, Scene):
            raise DtypeError(f"scene: expected an ibrtools Scene, got {type(scene).__name__}")
        self.params = PvmParams.from_dict(params)
        if not scene.views:
            raise InputError("PVM rendering: the scene has no input views")
        self.tiles = tiles if tiles is not None else load_tiles(scene)
        if not isinstance(self.tiles, PvmTiles):
            raise DtypeError(f"tiles: expected hybrid.pvm.PvmTiles, got {type(self.tiles).__name__}")
        images = images if images is not None else load_images(scene)
        by_name = {v.name: v for v in scene.views}
        unknown = [n for n in self.tiles.views if n not in by_name]
        # Views of the tiles that the scene lacks (held out, or removed) are disabled: their
        # tiles are never drawn. Their camera/image slots get a stand-in (never read).
        present = [n for n in self.tiles.views if n in by_name]
        if not present:
            raise InputError(f"PVM rendering: none of the tiles' views {self.tiles.views[:5]} is an input view "
                             f"of the scene; rerun {_preprocess_hint(scene)}")
        if self.params.free_space and depths is None:
            depths = load_depths(scene)
        # what was loaded, for a renderer of a subset of these views (HybridMethod._without_views)
        self.images, self.depths = images, depths
        self.free_space = bool(self.params.free_space and depths is not None)
        # stats["free_space"]: whether Eq. 1 / Eq. 2 counted background candidates by free space
        self._free_space_report: bool | str = (self.free_space if self.free_space or not self.params.free_space
                                               else "not run: no depth maps")
        cams, imgs, deps, enabled = [], [], [], []
        stand_in = None
        for n in self.tiles.views:
            if n in by_name:
                v = by_name[n]
                img = images.get(n)
                if img is None:
                    raise InputError(f"PVM rendering: no image for view {n}")
                if img.shape != (v.camera.height, v.camera.width, 3):
                    raise ShapeError(f"image of {n}: expected (H, W, 3) = "
                                     f"{(v.camera.height, v.camera.width, 3)}, got {img.shape}")
                cams.append(v.camera.to_core())
                imgs.append(np.ascontiguousarray(img, np.float32))
                if self.free_space:
                    dep = depths.get(n) if depths is not None else None
                    if dep is None or dep.shape != (v.camera.height, v.camera.width):
                        raise ShapeError(f"depth of {n}: expected (H, W) = {(v.camera.height, v.camera.width)}, got "
                                         f"{None if dep is None else dep.shape}")
                    deps.append(np.ascontiguousarray(dep, np.float32))
                enabled.append(True)
            else:
                if stand_in is None:
                    p0 = present[0]
                    stand_in = (by_name[p0].camera.to_core(), np.ascontiguousarray(images[p0], np.float32),
                                np.zeros((by_name[p0].camera.height, by_name[p0].camera.width), np.float32)
                                if self.free_space else None)
                cams.append(stand_in[0])
                imgs.append(stand_in[1])
                if self.free_space:
                    deps.append(stand_in[2])
                enabled.append(False)
        self.disabled_views = unknown
        t = self.tiles
        self._core = _core.PvmRenderer(
            t.vertices, t.faces, np.ascontiguousarray(t.face_offsets, np.int64),
            np.ascontiguousarray(t.vertex_offsets, np.int64), t.tile_view, t.tile_cell, t.tile_bounds,
            np.ascontiguousarray(t.coarse_offsets, np.int64), [float(x) for x in t.origin],
            [float(x) for x in t.cell], int(t.coarse), int(t.sub), cams, imgs, np.array(enabled, bool),
            deps if self.free_space else None)

    def render(self, camera: Camera, gbuffer_depth: np.ndarray | None = None,
               pixel_mask: np.ndarray | None = None, filtered: bool | None = None) -> PvmResult:
        """One frame (see the module doc). ``filtered`` None = the ``filtered`` parameter."""
        return self._run(camera, gbuffer_depth, pixel_mask, filtered, "full")

    def depth_pass(self, camera: Camera, gbuffer_depth: np.ndarray | None = None) -> PvmResult:
        """Stages 1-4 without colours: depth (Eq. 2), vote, valid and inside_grid of every pixel,
        colour 0. The candidate lists are kept for :meth:`resolve` (the hybrid method decides
        where it needs PVM from the depth, then resolves colours only there)."""
        return self._run(camera, gbuffer_depth, None, None, "depth")

    def resolve(self, camera: Camera, pixel_mask: np.ndarray | None = None,
                filtered: bool | None = None) -> PvmResult:
        """Colours of ``pixel_mask``'s pixels from the last depth pass (or render) of ``camera``
        (the same camera; BadValueError otherwise): cluster & blend and the spatial filter only.
        Identical to :meth:`render` with that mask."""
        return self._run(camera, None, pixel_mask, filtered, "resolve")

    def _run(self, camera, gbuffer_depth, pixel_mask, filtered, mode) -> PvmResult:
        if not isinstance(camera, Camera):
            raise DtypeError(f"camera: expected an ibrtools.Camera, got {type(camera).__name__}")
        if camera.model != PINHOLE:
            raise NotBuiltError("PVM rendering of an equirect target camera: not built yet (pinhole targets only)")
        p = self.params
        filt = p.filtered if filtered is None else P.to_boolean(filtered, "filtered")
        out = self._core.render(camera.to_core(), gbuffer_depth, pixel_mask, filt, p.sigma, p.alpha,
                                p.gamma, p.tau_depth, p.max_tiles, p.max_candidates, p.ulr_k,
                                p.merge_rel, p.radius_sigmas, p.margin, p.near, p.cull_back,
                                p.max_angle, p.ray_stride, p.filter_step, self.free_space,
                                p.free_space_tol, p.free_space_point_tol, p.tau_empty, p.min_views,
                                p.stretch_weight, p.stretch_free,
                                p.resample, mode)
        times = {STAGE_NAMES[k]: float(v) for k, v in out["times_ms"].items()}
        if mode == "resolve":
            times = {k: times[k] for k in ("cluster & blend", "spatial filter")}
        stats = {"visible_coarse": int(out["visible_coarse"]), "tiles": int(out["tiles"]),
                 "triangles": int(out["triangles"]), "free_space": self._free_space_report}
        return PvmResult(color=out["color"], depth=out["depth"], valid=out["valid"], vote=out["vote"],
                         inside_grid=out["inside_grid"], times_ms=times, stats=stats)

    def candidates(self, camera: Camera) -> dict[str, np.ndarray]:
        """The last rendered frame's per-pixel candidate lists (count (H, W), depth and view
        (H, W, K); entries past count unspecified), ``stretch`` (H, W, K) with the stretch term on (log2 of
        each candidate's triangle's magnification in the target, octaves in steps of 1/16, clamped to
        +-8) and, when that frame clustered every pixel (no
        pixel mask), the cluster sizes ``n_fg``, ``n_bg`` (H, W) of Eq. 1 / Eq. 2 (``n_bg`` counts
        only the background candidates whose view sees past the foreground, with ``free_space``;
        0 = one cluster), for tests and inspection."""
        return self._core.candidates(camera.height, camera.width, self.params.max_candidates)
