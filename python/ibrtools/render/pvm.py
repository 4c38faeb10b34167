"""``--method pvm``: per-view meshes with clustered depth filtering (Prakash et al. 2021, sec. 5),
rendered on their own (the ``hybrid`` method uses the same renderer only where it needs it).

Per frame:
  gbuffer  the global mesh (stage ``mesh``) ray-cast with Embree for its z (``gbuffer=mesh``,
           default; ``gbuffer=none``: every coarse voxel in the frustum is looked up instead);
  pvm      ibrtools.hybrid.pvm_render.PvmRenderer (voxel lookup, tile sort, per-view depth pass,
           cluster & blend, spatial filter; docs/pvm_render.md).

Outputs: color, depth (the PVM depth picked by the vote of Eq. 2) and hole = pixels with no
candidate (the hybrid method covers them with ULR/TM; ``ibr-render --inpaint`` can fill them).
Parameters (``--param key=value``): those of hybrid.pvm_render (sigma, alpha, gamma, tau_depth,
max_tiles, max_candidates, ulr_k, merge_rel, radius_sigmas, margin, near, cull_back, max_angle,
filtered) and ``gbuffer`` = mesh | none. Needs ``ibr-preprocess SCENE --methods pvm``.
"""
from __future__ import annotations

import time

import numpy as np

from ..camera import Camera
from ..errors import BadValueError, InputError, MissingFileError
from ..scene import Scene

GBUFFERS = ("mesh", "none")


class PvmMethod:
    """``--method pvm`` (see the module doc)."""

    name = "pvm"

    def __init__(self, params: dict | None = None):
        from ..hybrid.pvm_render import check_params

        params = dict(params or {})
        self.gbuffer = params.pop("gbuffer", "mesh")
        if self.gbuffer not in GBUFFERS:
            raise BadValueError(f"--param gbuffer: expected one of {', '.join(GBUFFERS)}, got {self.gbuffer!r}")
        self.params = check_params(params)
        self._renderer = None
        self._mesh_rt = None
        self.last_stats: dict = {}

    def prepare(self, scene: Scene) -> dict[str, float]:
        from .. import stages
        from ..hybrid.pvm_render import PvmRenderer

        t0 = time.perf_counter()
        self._renderer = PvmRenderer(scene, self.params)
        t1 = time.perf_counter()
        setup = {"pvm_load": (t1 - t0) * 1e3}
        if self.gbuffer == "mesh":
            from ..mesh import Mesh
            from .reference import ReferenceRenderer

            try:
                d = stages.load_npz(stages.stage_output(scene.root, "mesh"))
            except MissingFileError as e:
                raise InputError(f"--method pvm needs the global mesh for its G-buffer: {e}; run: ibr-preprocess "
                                 f"{scene.root} -o {scene.root} --methods pvm (or --param gbuffer=none)") from None
            mesh = Mesh(d["vertices"], d["faces"], kind="reconstructed")
            t2 = time.perf_counter()
            self._mesh_rt = ReferenceRenderer(mesh)
            setup["bvh"] = (time.perf_counter() - t2) * 1e3
        return setup

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        times: dict[str, float] = {}
        gbuf = None
        if self._mesh_rt is not None:
            t0 = time.perf_counter()
            gbuf = np.ascontiguousarray(self._mesh_rt.render(camera, outputs=("depth",))["depth"], np.float32)
            times["gbuffer"] = (time.perf_counter() - t0) * 1e3
        res = self._renderer.render(camera, gbuffer_depth=gbuf)
        times.update(res.times_ms)
        self.last_stats = dict(res.stats)
        return {"color": res.color, "depth": res.depth, "hole": ~res.valid}, times

    def frame_report(self) -> dict:
        return {"pvm": dict(self.last_stats)}
