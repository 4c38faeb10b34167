"""The background at infinity (docs/FORMAT.md "Background"): pixels an input knows to be empty
(depth +inf: a synthetic scene's sky, a NeRF image's alpha = 0) are a direction, not a point, so
a target sees them where an input sees them in the same direction, from wherever it stands (a
rotation-only warp).

:class:`Background` completes a method's frame after the method ran: every hole pixel whose
viewing direction the input that faces it best sees as background (depth +inf at its nearest
pixel in that direction) takes the colour of the input's background pixels around that direction (bilinear,
over background pixels only: never a foreground colour) and depth +inf, and is no longer a hole.
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

from ibrtools.camera import PINHOLE, Camera

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


@dataclass
class Background:
    """The input views that have background pixels (depth +inf), ready for :meth:`fill`."""

    views: list  # scene.View, each with some depth +inf
    clear: list  # per view: (H, W) bool, no surface pixel within CLEARANCE - 1 pixels (Chebyshev)
    colour: np.ndarray | None = None  # the scene's background colour (linear RGB), when it has one

    @classmethod
    def of(cls, views, colour=None) -> "Background | None":
        """The views among ``views`` with a background pixel, or None when none has one (the
        pass is then skipped); ``colour`` the scene's background colour (``shading.background``)
        or None. Reads each view's depth once (they are loaded for rendering)."""
        bg = [v for v in views if v.has_depth and v.has_color and np.isposinf(v.depth).any()]
        if not bg:
            return None
        c = None if colour is None else np.asarray(colour, np.float32).reshape(3)
        return cls(bg, [_clear(np.isfinite(v.depth) & (v.depth > 0)) for v in bg], c)

    def fill(self, camera: Camera, color: np.ndarray, hole: np.ndarray,
             depth: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(colour, hole, depth, background) of a frame with its background directions filled:
        new arrays; ``background`` (H, W) bool marks every background pixel of the result (the
        ones the method already gave depth +inf and the ones filled here). ``depth`` None: the
        result's depth is 0 except +inf on the background. A hole with depth +inf (a mesh
        method's ray that missed the mesh) no input sees takes :attr:`colour`, when known."""
        hole = np.asarray(hole, bool)
        depth = (np.zeros(hole.shape, np.float32) if depth is None
                 else np.array(depth, np.float32, copy=True))
        color = np.array(color, np.float32, copy=True)
        hole = hole.copy()
        ys, xs = np.nonzero(hole)
        if len(ys):
            dirs = camera.rays_in_cam(xs + 0.5, ys + 0.5) @ camera.cam_from_world[:3, :3]  # world
            found = np.zeros(len(ys), bool)
            decided = np.zeros(len(ys), bool)
            for i in self._order(camera)[:MAX_VIEWS]:
                todo = np.nonzero(~decided)[0]
                if not len(todo):
                    break
                v = self.views[i]
                seen, sky, rgb = _look_up(v, self.clear[i], dirs[todo])
                idx = todo[sky]
                color[ys[idx], xs[idx]] = rgb
                found[idx] = True
                decided[todo[seen]] = True
            # A method that renders geometry says where its rays miss it (depth +inf in a hole):
            # there the background is seen whatever its colour; no input seeing the direction at
            # all, it takes the scene's background colour.
            miss = np.isposinf(depth[ys, xs]) & ~found & ~decided
            if self.colour is not None and miss.any():
                color[ys[miss], xs[miss]] = self.colour
                found |= miss
            hole[ys[found], xs[found]] = False
            depth[ys[found], xs[found]] = np.inf
        depth[hole & np.isposinf(depth)] = 0  # still a hole: unknown
        background = np.isposinf(depth) & ~hole
        return color, hole, depth, background

    def _order(self, camera: Camera) -> list[int]:
        axis = camera.world_from_cam[:3, 2]
        agree = [float(np.dot(v.camera.world_from_cam[:3, 2], axis)) for v in self.views]
        return [int(i) for i in np.argsort(-np.asarray(agree), kind="stable")]


def _clear(surface: np.ndarray, margin: int = CLEARANCE) -> np.ndarray:
    """True where no ``surface`` pixel is within Chebyshev distance ``margin - 1`` (the square of
    radius ``margin - 1`` around the pixel holds none; outside the image there is none): the
    surface dilated by a separable running OR, rows then columns, and negated."""
    r = int(margin) - 1
    if r <= 0:
        return ~surface
    rows = surface.copy()
    for d in range(1, r + 1):
        rows[:, d:] |= surface[:, :-d]
        rows[:, :-d] |= surface[:, d:]
    near = rows.copy()
    for d in range(1, r + 1):
        near[d:] |= rows[:-d]
        near[:-d] |= rows[d:]
    return ~near


def _look_up(view, clear: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For world directions (n, 3): which ones ``view`` sees with a known depth at its nearest
    pixel in that direction (``seen``), which of those as clear background (``clear``: no surface
    within the parallax margin, ``sky``), and
    the colour of those (bilinear over the background pixels of the 2 x 2 neighbourhood; the
    nearest one always among them)."""
    cam = view.camera
    rot = np.eye(4)
    rot[:3, :3] = cam.cam_from_world[:3, :3]
    xy, _ = cam.with_pose(rot).project(dirs)  # camera at the origin: a direction projects as a point
    w, h = cam.width, cam.height
    with np.errstate(invalid="ignore"):
        inside = np.isfinite(xy).all(-1) & (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
    depth = view.depth
    seen = np.zeros(len(dirs), bool)
    got = np.zeros(len(dirs), bool)
    rgb = np.zeros((0, 3), np.float32)
    if not inside.any():
        return seen, got, rgb
    p = xy[inside]
    ix = np.minimum(p[:, 0].astype(np.int64), w - 1)
    iy = np.minimum(p[:, 1].astype(np.int64), h - 1)
    at = depth[iy, ix]
    sky = clear[iy, ix] & np.isposinf(at)
    seen[np.nonzero(inside)[0][at > 0]] = True  # +inf included
    got[np.nonzero(inside)[0][sky]] = True
    p = p[sky]
    if not len(p):
        return seen, got, rgb
    # Bilinear between pixel centres, over background pixels only (weights renormalised).
    gx, gy = p[:, 0] - 0.5, p[:, 1] - 0.5
    x0, y0 = np.floor(gx).astype(np.int64), np.floor(gy).astype(np.int64)
    fx, fy = gx - x0, gy - y0
    color = view.color
    acc = np.zeros((len(p), 3))
    wsum = np.zeros(len(p))
    for dx, dy, wt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        cx, cy = np.clip(x0 + dx, 0, w - 1), np.clip(y0 + dy, 0, h - 1)
        wt = wt * np.isposinf(depth[cy, cx])
        acc += wt[:, None] * color[cy, cx]
        wsum += wt
    # wsum > 0: the nearest pixel is background and one of the four with weight >= 1/4 (a clipped
    # corner repeats an edge pixel, whose weight then adds up the same way).
    rgb = (acc / np.maximum(wsum, 1e-12)[:, None]).astype(np.float32)
    return seen, got, rgb
