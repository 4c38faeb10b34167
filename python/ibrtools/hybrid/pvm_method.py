"""``--method pvm``: per-view meshes with clustered depth filtering (Prakash et al. 2021, sec. 5),
rendered on their own (the ``hybrid`` method uses the same renderer only where it needs it).

Per frame:
  gbuffer  the z of the global mesh's G-buffer (stage ``mesh``, its render mesh), as the hybrid
           method makes it (hybrid/method.py ``_GlobalMesh.gbuffer``: rasterised, or ray cast by
           Embree for a mesh dense for the frame) (``gbuffer=mesh``, default; ``gbuffer=none``:
           every coarse voxel in the frustum is looked up instead);
  pvm      ibrtools.hybrid.pvm_render.PvmRenderer (voxel lookup, tile sort, per-view depth pass,
           cluster & blend, spatial filter; docs/pvm_render.md).

Outputs: color, depth (the PVM depth picked by the vote of Eq. 2) and hole = pixels with no
candidate (the hybrid method covers them with ULR/TM; ``ibr-render --inpaint`` can fill them).
Parameters (``--param key=value``): those of hybrid.pvm_render (sigma, alpha, gamma, tau_depth,
max_tiles, max_candidates, ulr_k, merge_rel, radius_sigmas, margin, near, cull_back, max_angle,
stretch_weight, stretch_free, filtered, ...) and ``gbuffer`` = mesh | none. Needs ``ibr-preprocess SCENE --methods pvm``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import MissingFileError
from ibrtools.scene import Scene
from ibrtools import params as P
from ibrtools.hybrid.pvm_render import PvmParams, PvmRenderer

GBUFFERS = ("mesh", "none")


@dataclass(frozen=True)
class PvmMethodParams(PvmParams):
    """Parameters of ``--method pvm``: the renderer's and ``gbuffer`` (the module doc)."""

    gbuffer: str = P.choice("mesh", GBUFFERS)


class PvmMethod:
    """``--method pvm`` (see the module doc)."""

    name = "pvm"

    def __init__(self, params: dict | PvmMethodParams | None = None):
        self.params = PvmMethodParams.from_dict(params)
        self.gbuffer = self.params.gbuffer
        self._renderer = None
        self._gm = None
        self.last_stats: dict = {}

    def prepare(self, scene: Scene) -> dict[str, float]:
        t0 = time.perf_counter()
        self._renderer = PvmRenderer(scene, self.params)
        t1 = time.perf_counter()
        setup = {"pvm_load": (t1 - t0) * 1e3}
        if self.gbuffer == "mesh":
            from ibrtools.hybrid.method import _GlobalMesh

            try:
                self._gm = _GlobalMesh(scene, "pvm", texture=False)
            except MissingFileError as e:
                raise MissingFileError(f"{e} (or the parameter gbuffer=none)") from None
            setup["bvh"] = self._gm.build_ms
        return setup

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        times: dict[str, float] = {}
        gbuf = None
        if self._gm is not None:
            t0 = time.perf_counter()
            gbuf = np.ascontiguousarray(self._gm.gbuffer(camera, normal=False)["depth"], np.float32)
            times["gbuffer"] = (time.perf_counter() - t0) * 1e3
        res = self._renderer.render(camera, gbuffer_depth=gbuf)
        times.update(res.times_ms)
        self.last_stats = dict(res.stats)
        return {"color": res.color, "depth": res.depth, "hole": ~res.valid}, times

    def frame_report(self) -> dict:
        return {"pvm": dict(self.last_stats)}
