"""Single-view warp with background-depth holes (dos Anjos et al., *Metameric Inpainting for Image
Warping*, sec. 3.1): ``--method warp``.

Per frame:
  select  the one input view most similar to the target (view_selection.py, k = 1: the DIBR
          similarity of Eq. 4-6), or the view named by ``--inputs NAME``;
  warp    that view's RGB-D is forward-warped into the target by ``_core.warp_with_holes``
          (cpp/kernels/dibr/forward_warp.h, "Warp with background-depth holes": DIBR's rasteriser,
          stretched quads drawn flat at their farthest corner's depth and re-partitioned by Eq. 1
          so that they only fill disocclusions).

Outputs: "color" (0 in holes), "depth" (surface depth; the background depth inside disocclusions;
0 where nothing lands, e.g. outside the input's field of view), "hole" (bool: disoccluded or not
covered) and "disoccluded" (bool: holes with a background depth). ``ibr-render --inpaint pushpull``
fills the holes depth-aware with that depth (pipeline/job.py), so the fill takes the background.

Parameters (``--inputs`` or ``--param key=value``)
  inputs             one view name, or 1 (= the most similar view; the default)
  stretch_threshold  longest target edge (pixels) of a quad that is not stretched, (0, 1e6] (default 2)
  depth_jump         relative depth spread a stretched quad must also have, [0, 1e6] (default 0.1; 0 = off)
  samples, seed      Monte Carlo samples per target for view selection (1..100000, default 4000; dibr's
                     bound) and the seed
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import InputError, ParamError
from ibrtools.scene import Scene
from ibrtools import params as P
from ibrtools.dibr import view_selection as vs
from ibrtools.dibr.method import MAX_SAMPLES
from ibrtools.cache import missing_depth_error, with_stage_depth

def _one_input(v, name: str) -> int | str:
    """1 (the most similar input) or one view name."""
    if isinstance(v, str) and v.strip() == "1":
        v = 1
    if isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v == 1:
        return 1
    if isinstance(v, str) and v.strip() and "," not in v:
        return v.strip()
    raise ParamError(name, f"method 'warp' uses one input view: expected 1 (the most similar) "
                           f"or one view name, got {v!r}")


@dataclass(frozen=True)
class WarpParams(P.MethodParams):
    """Parameters of ``--method warp`` (the module doc)."""

    method: ClassVar[str] = "warp"
    inputs: int | str = P.custom(1, _one_input)
    stretch_threshold: float = P.number(2.0, 0.0, strict=True, maximum=P.FINITE_MAX)
    depth_jump: float = P.number(0.1, 0.0, maximum=P.FINITE_MAX)
    samples: int = P.integer(vs.DEFAULT_SAMPLES, 1, MAX_SAMPLES)
    seed: int = P.integer(vs.DEFAULT_SEED, 0)


class WarpMethod:
    """``--method warp`` (see the module doc)."""

    name = "warp"

    def __init__(self, params: dict | WarpParams | None = None):
        self.params = WarpParams.from_dict(params)
        self.last_frame: dict = {}
        self._scene: Scene | None = None

    def prepare(self, scene: Scene) -> dict[str, float]:
        if not scene.views:
            raise InputError.about("method", "the scene has no input views", "warp")
        scene = with_stage_depth(scene)  # photographs: the mvs stage's depth (else the mesh's)
        names = [v.name for v in scene.views]
        inputs = self.params.inputs
        if isinstance(inputs, str):
            if inputs not in names:
                raise ParamError("inputs", f"view {inputs!r} is not among the input views "
                                           f"(held-out views are not inputs)")
            self._candidates = [names.index(inputs)]
        else:
            self._candidates = None
        cand = self._candidates if self._candidates is not None else range(len(names))
        no_depth = [names[i] for i in cand if not scene.views[i].has_depth]
        if no_depth:
            raise missing_depth_error("warp", scene, no_depth)
        bad = [names[i] for i in cand if not scene.views[i].has_color]
        if bad:
            raise InputError.about("method", f"needs colour and depth for its input view(s); missing for: "
                                   f"{', '.join(bad[:5])}{' ...' if len(bad) > 5 else ''}", "warp")
        t0 = time.perf_counter()
        self._views = vs.ViewSet.of(scene.views)
        ms = (time.perf_counter() - t0) * 1e3
        self._scene = scene
        return {"depth_ranges": ms}

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        from ibrtools import _core

        if self._scene is None:
            raise InputError("warp: prepare(scene) must be called before render(camera)")
        t0 = time.perf_counter()
        if self._candidates is not None:
            index = self._candidates[0]
        else:
            sel = self._views.select(camera, 1, samples=self.params.samples, seed=self.params.seed)
            if not sel.indices:
                raise InputError.about("method", "no input view overlaps the target camera", "warp")
            index = sel.indices[0]
        t1 = time.perf_counter()
        v = self._scene.views[index]
        color, depth, mask = _core.warp_with_holes(
            np.ascontiguousarray(v.color, np.float32), np.ascontiguousarray(v.depth, np.float32),
            v.camera.to_core(), camera.to_core(), float(self.params.stretch_threshold),
            float(self.params.depth_jump))
        t2 = time.perf_counter()
        disoccluded = mask == _core.WARP_DISOCCLUDED
        hole = mask != _core.WARP_SURFACE
        self.last_frame = {"selected": [v.name], "disoccluded_pixels": int(disoccluded.sum()),
                           "uncovered_pixels": int((mask == _core.WARP_UNCOVERED).sum())}
        out = {"color": color, "depth": depth, "hole": hole, "disoccluded": disoccluded}
        return out, {"select": (t1 - t0) * 1e3, "warp": (t2 - t1) * 1e3}

    def frame_report(self) -> dict:
        """What report.json records for the last frame (the input view, hole pixel counts)."""
        return dict(self.last_frame)
