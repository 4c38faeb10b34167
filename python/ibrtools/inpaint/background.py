"""The background at infinity (docs/FORMAT.md "Background"): pixels an input knows to be empty
(depth +inf: a synthetic scene's sky, a NeRF image's alpha = 0) are a direction, not a point, so
a target sees them where an input sees them in the same direction, from wherever it stands (a
rotation-only warp).

:class:`Background` completes a method's frame after the method ran: every hole pixel whose
viewing direction the input that faces it best sees as background (depth +inf at its nearest
pixel in that direction) takes the colour of the input's background pixels around that direction (bilinear,
over background pixels only: never a foreground colour) and depth +inf, and is no longer a hole,
when the target's ray in that direction is free space (the ray test: each of its samples that an
asked input sees, that input or another sees past; a surface that no input sees, hidden behind
another part, is not the background that a displaced input sees beside the object).
The inputs are asked in the order of their viewing-direction agreement with the target (at most
``MAX_VIEWS`` of them); the first whose image holds the direction with a known depth decides (a
surface there: a far surface, e.g. ground at the horizon that another input sees past, is not
sky); a direction no input sees as background stays a hole (the inpainting
fills it, inpaint/complete.py). DIBR's kernel already warps background triangles (all three
vertices at infinity, cpp/kernels/dibr/forward_warp.cpp); this pass gives the same background to the
methods that render a mesh (tm, ulr, pvm, hybrid) and to the pixels the kernel leaves at
silhouettes against the sky (triangles with a vertex at infinity and one on a surface are
dropped there).

A scene none of whose inputs has a background pixel has no :class:`Background`
(:meth:`Background.of` returns None): the pass is skipped.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ibrtools import _core
from ibrtools.camera import Camera
from ibrtools.inpaint.pushpull import dilate

# Inputs tried per frame, best viewing-direction agreement first: a background direction is seen
# by the views that face it; more views only cost time on the pixels none of them sees.
MAX_VIEWS = 8
# A direction is background only where the input has no surface pixel within this many pixels
# (Chebyshev) of it: next to a surface the direction may be that surface seen from the target (a
# silhouette or a far edge the target's warp lost half a pixel of, ground at the horizon). Chosen
# on the synthetic objects scene (1 px: 0.13 % of the demo's pixels took sky colour on ground at
# the horizon, 2 px: none); wider margins leave the sky of wide-baseline captures to the
# inpainting, which fills it worse.
CLEARANCE = 2
# The ray test (cpp/kernels/inpaint/background.h): a background direction is also free space
# along the target's ray between the inputs' depth range widened by this factor either way
# (the 0.1 % and 99.9 % quantiles of their known depth, robust to a few outliers): the target
# may stand nearer to a surface or farther from it than the inputs.
RAY_QUANTILE = 0.001
RAY_MARGIN = 2.0
RAY_STRIDE = 4


@dataclass
class Background:
    """The input views that have background pixels (depth +inf), ready for :meth:`fill`."""

    views: list  # scene.View, each with some depth +inf
    clear: list  # per view: (H, W) bool, no surface pixel within CLEARANCE - 1 pixels (Chebyshev)
    colour: np.ndarray | None = None  # the scene's background colour (linear RGB), when it has one
    near: float = 0.0  # the ray test's depth bounds (0, 0: no ray test, a scene without surfaces)
    far: float = 0.0

    @classmethod
    def of(cls, views, colour=None) -> "Background | None":
        """The views among ``views`` with a background pixel, or None when none has one (the
        pass is then skipped); ``colour`` the scene's background colour (``shading.background``)
        or None. Reads each view's depth once (they are loaded for rendering)."""
        bg = [v for v in views if v.has_depth and v.has_color and np.isposinf(v.depth).any()]
        if not bg:
            return None
        c = None if colour is None else np.asarray(colour, np.float32).reshape(3)
        near, far = _ray_bounds(bg)
        return cls(bg, [_clear(np.isfinite(v.depth) & (v.depth > 0)) for v in bg], c, near, far)

    def fill(self, camera: Camera, color: np.ndarray, hole: np.ndarray,
             depth: np.ndarray | None, *, color_is_ours: bool = False
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(colour, hole, depth, background) of a frame with its background directions filled:
        new arrays (``color_is_ours``: the caller's float32 C-contiguous ``color`` is written in
        place and returned, not copied); ``background`` (H, W) bool marks every background pixel
        of the result (the ones the method already gave depth +inf and the ones filled here).
        ``depth`` None: the result's depth is 0 except +inf on the background. A hole with depth
        +inf (a mesh method's ray that missed the mesh) no input sees takes :attr:`colour`, when
        known."""
        hole = np.asarray(hole, bool)
        depth = (np.zeros(hole.shape, np.float32) if depth is None
                 else np.array(depth, np.float32, copy=True))
        if not (color_is_ours and isinstance(color, np.ndarray) and color.dtype == np.float32
                and color.flags.c_contiguous and color.flags.writeable):
            color = np.array(color, np.float32, copy=True)
        hole = hole.copy()
        if hole.any():
            # The inputs in order, each asked about the directions no input before it decided
            # (cpp/kernels/inpaint/background.h); the background colours are written into color.
            inputs = [(self.views[i].camera.to_core(), np.ascontiguousarray(self.views[i].depth, np.float32),
                       self.clear[i], np.ascontiguousarray(self.views[i].color, np.float32))
                      for i in self._order(camera)[:MAX_VIEWS]]
            state = _core.background_lookup(camera.to_core(), inputs, hole, color,  # 0 outside the holes
                                            near=self.near, far=self.far)
            found = state == 2
            # A method that renders geometry says where its rays miss it (depth +inf in a hole):
            # there the background is seen whatever its colour; no input seeing the direction at
            # all, it takes the scene's background colour.
            if self.colour is not None:
                miss = hole & (state == 0) & (depth == np.inf)
                if miss.any():
                    np.copyto(color, self.colour, where=miss[..., None])
                    found |= miss
            hole &= ~found
            np.copyto(depth, np.float32(np.inf), where=found)
        np.copyto(depth, np.float32(0), where=hole & (depth == np.inf))  # still a hole: unknown
        background = depth == np.inf
        background &= ~hole
        return color, hole, depth, background

    def _order(self, camera: Camera) -> list[int]:
        axis = camera.world_from_cam[:3, 2]
        agree = [float(np.dot(v.camera.world_from_cam[:3, 2], axis)) for v in self.views]
        return [int(i) for i in np.argsort(-np.asarray(agree), kind="stable")]


def _ray_bounds(views) -> tuple[float, float]:
    """(near, far) of the ray test: the views' known depth range (RAY_QUANTILE, of every
    RAY_STRIDE-th pixel of every RAY_STRIDE-th row: the bounds need no more), widened by
    RAY_MARGIN; (0, 0) when no view has a surface pixel."""
    lows, highs = [], []
    for v in views:
        sample = np.ascontiguousarray(np.asarray(v.depth, np.float32)[::RAY_STRIDE, ::RAY_STRIDE])
        n, _, _, _, values = _core.valid_depth_order_stats(sample, [RAY_QUANTILE, 1.0 - RAY_QUANTILE])
        if n:
            lows.append(values[0])
            highs.append(values[3])
    if not lows or not min(lows) > 0:
        return 0.0, 0.0
    return float(min(lows)) / RAY_MARGIN, float(max(highs)) * RAY_MARGIN


def _clear(surface: np.ndarray, margin: int = CLEARANCE) -> np.ndarray:
    """True where no ``surface`` pixel is within Chebyshev distance ``margin - 1`` (the square of
    radius ``margin - 1`` around the pixel holds none; outside the image there is none)."""
    return ~dilate(surface, int(margin) - 1)
