"""The ``reference`` method: the scene's ground-truth mesh ray cast with its lights (docs/reference.md)."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ibrtools import params as P
from ibrtools.camera import Camera
from ibrtools.errors import InputError
from ibrtools.scene import Scene


@dataclass(frozen=True)
class ReferenceParams(P.MethodParams):
    """Parameters of ``--method reference``. ambient: None = the scene's own shading (how its
    views were rendered)."""

    method: ClassVar[str] = "reference"
    ambient: float | None = P.number(None, 0.0, maximum=P.FINITE_MAX, optional=True)


class ReferenceMethod:
    """Ray-cast the ground-truth mesh with the scene's lights: the ideal answer, and the
    renderer that made the synthetic scenes (so held-out views match it to quantisation)."""

    name = "reference"

    def __init__(self, params: dict | ReferenceParams | None = None):
        self.params = ReferenceParams.from_dict(params)
        self._renderer = None

    def prepare(self, scene: Scene) -> dict[str, float]:
        from ibrtools.raycast.reference import Light, ReferenceRenderer, default_lights

        mesh = scene.meshes.get("ground_truth")
        if mesh is None:
            raise InputError.about("method", "the scene has no ground-truth mesh (reference rendering needs "
                                   "one; synthetic scenes carry it)", "reference")
        t0 = time.perf_counter()
        self._renderer = ReferenceRenderer(mesh)
        setup_ms = (time.perf_counter() - t0) * 1e3
        if scene.lights:
            self._lights = [Light(kind=d["kind"], vector=tuple(d["vector"]), color=tuple(d["color"]),
                                  shadows=bool(d.get("shadows", True))) for d in scene.lights]
        else:
            self._lights = default_lights(mesh.bounds())
        ambient = self.params.ambient
        self._ambient = float(scene.shading.get("ambient", 0.15) if ambient is None else ambient)
        self._background = tuple(scene.shading.get("background", (0.0, 0.0, 0.0)))
        return {"bvh": setup_ms}

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        t0 = time.perf_counter()
        out = self._renderer.render(camera, outputs=("color", "depth", "hit"), lights=self._lights,
                                    ambient=self._ambient, background=self._background)
        ms = (time.perf_counter() - t0) * 1e3
        # A ray that hits nothing sees the scene's background at infinity (as synth.py renders
        # it), in the background colour: not a hole.
        depth = np.where(out["hit"], out["depth"], np.float32(np.inf)).astype(np.float32)
        return {"color": out["color"], "depth": depth, "hole": np.zeros(depth.shape, bool)}, {"raycast_shade": ms}
