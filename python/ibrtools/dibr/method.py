"""Multi-view depth-image-based rendering, RVS class (Bonatto et al. 2021): ``--method dibr``.

Per frame:
  select  the k inputs most similar to the target camera (view_selection.py: frustum-intersection
          volume by Monte Carlo x viewing-direction agreement, Eq. 4-7), or the listed inputs;
          inputs that do not overlap the target are never warped;
  warp    each selected view is forward-warped as an implicit triangle mesh into the target
          (C++ kernel cpp/kernels/dibr/forward_warp.cpp, triangle quality of the paper's Table 1,
          combined depth test within a view) and accumulated at once into
          ``_core.DibrAccumulator`` (cpp/kernels/dibr/blend.cpp): constant memory whatever the
          number of inputs, views are streamed one at a time;
  blend   weighted mean of the warped views (Eq. 3) with weights (q / d)^p, p = --blend-exponent
          (RVS's BlendingFactor 5 by default).

Holes (no input covers the pixel) stay black and are returned as the ``hole`` mask; filling
them is the inpainting issue's job.

Parameters (``ibr-render --inputs/--quality/--blend-exponent`` or ``--param key=value``)
  inputs          K (int, default 4) = the K best views by similarity, or a list of view names
                  (list or "v1,v2,...") = those views, minus any that do not overlap the target
  quality         side | shape | depth | normal: the triangle quality measure (Table 1)
  blend_exponent  p in (0, 16] in the blending weight (q / d)^p (default 5, as RVS)
  side_threshold  T in [0, 1e6] target pixels for the "side" quality (default 10, RVS's absolute value);
                  0 = the kernel's resolution-scaled default
  samples, seed   Monte Carlo samples per target for view selection (1..100000, default 4000) and the seed
  blend_space     srgb (default) | linear: the values that are interpolated and blended. "srgb"
                  warps and blends the sRGB-encoded colours (what RVS does: it blends the stored
                  YUV code values; each selected view is encoded once and cached) and the kernel
                  decodes the result in its resolve; "linear" blends linear light; see
                  docs/dibr_accuracy.md, "Blend space"
  distance_exponent  beta >= 0: each selected view's fragment weights are multiplied by
                  (b_min / b_i)^beta, b_i = the distance from its camera centre to the target's,
                  b_min the smallest (the nearest view keeps factor 1; MPEG VSRS weights its two
                  views by inverse baseline distance, beta = 1); 0 = RVS (every view alike)
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import InputError, ParamError
from ibrtools.scene import Scene
from ibrtools import _core
from ibrtools import params as P
from ibrtools.dibr import view_selection as vs
from ibrtools.cache import missing_depth_error, with_stage_depth

QUALITIES = ("side", "shape", "depth", "normal")
# side_threshold 10 px: RVS 4.0's q = clamp(10000 - 1000 L, 1, 10000) is q = 1 - L / 10 with L in
# target pixels, whatever the resolution. Measured (docs/dibr.md, "Parameters"): on the real-data
# cases T = 10 beats the kernel's resolution-scaled auto T (5.6 px at 800x800, 4 px at 640x480)
# by +0.5 dB on lego object pixels and +0.2 dB on ICL-NUIM, and changes Middlebury by < 0.05 dB.
# stretched_quality 0.1 with stretched_holes (cpp/kernels/dibr/blend.h, "Visibility across views"):
# a fragment on a triangle stretched past 0.9 T never mixes into real surface, and pixels only
# such fragments cover are holes (background that no input sees is a hole, not
# stretched foreground). Measured (docs/dibr.md): lego all pixels +1.4 dB, RVS-protocol
# (nearest-filled) figures within +-0.1 dB. depth_tolerance stays 0 (RVS: every view's front
# fragment is blended): 0.02-0.05 gains +1.7 dB on exact synthetic depth but loses 0.16 dB on
# ICL-NUIM's noisy depth. distance_exponent stays 0 (RVS: every selected view alike): beta chosen
# on lego validation views (3 with the srgb blend space, 4 with linear) gains +1.4-1.7 dB on lego
# object pixels but loses 0.3-0.6 dB on ICL-NUIM, whose nearest input has the worse ground-truth
# pose (docs/dibr_accuracy.md, "lego").
_WARP = _core.WarpOptions()  # the kernel's defaults (RVS 4.0): the triangle quality and the blend exponent
# blend_space "srgb" (the default since 2026-11-22): the kernel interpolates and blends the sRGB
# encodings of the colours (RVS blends the stored code values) and decodes the result in its
# resolve (DibrAccumulator.result(srgb_to_linear=True)). The weighted mean of misregistered samples
# is the estimate of least squared error in the space it is taken in, so blending in the display
# encoding is what an sRGB PSNR rewards. Chosen on data that picks no other parameter (docs/dibr_accuracy.md,
# "Blend space"): lego object pixels on the 8 validation views 22.84 -> 23.35 dB (all 8 gain), over
# the 40-view spread 23.40 -> 23.91 (39 of 40 gain), the synthetic bench_dibr job 29.32 -> 29.39 dB;
# it costs ~4.5 ms of one core per 1080p frame (the decode, ~2.7 % of the job's CPU; the encode is
# once per input view, ~19 ms at 1080p). ICL-NUIM loses 0.03 dB (still above RVS), Middlebury 0.01.
BLEND_SPACES = ("linear", "srgb")
# Upper bounds of the numeric parameters (docs/dibr.md "Parameters"), shared by ibr-render, ibr-bench
# and DibrMethod. blend_exponent: the kernel's (cpp/bindings/dibr.cpp: (q / d)^p overflows float32
# past 16 for the depths it weights, 1e-6..1e6). samples: view selection multiplies an (M, N, 3)
# float64 matrix of N samples for M inputs: 100 000 samples are 240 MB for 100 inputs (25x the
# default 4000). side_threshold: pixels, float32 in the kernel.
MAX_SAMPLES = 100_000


def parse_inputs(v, name: str = "inputs") -> int | list[str]:
    """The selected inputs: a count K >= 1 or view names (a list, or "v1,v2,...")."""
    if isinstance(v, bool):
        raise ParamError(name, f"expected a count K >= 1 or view names v1,v2,..., got {v!r}")
    if isinstance(v, (int, np.integer)):
        if v < 1:
            raise ParamError(name, f"expected a count K >= 1 or view names v1,v2,..., got {v}")
        return int(v)
    if isinstance(v, float):
        raise ParamError(name, f"expected a whole count K >= 1 or view names, got {v}")
    if isinstance(v, str):
        s = v.strip()
        if s.lstrip("+-").isdigit():
            return parse_inputs(int(s), name)
        names = [n.strip() for n in s.split(",")]
    elif isinstance(v, (list, tuple)):
        names = [str(n).strip() for n in v]
    else:
        raise ParamError(name, f"expected a count K or view names v1,v2,..., got {type(v).__name__}")
    if not names or any(not n for n in names):
        raise ParamError(name, f"empty view name in {v!r} (expected K or v1,v2,...)")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ParamError(name, f"view(s) listed twice: {dup}")
    return names


@dataclass(frozen=True)
class DibrParams(P.MethodParams):
    """Parameters of ``--method dibr`` (docs/dibr.md "Parameters")."""

    method: ClassVar[str] = "dibr"
    inputs: int | list[str] = P.custom(vs.DEFAULT_K, parse_inputs)
    quality: str = P.choice(_WARP.quality, QUALITIES)
    blend_exponent: float = P.number(float(_WARP.blend_exponent), 0.0, strict=True, maximum=16.0)
    side_threshold: float = P.number(10.0, 0.0, maximum=P.FINITE_MAX)
    samples: int = P.integer(vs.DEFAULT_SAMPLES, 1, MAX_SAMPLES)
    seed: int = P.integer(vs.DEFAULT_SEED, 0)
    stretched_quality: float = P.number(0.1, 0.0, maximum=1.0)
    stretched_holes: bool = P.boolean(True)
    depth_tolerance: float = P.number(0.0, 0.0, maximum=1.0, strict_max=True)
    blend_space: str = P.choice("srgb", BLEND_SPACES)
    distance_exponent: float = P.number(0.0, 0.0, maximum=16.0)


class DibrMethod:
    """``--method dibr`` (see the module doc)."""

    name = "dibr"

    def __init__(self, params: dict | DibrParams | None = None):
        self.params = DibrParams.from_dict(params)
        self.last_frame: dict = {}
        self._scene: Scene | None = None

    def warp_options(self):
        from ibrtools import _core

        o = _core.WarpOptions()
        o.quality = self.params.quality
        o.side_threshold = float(self.params.side_threshold)
        o.blend_exponent = float(self.params.blend_exponent)
        return o

    def prepare(self, scene: Scene) -> dict[str, float]:
        if not scene.views:
            raise InputError.about("method", "the scene has no input views", "dibr")
        scene = with_stage_depth(scene)  # photographs: the mvs stage's depth (else the mesh's)
        no_depth = [v.name for v in scene.views if not v.has_depth]
        if no_depth:
            raise missing_depth_error("dibr", scene, no_depth)
        no_color = [v.name for v in scene.views if not v.has_color]
        if no_color:
            raise InputError.about("method", f"needs colour for every input view; without colour: "
                                   f"{', '.join(no_color[:5])}", "dibr")
        names = [v.name for v in scene.views]
        inputs = self.params.inputs
        if isinstance(inputs, list):
            missing = [n for n in inputs if n not in names]
            if missing:
                raise ParamError("inputs", f"view(s) {missing} not among the input views "
                                           f"(held-out views are not inputs)")
            self._candidates = [names.index(n) for n in inputs]
            self._k = len(inputs)
        else:
            self._candidates = None
            self._k = inputs
        t0 = time.perf_counter()
        self._views = vs.ViewSet.of(scene.views)
        ranges_ms = (time.perf_counter() - t0) * 1e3
        self._scene = scene
        self._core_cams = [c.to_core() for c in self._views.cameras]
        self._options = None  # made at the first render (the kernel's WarpOptions)
        self._encoded: dict[int, np.ndarray] = {}  # blend_space "srgb": encoded colour of the selected views
        return {"depth_ranges": ranges_ms}

    def select(self, camera: Camera) -> vs.Selection:
        return self._views.select(camera, self._k, candidates=self._candidates,
                                  samples=self.params.samples, seed=self.params.seed)

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        from ibrtools import _core

        if self._scene is None:
            raise InputError("dibr: prepare(scene) must be called before render(camera)")
        if self._options is None:
            self._options = self.warp_options()
        t0 = time.perf_counter()
        sel = self.select(camera)
        t1 = time.perf_counter()
        acc = _core.DibrAccumulator(camera.to_core(), float(self.params.stretched_quality),
                                    self.params.stretched_holes, float(self.params.depth_tolerance))
        for i in [i for i in self._encoded if i not in sel.indices]:
            del self._encoded[i]  # the cache holds the selected views only (memory: k encoded copies)
        factors = self.view_factors(camera, sel.indices)
        for i, f in zip(sel.indices, factors):
            v = self._scene.views[i]
            opts = self._options
            if f != 1.0:
                opts = self.warp_options()
                opts.view_weight = f
            acc.add_view(self._input_color(i, v.color), np.ascontiguousarray(v.depth, np.float32),
                         self._core_cams[i], opts)
        t2 = time.perf_counter()
        # blend_space "srgb": the kernel decodes the blended colour in its resolve (row by row).
        color, depth, confidence, hole = acc.result(srgb_to_linear=self.params.blend_space == "srgb")
        t3 = time.perf_counter()
        views = self._scene.views
        self.last_frame = {
            "selected": [views[i].name for i in sel.indices],
            "similarity": [round(float(sel.scores[i]), 6) for i in sel.indices],
            "candidates": len(sel.candidates),
            "skipped_no_overlap": int(sel.skipped),
        }
        if self.params.distance_exponent > 0:
            self.last_frame["view_factors"] = [round(f, 6) for f in factors]
        out = {"color": color, "depth": depth, "confidence": confidence, "hole": hole}
        return out, {"select": (t1 - t0) * 1e3, "warp": (t2 - t1) * 1e3, "blend": (t3 - t2) * 1e3}

    def view_factors(self, camera: Camera, indices) -> list[float]:
        """Per-view weight factors (b_min / b_i)^distance_exponent of the views ``indices`` for
        the target ``camera`` (module doc), in [1e-6, 1]; all 1 when the exponent is 0. A view
        at the target's own centre (b_i = 0) gets 1 and the others the floor 1e-6."""
        beta = float(self.params.distance_exponent)
        if beta == 0.0 or len(indices) == 0:
            return [1.0] * len(indices)
        b = np.array([np.linalg.norm(self._views.cameras[i].centre - camera.centre) for i in indices])
        b = np.maximum(b, 1e-9 * (1.0 + float(b.max())))
        return [float(x) for x in np.clip((b.min() / b) ** beta, 1e-6, 1.0)]

    def _input_color(self, i: int, color: np.ndarray) -> np.ndarray:
        """View i's colour as the kernel blends it: linear, or its sRGB encoding (cached)."""
        if self.params.blend_space == "linear":
            return np.ascontiguousarray(color, np.float32)
        if i not in self._encoded:
            self._encoded[i] = srgb_encode(color)
        return self._encoded[i]

    def frame_report(self) -> dict:
        """What report.json records for the last frame (selected views, skipped count)."""
        return dict(self.last_frame)


def srgb_encode(v: np.ndarray) -> np.ndarray:
    """sRGB encoding (IEC 61966-2-1) of linear colour as a new float32 array of v's shape: negative
    values as 0, values above 1 on the same curve (not clipped: HDR inputs keep their range
    through the blend), NaN stays NaN (``add_view`` then rejects the view, as in linear space).
    The C++ ``_core.srgb_encode_unclipped`` (cpp/kernels/inpaint/metameric.h LinearToSrgbUnclipped: a
    table of the curve's own values in [0, 1], the curve ``SrgbEncode`` above; within 1e-6 of the
    exact curve; ~6 ms of one core per 1080p RGB view, the curve per value ~18 ms); not
    ``_core.linear_to_srgb``, which clips above 1."""
    from ibrtools import _core

    a = np.asarray(v, np.float32)
    return _core.srgb_encode_unclipped(a if a.flags.c_contiguous else a.copy())  # 0-d arrays stay 0-d

