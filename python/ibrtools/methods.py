"""The registry of novel-view methods (``--method`` of ibr-render and ibr-bench).

A method is a class with ``prepare(scene) -> dict of setup times`` (work done once per scene:
BVH builds, view selection structures) and ``render(camera) -> (outputs, stage times in ms)``,
where outputs holds "color" (H, W, 3) float32 linear, optionally "depth" (H, W) and "hole"
(H, W) bool. Methods that are documented but not built yet raise NotBuiltError by name.
"""
from __future__ import annotations

import importlib.util
from typing import Protocol

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, NotBuiltError
from ibrtools.scene import Scene
from ibrtools.cache import with_stage_depth
from ibrtools.depthwarp.method import DepthWarpMethod
from ibrtools.dibr.method import DibrMethod
from ibrtools.dibr.warp import WarpMethod
from ibrtools.hybrid.method import HybridMethod, TmMethod, UlrMethod
from ibrtools.hybrid.pvm_method import PvmMethod
from ibrtools.raycast.method import ReferenceMethod

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


def resolve(name: str, scene: Scene) -> str:
    """The concrete method for ``--method name`` on ``scene``."""
    if name not in METHODS:
        raise BadValueError(f"--method: unknown method {name!r} (expected one of {', '.join(METHODS)})")
    if name == "auto":
        # Captured colour + depth views are what DIBR is for; a ground-truth mesh alone (views
        # without depth) still renders exactly with the reference ray caster.
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
        return DibrMethod(params)
    if name == "warp":
        return WarpMethod(params)
    if name == "depthwarp":
        return DepthWarpMethod(params)
    if name in ("tm", "ulr", "hybrid") and name in BUILT:
        return {"tm": TmMethod, "ulr": UlrMethod, "hybrid": HybridMethod}[name](params)
    if name == "pvm":
        return PvmMethod(params)
    raise NotBuiltError(f"--method {name}: not built yet")
