"""A method's frame made complete, as ``ibr-render`` writes it and :func:`ibrtools.render` returns
it (docs/render.md "Complete images"):

1. **background**: hole pixels whose direction an input sees as background at infinity take its
   colour (inpaint/background.py); they are not holes;
2. **holes filled** (``inpaint``): each hole pixel is a background hole when at least half of
   its nearest covered pixels left, right, above and below are background at infinity (a surface
   pixel :data:`OCCLUDER_RATIO` times nearer than the farthest of them, the occluder, gives its
   vote to the side opposite it; it takes
   the scene's background colour, or a push-pull of the background pixels), else a surface hole,
   a disocclusion, filled from the surface pixels only: ``auto`` (the default) and ``pushpull``
   = depth-aware push-pull (inpaint.py) with each hole's depth the background depth around it
   (the largest depth of those nearest surface pixels), so a wedge of ground behind an object is
   filled with ground, not with the object nor the sky; ``metameric`` = the same set-up through
   metameric inpainting; ``none`` leaves holes black. A frame whose only covered pixels are
   background is filled as background; a frame with no covered pixel at all is left black and
   says so (``NOTHING_TO_FILL``);
3. **background colour**: a scene with a uniform background (``shading.background``: the colour an
   RGBA capture was composited over, a synthetic scene's sky) paints every background pixel in it
   (an input's background pixels beside its silhouette carry the object's antialiased edge,
   which the rotation-only warp would draw as a thin ghost outline far from the object), or in
   ``override`` (``--background``) when given.

``auto`` is depth-aware push-pull because it measured best of the built fills on the held-out
views we score (docs/benchmarks.md "Complete images").
"""
from __future__ import annotations

import time
import weakref
from dataclasses import dataclass, field

import numpy as np

from ibrtools import _core
from ibrtools.cache import with_stage_depth
from ibrtools.errors import BadValueError
from ibrtools.inpaint.background import Background
from ibrtools.imageio import srgb_to_linear
from ibrtools.inpaint import inpaint as fill_holes
from ibrtools.inpaint.pushpull import pushpull

INPAINT = {
    "auto": "the measured best fill: depth-aware push-pull from the background side (default)",
    "none": "leave holes black",
    "pushpull": "depth-aware push-pull from the background side",
    "metameric": "metameric inpainting from the background side (ibrtools.inpaint.metameric)",
}
DEFAULT_INPAINT = "auto"
# The notes of a frame whose holes were filled.
INPAINT_FILLS = ("auto", "pushpull", "metameric", "from the background")
# A surface pixel beside a hole that is nearer than its farthest surface side by this factor is
# the occluder whose disocclusion the hole is: its vote on whether the hole is background goes to
# the side opposite it (the sky behind a pole's top, between the sky and the ground at the
# horizon, is sky; a wall's disocclusion beside a box under the sky is wall).
OCCLUDER_RATIO = 1.5
NOTHING_TO_FILL = "nothing to fill from: no input covers any pixel of the frame"


def parse_background(value) -> "np.ndarray | str | None":
    """``--background``: None (the scene's background colour when it has one, else the background
    as the inputs show it), "transparent" (alpha 0 on
    the background: an RGBA image), or a colour: black, white or R,G,B (sRGB in [0, 1]) ->
    linear RGB float32 (3,)."""
    if value is None:
        return None
    if isinstance(value, str):
        v = value.strip().lower()
        if v == "transparent":
            return "transparent"
        named = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0)}
        if v in named:
            rgb = named[v]
        else:
            try:
                rgb = tuple(float(x) for x in v.split(","))
            except ValueError:
                rgb = ()
    else:
        try:
            rgb = tuple(float(x) for x in value)
        except (TypeError, ValueError):
            rgb = ()
    if len(rgb) != 3 or not all(0.0 <= x <= 1.0 for x in rgb):
        raise BadValueError.about("background", f"expected black, white, transparent or R,G,B in [0, 1], "
                                                f"got {value!r}")

    return np.asarray(srgb_to_linear(np.asarray(rgb, np.float32)), np.float32).reshape(3)


def check_inpaint(mode) -> str:
    if not isinstance(mode, str) or mode not in INPAINT:
        raise BadValueError.about("inpaint", f"expected one of {', '.join(INPAINT)}, got {mode!r}")
    return mode


@dataclass
class Completed:
    """A frame as written: ``color`` (no NaN, holes black or filled), ``hole`` (the pixels that
    neither the method nor the background covered: filled unless inpaint is "none"), ``depth``
    (+inf on the background at infinity; None when the method gives none and the scene has no
    background), ``background`` (bool, the background-at-infinity pixels, the filled background
    holes included), ``note`` (what the
    inpainting did: the mode, "skipped: no hole", or why nothing could be filled), stage times."""

    color: np.ndarray
    hole: np.ndarray | None
    depth: np.ndarray | None
    background: np.ndarray | None
    note: str | None
    stage_ms: dict = field(default_factory=dict)
    alpha: np.ndarray | None = None  # (H, W) float32, 0 on the background: --background transparent

    @property
    def filled(self) -> bool:
        return self.note in INPAINT_FILLS


_BACKGROUNDS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
def completion(method, scene, inpaint: str) -> tuple[Background | None, str]:
    """(background, inpaint) to :func:`complete` a frame of the prepared ``method`` on ``scene``
    with. A method whose image is its depth visualised, not a view of the scene's colours
    (``method.image_is_depth``, depthwarp), is written as rendered, holes black."""
    if getattr(method, "image_is_depth", False):
        return None, "none"
    return background_of(scene), check_inpaint(inpaint)


def background_of(scene) -> Background | None:
    """The scene's :class:`Background` (None when no input has a background pixel), made once per
    scene object; views without depth of their own take the depth a stage made (the mvs stage's
    background outside an RGBA capture's masks), as the methods warp them."""
    try:
        return _BACKGROUNDS[scene]
    except KeyError:
        bg = Background.of(with_stage_depth(scene).views, (scene.shading or {}).get("background"))
        _BACKGROUNDS[scene] = bg
        return bg


def clean_color(out: dict) -> np.ndarray:
    """A method's colour as written: float32, C-contiguous, NaN/inf as 0, holes
    (``out["hole"]``) black."""
    hole = out.get("hole")
    return _core.clean_color(np.ascontiguousarray(out["color"], np.float32),
                             None if hole is None else np.ascontiguousarray(hole, bool))  # inpaint/clean.h


def complete(out: dict, camera, background: Background | None, inpaint: str,
             override: "np.ndarray | str | None" = None) -> Completed:
    """The complete frame of a method's outputs ``out`` ("color", optional "hole", "depth");
    ``override`` (:func:`parse_background`) recolours the background or makes it transparent."""
    check_inpaint(inpaint)
    stage_ms: dict = {}
    hole = out.get("hole")
    depth = out.get("depth")
    color = clean_color(out)
    bg = None
    if hole is not None:
        hole = np.asarray(hole, bool)
        if background is not None and hole.any():
            t0 = time.perf_counter()
            color, hole, depth, bg = background.fill(camera, color, hole, depth, color_is_ours=True)  # clean_color's
            stage_ms["background"] = (time.perf_counter() - t0) * 1e3
        elif depth is not None:
            depth = np.where(hole & np.isposinf(depth), np.float32(0), depth)  # a miss no input explains: unknown
            bg = np.isposinf(depth) & ~hole
    note = None
    if inpaint != "none":
        if hole is None or not hole.any():
            note = "skipped: no hole"  # inpainting does nothing where there is no hole
        else:
            t0 = time.perf_counter()
            color, note, sky = _fill(color, hole, depth, bg, inpaint,
                                     None if background is None else background.colour)
            stage_ms["inpaint"] = (time.perf_counter() - t0) * 1e3
            if sky is not None and sky.any():
                bg = sky if bg is None else bg | sky
    alpha = None
    if override is None and background is not None and background.colour is not None:
        override = background.colour  # the uniform background's own colour (step 3 of the module doc)
    if override is not None and bg is not None:
        if isinstance(override, str):  # transparent
            alpha = (~bg).astype(np.float32)
            color = np.where(bg[..., None], np.float32(0), color)
        else:
            color = np.where(bg[..., None], override.astype(np.float32), color)
    elif isinstance(override, str):
        alpha = np.ones(color.shape[:2], np.float32)
    return Completed(np.ascontiguousarray(color, np.float32), hole,
                     None if depth is None else np.ascontiguousarray(depth, np.float32), bg, note, stage_ms,
                     alpha)


def _fill(color: np.ndarray, hole: np.ndarray, depth: np.ndarray | None, bg: np.ndarray | None,
          mode: str, bg_colour: np.ndarray | None = None) -> tuple[np.ndarray, str, np.ndarray | None]:
    """Fill the holes of ``color`` (complete's own array: filled in place, and returned): each
    hole pixel is a surface hole or a background hole by the nearest
    covered pixels left, right, above and below it (a background hole when more than half of
    those found are background at infinity: the sky behind a thin pole no input saw past); surface
    holes are filled with ``mode`` from the surface pixels only, with the background depth around
    each hole (the largest depth of those nearest surface pixels) as its depth, background holes
    by the scene's background colour ``bg_colour`` when it has one (a uniform background: the
    background pixels beside an object carry its antialiased edge, which a push-pull would smear
    over the hole), else by push-pull from the background pixels only."""
    bg = np.zeros(hole.shape, bool) if bg is None else bg
    d = None if depth is None else np.asarray(depth, np.float32)
    blocked = hole | bg  # what a fill never reads from
    surface = ~blocked
    known_depth = np.zeros(hole.shape, np.float32)
    if d is not None:
        known = d > 0
        known &= d < np.inf  # finite and > 0 (NaN fails both)
        known &= surface
        known_depth = np.where(known, d, np.float32(0))
    # The nearest covered pixels left, right, above and below each hole pixel
    # (cpp/kernels/inpaint/hole_sides.h): what each is, and the largest depth of the surface ones
    # (known_depth is 0 on the background; without background no occluder is looked for: the
    # sides then only give `around`).
    has_bg = bool(bg.any())
    sides, around = _core.hole_sides(hole, bg, known_depth, OCCLUDER_RATIO if has_bg else 0.0)
    sky = _background_holes(hole, sides) if has_bg else np.zeros(hole.shape, bool)
    ground = hole & ~sky
    if ground.any() and not surface.any():
        sky, ground = hole, np.zeros(hole.shape, bool)  # nothing but background to fill from
    if sky.any() and not has_bg and bg_colour is None:
        return color, NOTHING_TO_FILL, None
    out = color
    if ground.any():
        method = "pushpull" if mode == "auto" else mode
        aware = None
        if d is not None and known_depth.any():
            # A hole pixel's background depth is `around` (0 outside the holes, where known_depth
            # is 0 inside them), or the largest known depth where no side found one.
            aware = np.maximum(known_depth, around)
            np.copyto(aware, known_depth.max(), where=hole & (around <= 0))
            np.copyto(aware, np.float32(0), where=sky)  # not read: the background holes are blocked as the background is
        if method == "pushpull":  # the surface holes filled in place (color is ours: complete's)
            out = pushpull(color, blocked, depth=aware, write=ground, out=color)
        else:
            filled = fill_holes(color, blocked, method, depth=aware)  # never from the background at infinity
            out = np.where(ground[..., None], filled, out)
    if sky.any():
        filled = bg_colour.astype(np.float32) if bg_colour is not None else \
            fill_holes(color, ~bg, "pushpull")[sky]  # from the background at infinity only
        if out.flags.c_contiguous:  # by flat pixel index: 4x faster than a 2-D boolean index at 1080p
            out.reshape(-1, out.shape[-1])[np.flatnonzero(sky)] = filled
        else:
            out[sky] = filled
    return out, (mode if ground.any() else "from the background"), sky


def _background_holes(hole: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """The background holes among ``hole`` by their ``sides`` (cpp/kernels/inpaint/hole_sides.h):
    every side found votes, background or surface, except an occluder, whose vote goes to the side
    opposite it (what the disocclusion reveals: the sky left of a pole, the wall right of a box);
    a background hole has at least half its votes background."""
    at = np.flatnonzero(hole)
    code = sides.reshape(-1)[at]
    side = [(code >> (2 * k)) & 3 for k in range(4)]  # left, right, up, down
    votes = np.zeros(len(at), np.int8)
    bg_votes = np.zeros(len(at), np.int8)
    for k, opposite in ((0, 1), (1, 0), (2, 3), (3, 2)):
        seen = (side[k] == _core.SIDE_BACKGROUND) | (side[k] == _core.SIDE_SURFACE)
        weight = seen.astype(np.int8) + (seen & (side[opposite] == _core.SIDE_OCCLUDER))
        votes += weight
        bg_votes += np.where(side[k] == _core.SIDE_BACKGROUND, weight, np.int8(0))
    out = np.zeros(hole.shape, bool)
    out.reshape(-1)[at[(2 * bg_votes >= votes) & (votes > 0)]] = True
    return out
