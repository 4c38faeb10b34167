"""Hybrid image-based rendering (Prakash et al. 2021, sec. 3.3 and 6): ``--method tm``, ``ulr``
and ``hybrid`` (docs/hybrid.md).

Every method starts from the **G-buffer** of the global mesh's render mesh (the ``mesh`` stage;
the same surface as the dense mesh the per-vertex statistics live on, with fewer faces): the
nearest face at each pixel centre with depth, normal, prim_id and bary, rasterised for pinhole
cameras (``_core.raster_gbuffer``) and ray cast with Embree (``ReferenceRenderer``) for equirect
ones and for meshes dense for the frame (``RASTER_MAX_FACES``, ``RASTER_MAX_FACES_PER_PIXEL``).

* ``tm`` (textured mesh): the ``texture`` stage's atlas read bilinearly at the hit's UV (the
  face's UVs interpolated with the hit's barycentrics, C++ ``_core.sample_atlas``); a texture
  stage from before the atlas (no ``atlas`` array): its per-vertex colour interpolated
  (``_core.interpolate_vertex_attribute``). Pixels the mesh misses are holes.
* ``ulr`` (per-pixel Unstructured Lumigraph, Buehler et al. 2001): at each G-buffer point the
  input views are ranked by the ULR penalty (cpp/kernels/hybrid/ulr.h: angle + 0.5 x resolution term),
  views that do not see the point (outside the image, behind the surface, or the depth at the
  point's pixel differs by more than ``depth_tol`` = 0.5 % relative; that depth is the global mesh
  rendered into the view, ``occlusion=mesh``, or the view's own, ``occlusion=views``) are dropped, the best
  ``k`` = 4 are blended with weights falling to 0 at the 4th, reading the harmonised images
  (``harmonise`` stage; the original images when the stage was skipped) with Catmull-Rom
  (``resample`` = cubic; ``bilinear`` on request). Pixels no
  view sees fall back to TM when the scene has the ``texture`` stage (else they are holes).
* ``hybrid`` (Fig. 7): per pixel, outside the PVM grid -> ULR; PVM depth (the cluster vote of
  Eq. 2, ``tau_depth``) farther than ``geo_threshold`` (3 cm when the scene's units are a length;
  one voxel of the global mesh when they are not, :func:`geo_threshold_for`) from the global
  depth -> PVM; else the view-dependent texture (``harmonise`` stage) above ``tau_var`` -> ULR;
  else TM (``tau_var`` = -1 by default: never, TM is ULR's fallback where no view sees the point;
  0: TM where no view found the surface view-dependent). The one-hot selection is blurred
  (Gaussian ``sigma_blur`` = 16 px; at 1/4 resolution, variance matched, docs/hybrid.md), weights below
  ``min_weight`` (0.05) dropped and the rest normalised again, the PVM weight raised to at least
  ``pvm_floor`` (ours; "auto": the ``mix`` stage's value, fitted per scene on leave-one-out renders
  of input views, :func:`fit_pvm_floor`; 0 is the paper's composite), and the three colours composited;
  ULR is computed only where its weight is positive (or where a PVM pixel without candidates
  falls back to it). The PVM colour comes from
  :class:`ibrtools.hybrid.pvm_render.PvmRenderer` (clustered depth filtering, ``sigma``,
  ``alpha``, ``gamma``). The selection (red PVM, blue ULR, green TM; the blurred weights) is
  returned as output "selection" and written as ``<frame>.method.png`` by the render job.

Held-out views (``--holdout``) are absent from the job's scene, so ULR and PVM never read them;
the mesh, texture, variance and harmonise stages were computed with every view of the scene (as
in the paper's Ponche evaluation), so for unseen-view figures use the scene's targets, which no
stage reads.
"""
from __future__ import annotations

import copy
import math

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ibrtools import _core
from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, InputError, MissingFileError, ParamError
from ibrtools.hybrid.pvm_render import RESAMPLE, PvmParams
from ibrtools.mesh import Mesh
from ibrtools.scene import Scene
from ibrtools import params as P
from ibrtools.cache import load_npz, read_doc, stage_output
from ibrtools.hybrid.pvm_render import PvmRenderer, harmonised_images

# occlusion "mesh": each input view's depth for the occlusion test is the global mesh rendered
# into that view (the proxy ULR blends on, as in Buehler et al. and the paper's deferred ULR), so
# a surface point of the G-buffer is tested against the same geometry; "views": the views' own
# (captured) depth, which disagrees with a reconstructed mesh by more than depth_tol over much of
# the surface (measured: 11 % of pixels kept ULR on a 48-voxel fusion, docs/ulr.md).
# depth_tol 0.005 (was 0.02, the texture stage's): a view whose depth at the point's pixel differs
# by more than 0.5 % does not see the point; chosen on the selection scenes (lego validation views,
# synth:objects seed 1) over 0.0025 / 0.01 / 0.02 / 0.04: best PSNR on both (hybrid lego 27.80 ->
# 27.99 dB, FLIP 0.0502 -> 0.0487; synth 31.75 -> 31.87, 0.0596 -> 0.0588; ULR alone better too).
# The rejected views are those where the point sits at a depth edge of the view (its bilinear colour
# mixes both sides) or is seen at a grazing angle (docs/ulr.md "Parameters"). resample "cubic": the
# views' colours are read with Catmull-Rom (cpp/ibr/resample.h), sharper than bilinear; chosen on
# the selection scenes (docs/ulr.md "Parameters"; the PVM renderer reads its candidates the same way).
# k, resolution_weight, depth_tol: the kernel's defaults, defined once (cpp/kernels/hybrid/hybrid.h UlrOptions).
# k: the kernel's bound (UlrOptions::kMaxK, a fixed-size per-pixel list); the others only have to
# stay finite in the kernels' float32 (params.py FINITE_MAX).


@dataclass(frozen=True)
class TmParams(P.MethodParams):
    """``--method tm`` has no parameters."""

    method: ClassVar[str] = "tm"


@dataclass(frozen=True)
class UlrParams(P.MethodParams):
    """Parameters of ``--method ulr`` (docs/ulr.md "Parameters")."""

    method: ClassVar[str] = "ulr"
    k: int = P.integer(_core.ULR_DEFAULT_K, 1, _core.ULR_MAX_K)
    resolution_weight: float = P.number(_core.ULR_DEFAULT_RESOLUTION_WEIGHT, 0.0, maximum=P.FINITE_MAX)
    depth_tol: float = P.number(_core.ULR_DEFAULT_DEPTH_TOL, 0.0, strict=True, maximum=P.FINITE_MAX)
    harmonised: bool = P.boolean(True)
    occlusion: str = P.choice("mesh", ("mesh", "views"))
    resample: str = P.choice("cubic", RESAMPLE)
# sigma, alpha, gamma, tau_depth: the paper's sweep values (sec. 7). sigma_blur 16 px (the
# paper: 4): chosen on synth:objects seed 1, a scene no reported figure uses (12 views of
# 480x360, 4 targets: sigma_blur 4 / 8 / 12 / 16 -> hybrid 30.50 / 30.63 / 30.72 / 30.78 dB,
# SSIM 0.9316 / 0.9326 / 0.9332 / 0.9336; docs/hybrid.md "Parameters"). tau_var -1 (the paper: 0.82,
# which our view-dependent texture, an average of per-view binary masks, almost never reaches):
# below every vd value, so reliable geometry always goes to ULR and TM is left as ULR's fallback
# where no view sees the point. Chosen on synth:objects seed 1 and the lego validation views:
# every metric improves monotonically from 0.82 down to 0 (docs/hybrid.md "Parameters"), and again
# from 0 to -1 once the harmonised images keep the views' shading (harmonise diffuse="exposure":
# lego 27.45 / 0.9358 / 0.0559 -> 27.67 / 0.9406 / 0.0520, synth 31.31 / 0.9397 / 0.0641 -> 31.55 /
# 0.9431 / 0.0599; docs/hybrid.md "Parameters"). tau_var 0 keeps the paper's TM branch (vd = 0 -> TM).
# min_weight 0.05 (the paper: 0, no threshold): the largest value costing <= 0.01 dB on synth:objects
# seed 1 and the lego validation views; ULR / PVM colours then run on 37 / 53 % of a 1280x720 frame
# instead of 60 / 75 % (docs/hybrid.md "Parameters").
# geo_threshold None = geo_threshold_for(the scene's units, the mesh stage's voxel).
# TM is shaded at the pixels the composite reads alone when they are at most this share of the
# frame (a (1, n) G-buffer: indexing costs more per pixel than the full-frame shade).
TM_SUBSET_MAX = 0.25
# The G-buffer of a pinhole camera is rasterised when the mesh has at most RASTER_MAX_FACES faces and
# at most RASTER_MAX_FACES_PER_PIXEL faces per pixel of the frame, else ray cast by Embree: the
# rasteriser's cost grows with the faces (~110 ns each), the ray caster's with the pixels. Measured
# (docs/tm.md "The G-buffer"): these limits pick the faster of the two, or one within 5 % of
# it, on every mesh (10.9 k to 2.2 M faces) and frame (320x180 to 3200x3200) tried.
RASTER_MAX_FACES = 500_000
RASTER_MAX_FACES_PER_PIXEL = 0.3
# The hybrid parameters that are the PVM renderer's: its defaults, checked by it, passed to it.
PVM_KEYS = ("sigma", "alpha", "gamma", "tau_depth", "free_space", "free_space_tol", "free_space_point_tol", "tau_empty",
            "ulr_k", "min_views", "resample", "max_angle", "merge_rel", "stretch_weight", "stretch_free")
STAGES_FOR = {"tm": ("mesh", "texture"), "ulr": ("mesh", "depth"),
              "hybrid": ("mesh", "depth", "texture", "variance", "harmonise", "pvm", "mix")}
_UNIT_METRES = {"m": 1.0, "meter": 1.0, "metre": 1.0, "meters": 1.0, "metres": 1.0, "cm": 0.01, "mm": 0.001,
                "km": 1000.0}
SELECTION_COLORS = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], np.float32)  # TM, ULR, PVM


def _pvm_floor(v, name: str) -> str | float:
    """"auto" (fitted by the mix stage) or a weight in [0, 1]."""
    if v == "auto":
        return "auto"
    try:
        return P.to_number(v, name, 0.0, maximum=1.0)
    except ParamError:
        raise ParamError(name, f"expected 'auto' or a weight in [0, 1], got {v!r}") from None


@dataclass(frozen=True)
class HybridParams(UlrParams):
    """Parameters of ``--method hybrid`` (docs/hybrid.md "Parameters"): ULR's, the PVM renderer's
    PVM_KEYS (checked by it, passed to it) and the choice's own."""

    method: ClassVar[str] = "hybrid"
    sigma: float = P.same_as(PvmParams, "sigma")
    alpha: float = P.same_as(PvmParams, "alpha")
    gamma: float = P.same_as(PvmParams, "gamma")
    tau_depth: float = P.same_as(PvmParams, "tau_depth")
    free_space: bool = P.same_as(PvmParams, "free_space")
    free_space_tol: float = P.same_as(PvmParams, "free_space_tol")
    free_space_point_tol: float = P.same_as(PvmParams, "free_space_point_tol")
    tau_empty: float = P.same_as(PvmParams, "tau_empty")
    ulr_k: int = P.same_as(PvmParams, "ulr_k")
    min_views: int = P.same_as(PvmParams, "min_views")
    resample: str = P.same_as(PvmParams, "resample")
    max_angle: float = P.same_as(PvmParams, "max_angle")
    merge_rel: float = P.same_as(PvmParams, "merge_rel")
    stretch_weight: float = P.same_as(PvmParams, "stretch_weight")
    stretch_free: float = P.same_as(PvmParams, "stretch_free")
    tau_var: float = P.number(-1.0, -P.FINITE_MAX, maximum=P.FINITE_MAX)
    sigma_blur: float = P.number(16.0, 0.0, maximum=1000.0)
    min_weight: float = P.number(0.05, 0.0, maximum=1.0 / 3.0)
    geo_threshold: float | None = P.number(None, 0.0, maximum=P.FINITE_MAX, optional=True)
    filtered: bool = P.boolean(True)
    pvm_floor: str | float = P.custom("auto", _pvm_floor)

    def pvm(self) -> PvmParams:
        """The PVM renderer's parameters: PVM_KEYS from these, the rest its defaults."""
        return PvmParams.from_dict({k: getattr(self, k) for k in PVM_KEYS})

    def check(self) -> None:
        self.pvm()  # the PVM renderer's bounds between its fields


# geo_threshold in a scene without a length unit: this many voxels of the global mesh. Chosen on
# the lego validation views (docs/hybrid.md "geo_threshold"): 0.5 / 1 / 1.7 /
# 2.5 voxels -> hybrid 26.90 / 27.10 / 27.03 / 26.95 dB, the best mean rank of PSNR, SSIM and FLIP at 1.
GEO_THRESHOLD_VOXELS = 1.0


def geo_threshold_for(units: str, voxel: float | None = None) -> float:
    """The geometric-uncertainty threshold of the hybrid choice (Fig. 7) for a scene in ``units``
    whose global mesh has voxels of ``voxel`` (the mesh stage's record). The paper's 3 cm
    converted to the units when they are a length (m, cm, mm, km). Otherwise ("unknown": nerf
    and COLMAP scenes are up to scale; "disparity") 3 cm means nothing, and the threshold is
    ``GEO_THRESHOLD_VOXELS`` voxels: the global mesh is a TSDF fusion at that voxel (or a given
    mesh sampled at it), so a PVM depth nearer to it than that is within the mesh's own error.
    3 cm read as metres when there is no voxel either."""
    metres = _UNIT_METRES.get(str(units).strip().lower())
    if metres is not None:
        return 0.03 / metres
    if voxel is not None and math.isfinite(voxel) and voxel > 0:
        return GEO_THRESHOLD_VOXELS * float(voxel)
    return 0.03


def _stage_record(scene: Scene, stage: str) -> dict:
    """The stage's record in the scene directory's scene.json ({} when none): read from the file,
    not ``scene.stages``, since stages may have run after the scene was loaded."""
    if scene.root is None:
        return {}
    return (read_doc(scene.root).get("stages") or {}).get(stage) or {}


def _stage(scene: Scene, stage: str, method: str):
    if scene.root is None:
        raise InputError.about("method", f"the scene has no directory with preprocessed stages; "
                                   f"run: ibr-preprocess INPUT -o SCENE --methods {method}", method)
    try:
        return load_npz(stage_output(scene.root, stage))
    except MissingFileError as e:
        raise MissingFileError.about("method", f"needs stage {stage!r}: {e}; or run: "
                                     f"ibr-preprocess {scene.root} -o {scene.root} --methods {method}",
                                     method) from None


def _miss_at_infinity(gb: dict) -> np.ndarray:
    """The G-buffer's depth with +inf where the ray missed the global mesh: it sees the background
    at infinity (inpaint/background.py gives it the background's colour where the scene has one)."""
    return np.where(gb["hit"], gb["depth"], np.float32(np.inf)).astype(np.float32)


class _GlobalMesh:
    """The global mesh's ray caster, per-vertex attributes and G-buffer."""

    def __init__(self, scene: Scene, method: str, texture: bool):
        from ibrtools.raycast.reference import ReferenceRenderer

        d = _stage(scene, "mesh", method)
        # The render mesh (mesh stage, GlobalMeshOptions.render_edge_voxels): the same surface as
        # the dense mesh with fewer faces; the dense one when the stage stored no other.
        self.dense_vertices = len(d["vertices"])
        pre = "render_" if "render_vertices" in d else ""
        self.mesh = Mesh(d[pre + "vertices"], d[pre + "faces"], object_ids=d.get(pre + "object_ids"),
                         kind="reconstructed")
        t0 = time.perf_counter()
        self.renderer = ReferenceRenderer(self.mesh)
        self.build_ms = (time.perf_counter() - t0) * 1e3
        self.faces = np.ascontiguousarray(self.mesh.faces, np.int32)
        self._vertices32: np.ndarray | None = None
        self.colors = None
        self.atlas = self.uv = None
        if texture:
            tex = _stage(scene, "texture", method)
            self.colors = np.ascontiguousarray(tex["vertex_colors"], np.float32)
            rerun = f"; rerun ibr-preprocess {scene.root} -o {scene.root} --stages texture --force"
            if self.colors.shape != (len(self.mesh.vertices), 3):
                raise InputError(f"texture stage: vertex_colors shape {self.colors.shape} does not match the mesh's "
                                 f"{len(self.mesh.vertices)} vertices" + rerun)
            if "atlas" in tex:
                # uint8 (h, w, 4) sRGB RGBA (texture stage v3), or float32 (h, w, 3) linear (v2)
                a = tex["atlas"]
                self.atlas = np.ascontiguousarray(a, np.uint8 if a.dtype == np.uint8 else np.float32)
                self.uv = np.ascontiguousarray(tex["uv"], np.float32)
                if (self.uv.shape != (len(self.faces), 3, 2) or self.atlas.ndim != 3
                        or self.atlas.shape[2] != (4 if a.dtype == np.uint8 else 3)):
                    raise InputError(f"texture stage: atlas {self.atlas.shape} / uv {self.uv.shape} do not match the "
                                     f"mesh's {len(self.faces)} faces" + rerun)

    def gbuffer(self, camera: Camera, normal: bool = True) -> dict:
        """depth, prim_id, bary (and the normal, for ULR's back-face test); hit = prim_id >= 0.
        Pinhole cameras and a mesh of at most RASTER_MAX_FACES faces, RASTER_MAX_FACES_PER_PIXEL
        per pixel: rasterised (``_core.raster_gbuffer``: the same nearest face per pixel centre as the ray
        caster, faster for such meshes, tests/hybrid/test_hybrid_raster.py); else (equirect, or a mesh
        dense for the frame): Embree."""
        from ibrtools import _core

        faces = len(self.faces)
        few = faces <= min(RASTER_MAX_FACES, RASTER_MAX_FACES_PER_PIXEL * camera.width * camera.height)
        if camera.model == "pinhole" and few:
            if self._vertices32 is None:
                self._vertices32 = np.ascontiguousarray(self.mesh.vertices, np.float32)
            out = dict(_core.raster_gbuffer(camera.to_core(), self._vertices32, self.faces, normal=normal))
        else:
            names = ("depth", "normal", "prim_id", "bary") if normal else ("depth", "prim_id", "bary")
            out = self.renderer.render(camera, outputs=names, lights=[], ambient=0.0)
        out["hit"] = out["prim_id"] >= 0
        return out

    def tm_color(self, gb: dict) -> np.ndarray:
        """TM colour at the G-buffer's hits: the atlas when the texture stage has one, else the
        per-vertex colour."""
        from ibrtools import _core

        if self.atlas is not None:
            return _core.sample_atlas(gb["prim_id"], gb["bary"], self.uv, self.atlas)
        return self.interpolate(gb, self.colors)

    def tm_color_at(self, gb: dict, pixels: np.ndarray, out: np.ndarray) -> None:
        """TM colour written into ``out`` (H, W, 3) at the flat pixel indices ``pixels`` only (a
        (1, n) G-buffer of those pixels: the same values as :meth:`tm_color` there)."""
        if pixels.size:
            sub = {"prim_id": gb["prim_id"].reshape(1, -1)[:, pixels], "bary": gb["bary"].reshape(1, -1, 2)[:, pixels]}
            out.reshape(-1, 3)[pixels] = self.tm_color(sub).reshape(-1, 3)

    def interpolate(self, gb: dict, attrib: np.ndarray) -> np.ndarray:
        from ibrtools import _core

        return _core.interpolate_vertex_attribute(gb["prim_id"], gb["bary"], self.faces, attrib)


def _views_for_ulr(scene: Scene, method: str, harmonised: bool, gm: "_GlobalMesh | None" = None,
                   harmonise: dict | None = None) -> tuple[list, str]:
    """[(core camera, colour, depth)] of the input views: harmonised colour when the harmonise
    stage has it (``harmonise``: its arrays, when the caller has loaded them); depth = the
    global mesh rendered into the view (``gm`` given: occlusion "mesh"), else the view's depth
    or the depth stage's rendering."""
    images: dict = {}
    source = "original"
    if harmonised and scene.root is not None:
        rec = _stage_record(scene, "harmonise")
        if rec.get("outputs"):
            images = harmonised_images(harmonise if harmonise is not None else _stage(scene, "harmonise", method))
            source = "harmonised"
        elif rec.get("skipped"):
            source = f"original (harmonise skipped: {rec['skipped']})"
    depths: dict = {}
    if gm is None:
        from ibrtools.cache import view_depths

        try:
            depths = view_depths(scene.views, lambda: _stage(scene, "depth", method))
        except KeyError as e:
            raise InputError.about("method", f"view {e.args[0]!r} has no depth and the depth stage has none; "
                                       f"rerun ibr-preprocess {scene.root} -o {scene.root} --stages depth --force",
                                   method) from None
    out = []
    for v in scene.views:
        if gm is not None:
            depth = gm.renderer.render(v.camera, outputs=("depth",), lights=[], ambient=0.0)["depth"]
        else:
            depth = depths[v.name]
        color = images.get(v.name)
        if color is None:
            color = v.color
        out.append((v.camera.to_core(), np.ascontiguousarray(color, np.float32),
                    np.ascontiguousarray(depth, np.float32)))
    if not out:
        raise InputError.about("method", "the scene has no input views", method)
    return out, source


class TmMethod:
    """Textured global mesh (the texture stage's atlas)."""

    name = "tm"

    def __init__(self, params: dict | TmParams | None = None):
        self.params = TmParams.from_dict(params)
        self._gm: _GlobalMesh | None = None

    def prepare(self, scene: Scene) -> dict[str, float]:
        t0 = time.perf_counter()
        self._gm = _GlobalMesh(scene, "tm", texture=True)
        return {"load": (time.perf_counter() - t0) * 1e3 - self._gm.build_ms, "bvh": self._gm.build_ms}

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        if self._gm is None:
            raise BadValueError("tm: prepare(scene) must be called before render")
        t0 = time.perf_counter()
        gb = self._gm.gbuffer(camera, normal=False)
        t1 = time.perf_counter()
        color = self._gm.tm_color(gb)
        t2 = time.perf_counter()
        return ({"color": color, "depth": _miss_at_infinity(gb), "hole": ~gb["hit"]},
                {"gbuffer": (t1 - t0) * 1e3, "tm_shade": (t2 - t1) * 1e3})


class UlrMethod:
    """Per-pixel ULR at the global mesh's points; TM where no view sees the point."""

    name = "ulr"

    def __init__(self, params: dict | UlrParams | None = None):
        self.params = UlrParams.from_dict(params)
        self._gm: _GlobalMesh | None = None
        self._last: dict = {}

    def prepare(self, scene: Scene) -> dict[str, float]:
        t0 = time.perf_counter()
        has_tex = bool(_stage_record(scene, "texture").get("outputs"))
        self._gm = _GlobalMesh(scene, "ulr", texture=has_tex)
        self._views, self._source = _views_for_ulr(scene, "ulr", self.params.harmonised,
                                                   self._gm if self.params.occlusion == "mesh" else None)
        return {"load": (time.perf_counter() - t0) * 1e3 - self._gm.build_ms, "bvh": self._gm.build_ms}

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        from ibrtools import _core

        if self._gm is None:
            raise BadValueError("ulr: prepare(scene) must be called before render")
        p = self.params
        t0 = time.perf_counter()
        gb = self._gm.gbuffer(camera)
        t1 = time.perf_counter()
        ulr, count = _core.ulr_blend(camera.to_core(), gb["depth"], self._views, normal=gb["normal"], k=p.k,
                                     resolution_weight=p.resolution_weight, depth_tol=p.depth_tol,
                                     resample=p.resample)
        t2 = time.perf_counter()
        seen = count > 0
        times = {"gbuffer": (t1 - t0) * 1e3, "ulr_blend": (t2 - t1) * 1e3}
        if self._gm.colors is not None:
            # TM only where the mesh is hit and no view sees the point (0.05 % of the hits on the
            # benchmark frames), read at those pixels alone (a (1, n) G-buffer) and written into
            # the ULR image in place; elsewhere ULR's colour stands (0 where nothing is hit, as
            # TM's): the same image as np.where(seen, ulr, tm over the frame), ~5 ms less serial
            # NumPy per 1280x720 frame.
            color = ulr
            self._gm.tm_color_at(gb, np.flatnonzero(gb["hit"] & ~seen), color)
            hole = ~gb["hit"]
            times["tm_fallback"] = (time.perf_counter() - t2) * 1e3
        else:
            color, hole = ulr, ~seen
        hit = gb["hit"]
        self._last = {"images": self._source,
                      "ulr_fraction": round(float(seen.sum() / max(1, hit.sum())), 4)}
        return {"color": color, "depth": _miss_at_infinity(gb), "hole": hole}, times

    def frame_report(self) -> dict:
        return dict(self._last)


class HybridMethod:
    """Per-pixel choice of TM / ULR / PVM (Fig. 7) with the blurred selection mask."""

    name = "hybrid"

    def __init__(self, params: dict | HybridParams | None = None):
        self.params = HybridParams.from_dict(params)
        self._gm: _GlobalMesh | None = None
        self._last: dict = {}

    def prepare(self, scene: Scene) -> dict[str, float]:
        try:
            from ibrtools.hybrid.pvm_render import PvmRenderer, load_images
        except ImportError:
            from ibrtools.errors import NotBuiltError

            raise NotBuiltError.about("method", "the PVM renderer (ibrtools.hybrid.pvm_render) is not built yet",
                                      "hybrid") from None
        t0 = time.perf_counter()
        self._gm = _GlobalMesh(scene, "hybrid", texture=True)
        h = None  # the harmonise stage, loaded once for ULR's images, PVM's and the vd texture
        rec = _stage_record(scene, "harmonise")
        if rec.get("outputs"):
            h = _stage(scene, "harmonise", "hybrid")
        elif not rec.get("skipped"):
            _stage(scene, "harmonise", "hybrid")  # raises, naming the command
        self._views, self._source = _views_for_ulr(scene, "hybrid", self.params.harmonised,
                                                   self._gm if self.params.occlusion == "mesh" else None, h)
        self._view_names = [v.name for v in scene.views]  # _views_for_ulr's order
        self._vd = None
        if h is not None and ("vd_render" in h or "vd_texture" in h):
            # per vertex of the render mesh ("vd_render"), or of the dense mesh when it is the same
            self._vd = np.ascontiguousarray(h["vd_render" if "vd_render" in h else "vd_texture"], np.float32)
            if self._vd.shape != (len(self._gm.mesh.vertices),):
                raise InputError(f"harmonise stage: vd_texture shape {self._vd.shape} does not match the mesh; "
                                 f"rerun ibr-preprocess {scene.root} -o {scene.root} --stages harmonise --force")
        p = self.params
        voxel = (_stage_record(scene, "mesh").get("details") or {}).get("voxel")
        self._geo = (geo_threshold_for(scene.units, voxel if isinstance(voxel, (int, float)) else None)
                     if p.geo_threshold is None else p.geo_threshold)
        self._floor, self._floor_source = self._resolve_floor(scene)
        t1 = time.perf_counter()
        self._pvm = PvmRenderer(scene, p.pvm(), images=load_images(scene, h))
        t2 = time.perf_counter()
        return {"load": (t1 - t0) * 1e3 - self._gm.build_ms, "bvh": self._gm.build_ms, "pvm_load": (t2 - t1) * 1e3}

    def _without_views(self, scene: Scene) -> "HybridMethod":
        """This method prepared for ``scene``, the scene it was prepared for with some input views
        taken out (``plan(..., holdout=)``'s scene), without loading the stages again: the global
        mesh, the ULR inputs and the PVM tiles, images and depths are shared; the views that
        ``scene`` lacks are dropped from ULR and disabled in PVM, as preparing for ``scene`` does.
        Renders what ``prepare(scene)`` would, bit for bit (the mix stage's fit;
        tests/hybrid/test_hybrid_render.py). Occlusion "mesh" (the default) only: with "views", prepare."""
        if self._gm is None:
            raise BadValueError("hybrid: prepare(scene) must be called before _without_views")
        keep = {v.name for v in scene.views}
        if not keep <= set(self._view_names) or self.params.occlusion != "mesh":
            raise BadValueError("hybrid: _without_views needs a subset of the prepared scene's views "
                                "and occlusion mesh")
        m = copy.copy(self)
        m._views = [v for v, name in zip(self._views, self._view_names) if name in keep]
        m._view_names = [name for name in self._view_names if name in keep]
        # depths None: some view had no depth map; the subset may have them all, so PVM loads its own
        m._pvm = PvmRenderer(scene, self._pvm.params, tiles=self._pvm.tiles, images=self._pvm.images,
                             depths=self._pvm.depths)
        m._last = {}
        return m

    def _resolve_floor(self, scene: Scene) -> tuple[float, str]:
        """pvm_floor: the parameter when it is a number; "auto": the mix stage's fit (0 when the
        stage skipped the scene, e.g. too few views to hold one out)."""
        f = self.params.pvm_floor
        if f != "auto":
            return float(f), "parameter"
        rec = _stage_record(scene, "mix")
        if rec.get("skipped") and not rec.get("outputs"):
            return 0.0, f"mix stage skipped: {rec['skipped']}"
        return float(_stage(scene, "mix", "hybrid")["pvm_floor"]), "mix stage"

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        out, times, _ = self._render(camera, (self._floor,))
        return out, times

    def _render(self, camera: Camera, floors: tuple[float, ...]):
        """The frame at ``floors[0]`` (outputs, stage times) and its colour at every pvm_floor of
        ``floors`` (each < 1: the TM and ULR weights keep their support, so the colours computed
        for the largest serve them all; the mix stage's fit)."""
        from ibrtools import _core

        if self._gm is None:
            raise BadValueError("hybrid: prepare(scene) must be called before render")
        if not floors or (len(floors) > 1 and not all(0.0 <= f < 1.0 for f in floors)):
            raise BadValueError(f"hybrid: floors {floors!r}: expected one weight, or several in [0, 1)")
        p = self.params
        times: dict[str, float] = {}
        t0 = time.perf_counter()
        gb = self._gm.gbuffer(camera)
        t1 = time.perf_counter()
        # The view-dependent texture lies in [0, 1]: with tau_var < 0 the test sends every pixel to
        # ULR whatever it is, and it is not interpolated.
        vd = self._gm.interpolate(gb, self._vd) if self._vd is not None and p.tau_var >= 0 else None
        t2 = time.perf_counter()
        times["gbuffer"], times["vd"] = (t1 - t0) * 1e3, (t2 - t1) * 1e3
        # PVM in two passes: the depth pass (candidates of the visible voxels, 2-means, the Eq. 2
        # vote) at every pixel, which the geometric test needs; colours (cluster blend, spatial
        # filter) only where the blurred mask gives PVM a weight (resolve, below).
        res = self._pvm.depth_pass(camera, gbuffer_depth=gb["depth"])
        t3 = time.perf_counter()
        for k, v in (res.times_ms or {}).items():
            times[k] = float(v)  # the PVM stages of Table 2: voxel lookup, tile sort, ...
        inside = np.ascontiguousarray(res.inside_grid, bool)
        valid = np.ascontiguousarray(res.valid, bool)
        pvm_depth = np.ascontiguousarray(res.depth, np.float32)
        label = _core.hybrid_select(gb["depth"], inside_grid=inside, pvm_valid=valid, pvm_depth=pvm_depth, vd=vd,
                                    geo_threshold=self._geo, tau_var=p.tau_var)
        by_floor: dict[float, np.ndarray] = {}

        def weights_at(floor):  # the blurred selection at a floor, computed once
            if floor not in by_floor:
                by_floor[floor] = _core.blur_selection(label, p.sigma_blur, p.min_weight, decimate=True,
                                                       pvm_floor=floor)
            return by_floor[floor]

        need_ulr, need_pvm, n_ulr, n_pvm = _core.hybrid_needs(weights_at(max(floors)), valid)
        weights = weights_at(floors[0])
        t4 = time.perf_counter()
        times["masking"] = (t4 - t3) * 1e3
        pvm_color = None
        if n_pvm:
            col = self._pvm.resolve(camera, pixel_mask=need_pvm, filtered=p.filtered)
            for k, v in (col.times_ms or {}).items():
                times[k] = times.get(k, 0.0) + float(v)
            pvm_color = np.ascontiguousarray(col.color, np.float32)
        t4 = time.perf_counter()
        if n_ulr:
            ulr, count = _core.ulr_blend(camera.to_core(), gb["depth"], self._views, normal=gb["normal"],
                                         pixel_mask=need_ulr, k=p.k, resolution_weight=p.resolution_weight,
                                         depth_tol=p.depth_tol, resample=p.resample)
        else:
            ulr, count = None, None
        t5 = time.perf_counter()
        times["ulr_blend"] = (t5 - t4) * 1e3
        # TM where the composite reads it: a TM weight, or ULR's fallback where ULR is needed and no
        # view sees the point, on the mesh (TM is 0 off it, as the zeros below). With tau_var < 0
        # that is a few pixels: shaded there alone (elsewhere TM's weight is 0 and the zeros give
        # the same composite, bit for bit).
        need_tm = weights[..., 0] > 0
        if count is not None:
            need_tm |= need_ulr & (count == 0)
        need_tm &= gb["hit"]
        n_tm = int(np.count_nonzero(need_tm))
        if n_tm > TM_SUBSET_MAX * need_tm.size:
            tm = self._gm.tm_color(gb)
        else:
            tm = np.zeros(gb["depth"].shape + (3,), np.float32)
            self._gm.tm_color_at(gb, np.flatnonzero(need_tm), tm)
        t6 = time.perf_counter()
        times["tm_shade"] = (t6 - t5) * 1e3
        parts = dict(tm=tm, ulr=ulr, ulr_count=count, pvm=pvm_color, pvm_valid=valid if pvm_color is not None else None)
        colors = [_core.hybrid_composite(weights_at(f), **parts) for f in floors]
        color = colors[0]
        # hole (label none), depth (PVM's where chosen), the selection image (weights @
        # SELECTION_COLORS, 0 at holes) and the label counts in one pass (numpy: ~15 ms at 1280x720)
        fo = _core.hybrid_frame_outputs(label, weights, gb["depth"], pvm_depth)
        fo["depth"] = np.where(gb["hit"] | ~fo["hole"], fo["depth"], np.float32(np.inf))  # rays that miss the mesh
        times["composite"] = (time.perf_counter() - t6) * 1e3
        n = label.size
        self._last = {"selection": {name: round(fo["label_counts"][i] / n, 4)
                                    for i, name in enumerate(("tm", "ulr", "pvm", "none"))},
                      "ulr_pixels": int(n_ulr), "pvm_pixels": int(n_pvm), "tm_pixels": n_tm,
                      "geo_threshold": self._geo, "images": self._source,
                      "pvm_floor": floors[0], "pvm_floor_source": self._floor_source,
                      "free_space": (res.stats or {}).get("free_space")}
        return ({"color": color, "depth": fo["depth"], "hole": fo["hole"], "selection": fo["selection"],
                 "label": label}, times, colors)

    def frame_report(self) -> dict:
        return dict(self._last)


