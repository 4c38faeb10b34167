"""The registry of novel-view methods (``--method`` of ibr-render and ibr-bench).

A method is a class with ``prepare(scene) -> dict of setup times`` (work done once per scene:
BVH builds, view selection structures) and ``render(camera) -> (outputs, stage times in ms)``,
where outputs holds "color" (H, W, 3) float32 linear, optionally "depth" (H, W) and "hole"
(H, W) bool. Methods that are documented but not built yet raise NotBuiltError by name.
"""
from __future__ import annotations

import importlib.util
import time
from typing import Protocol

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, InputError, NotBuiltError
from ibrtools.scene import Scene
from ibrtools import params as P

METHODS: dict[str, str] = {
    "auto": "pick the best built method for the scene's data",
    "reference": "Embree ray casting of the scene's ground-truth mesh (shaded as the scene was made)",
    "dibr": "multi-view depth-image-based rendering, RVS class (Bonatto et al. 2021)",
    "warp": "single-view warp with background-depth holes (dos Anjos et al.)",
    "depthwarp": "iterative backward depth warping (Lee et al. 2018)",
    "tm": "textured global mesh (Prakash et al. 2021)",
    "ulr": "per-pixel unstructured lumigraph (Prakash et al. 2021)",
    "pvm": "per-view meshes with clustered depth filtering (Prakash et al. 2021)",
    "hybrid": "per-pixel choice of TM / ULR / PVM (Prakash et al. 2021)",
}
BUILT = ("reference", "dibr", "warp", "depthwarp", "tm", "ulr") + (
    ("hybrid",) if importlib.util.find_spec("ibrtools.hybrid.pvm_render") is not None else ())
BUILT += ("pvm",)  # per-view meshes (hybrid/pvm_method.py)


class Method(Protocol):
    name: str

    def prepare(self, scene: Scene) -> dict[str, float]: ...

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]: ...


class ReferenceMethod:
    """Ray-cast the ground-truth mesh with the scene's lights: the ideal answer, and the
    renderer that made the synthetic scenes (so held-out views match it to quantisation)."""

    name = "reference"

    def __init__(self, params: dict | None = None):
        # ambient: None = the scene's own shading (how its views were rendered).
        self.params = P.with_defaults("reference", params, {"ambient": None})
        if self.params["ambient"] is not None:
            self.params["ambient"] = P.number(self.params["ambient"], "--param ambient", 0.0, maximum=P.FINITE_MAX)
        self._renderer = None

    def prepare(self, scene: Scene) -> dict[str, float]:
        from ibrtools.raycast.reference import Light, ReferenceRenderer, default_lights

        mesh = scene.meshes.get("ground_truth")
        if mesh is None:
            raise InputError("--method reference: the scene has no ground-truth mesh "
                             "(reference rendering needs one; synthetic scenes carry it)")
        t0 = time.perf_counter()
        self._renderer = ReferenceRenderer(mesh)
        setup_ms = (time.perf_counter() - t0) * 1e3
        if scene.lights:
            self._lights = [Light(kind=d["kind"], vector=tuple(d["vector"]), color=tuple(d["color"]),
                                  shadows=bool(d.get("shadows", True))) for d in scene.lights]
        else:
            self._lights = default_lights(mesh.bounds())
        ambient = self.params["ambient"]
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


def resolve(name: str, scene: Scene) -> str:
    """The concrete method for ``--method name`` on ``scene``."""
    if name not in METHODS:
        raise BadValueError(f"--method: unknown method {name!r} (expected one of {', '.join(METHODS)})")
    if name == "auto":
        # Captured colour + depth views are what DIBR is for; a ground-truth mesh alone (views
        # without depth) still renders exactly with the reference ray caster.
        from ibrtools.cache import with_stage_depth

        if scene.views and all(v.has_depth for v in with_stage_depth(scene).views):
            return "dibr"
        if "ground_truth" in scene.meshes:
            return "reference"
        raise NotBuiltError("--method auto: some input views have no depth (dibr needs depth) and the "
                            "scene has no ground-truth mesh; the methods for colour-only views "
                            "(tm, ulr, pvm, hybrid) need ibr-preprocess SCENE --methods ...; "
                            "ask for one with --method")
    if name not in BUILT:
        raise NotBuiltError(f"--method {name}: not built yet ({METHODS[name]}); built: {', '.join(BUILT)}")
    return name


def create(name: str, params: dict | None = None) -> Method:
    if name == "reference":
        return ReferenceMethod(params)
    if name == "dibr":
        from ibrtools.dibr.method import DibrMethod

        return DibrMethod(params)
    if name == "warp":
        from ibrtools.dibr.warp import WarpMethod

        return WarpMethod(params)
    if name == "depthwarp":
        from ibrtools.depthwarp.method import DepthWarpMethod

        return DepthWarpMethod(params)
    if name in ("tm", "ulr", "hybrid") and name in BUILT:
        from ibrtools.hybrid.method import HybridMethod, TmMethod, UlrMethod

        return {"tm": TmMethod, "ulr": UlrMethod, "hybrid": HybridMethod}[name](params)
    if name == "pvm":
        from ibrtools.hybrid.pvm_method import PvmMethod

        return PvmMethod(params)
    raise NotBuiltError(f"--method {name}: not built yet")
