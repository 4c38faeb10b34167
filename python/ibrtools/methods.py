"""The registry of novel-view methods (``--method`` of ibr-render and ibr-bench).

A method is a class with ``prepare(scene) -> dict of setup times`` (work done once per scene:
BVH builds, view selection structures) and ``render(camera) -> (outputs, stage times in ms)``,
where outputs holds "color" (H, W, 3) float32 linear, optionally "depth" (H, W) and "hole"
(H, W) bool. Methods that are documented but not built yet raise NotBuiltError by name.
"""
from __future__ import annotations

import importlib.util
from typing import Any, Mapping, Protocol

import numpy as np

from ibrtools.camera import Camera
from ibrtools.errors import BadValueError, NotBuiltError
from ibrtools.scene import Scene
from ibrtools.cache import with_stage_depth
from ibrtools.params import MethodParams
from ibrtools.depthwarp.method import DepthWarpMethod, DepthWarpMethodParams
from ibrtools.dibr.method import DibrMethod, DibrParams
from ibrtools.dibr.warp import WarpMethod, WarpParams
from ibrtools.hybrid.method import HybridMethod, HybridParams, TmMethod, TmParams, UlrMethod, UlrParams
from ibrtools.hybrid.pvm_method import PvmMethod, PvmMethodParams
from ibrtools.raycast.method import ReferenceMethod, ReferenceParams

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


# Each built method's typed parameters (ibrtools.params): defaults, bounds and checks, defined once.
PARAMS: dict[str, type[MethodParams]] = {
    "reference": ReferenceParams, "dibr": DibrParams, "warp": WarpParams, "depthwarp": DepthWarpMethodParams,
    "tm": TmParams, "ulr": UlrParams, "hybrid": HybridParams, "pvm": PvmMethodParams}


def check_params(name: str, params: Mapping[str, Any] | MethodParams | None = None) -> MethodParams:
    """``params`` of method ``name`` checked, with the defaults filled in (ParamError naming the
    parameter; NotBuiltError for a method that is not built)."""
    if name not in METHODS or name == "auto":
        raise BadValueError.about("method", f"expected one of {', '.join(PARAMS)}, got {name!r}")
    if name not in BUILT:
        raise NotBuiltError.about("method", f"not built yet ({METHODS[name]}); built: {', '.join(BUILT)}", name)
    return PARAMS[name].from_dict(params)


class Method(Protocol):
    name: str

    def prepare(self, scene: Scene) -> dict[str, float]: ...

    def render(self, camera: Camera) -> tuple[dict[str, np.ndarray], dict[str, float]]: ...


def resolve(name: str, scene: Scene) -> str:
    """The concrete method for ``--method name`` on ``scene``."""
    if name not in METHODS:
        raise BadValueError.about("method", f"unknown method {name!r} (expected one of {', '.join(METHODS)})")
    if name == "auto":
        # Captured colour + depth views are what DIBR is for; a ground-truth mesh alone (views
        # without depth) still renders exactly with the reference ray caster.
        if scene.views and all(v.has_depth for v in with_stage_depth(scene).views):
            return "dibr"
        if "ground_truth" in scene.meshes:
            return "reference"
        raise NotBuiltError.about("method", "some input views have no depth (dibr needs depth) and the "
                                  "scene has no ground-truth mesh; the methods for colour-only views "
                                  "(tm, ulr, pvm, hybrid) need ibr-preprocess SCENE --methods ...; "
                                  "name one of them", "auto")
    if name not in BUILT:
        raise NotBuiltError.about("method", f"not built yet ({METHODS[name]}); built: {', '.join(BUILT)}", name)
    return name


def create(name: str, params: Mapping[str, Any] | MethodParams | None = None) -> Method:
    """Method ``name`` with ``params`` (checked: ParamError before any work)."""
    classes = {"reference": ReferenceMethod, "dibr": DibrMethod, "warp": WarpMethod, "depthwarp": DepthWarpMethod,
               "tm": TmMethod, "ulr": UlrMethod, "hybrid": HybridMethod, "pvm": PvmMethod}
    if name not in classes or name not in BUILT:
        raise NotBuiltError.about("method", "not built yet", name)
    return classes[name](check_params(name, params))
