"""Hole filling (dos Anjos et al. 2022, *Metameric Inpainting for Image Warping*): push-pull,
classic and depth-aware (``pushpull``), metameric inpainting (``metameric``), and the completion
of rendered frames that every method's output goes through (``complete``, with the background
lookup of ``background``); docs/inpaint.md, docs/render.md.

:func:`inpaint` is the method switch (``--inpaint`` of a render)."""
from __future__ import annotations

from typing import Any

import numpy as np

from ibrtools.errors import BadValueError, NotBuiltError
from ibrtools.inpaint.metameric import metameric
from ibrtools.inpaint.pushpull import check_arrays, pushpull

METHODS = {
    "none": "leave holes as they are",
    "pushpull": "push-pull pyramid fill (depth-aware when the frame has depth)",
    "metameric": "metameric inpainting: steerable-band statistics matched by noise (ibrtools.inpaint.metameric)",
}
NOT_BUILT: dict[str, str] = {}


def inpaint(image: np.ndarray, hole: np.ndarray, method: str = "pushpull",
            depth: np.ndarray | None = None, **options: Any) -> np.ndarray:
    """Fill holes with ``method`` ("none" returns ``image`` unchanged, "pushpull" is
    :func:`pushpull`, depth-aware when ``depth`` is given, "metameric" is
    :func:`ibrtools.inpaint.metameric.metameric`, which takes ``options`` levels, orientations, seed, flow)."""
    if options and method != "metameric":
        raise BadValueError(f"inpaint method {method!r}: takes no options, got {', '.join(options)}")
    if method == "none":
        check_arrays(image, hole, depth)
        return image
    if method == "pushpull":
        return pushpull(image, hole, depth)
    if method == "metameric":
        return metameric(image, hole, depth, **options)
    if method in NOT_BUILT:
        raise NotBuiltError(f"inpaint method {method!r}: {NOT_BUILT[method]} is not built yet")
    raise BadValueError(f"inpaint method: expected one of {', '.join(METHODS)}, got {method!r}")
