"""Which part of the views' estimated global gains is exposure (the texture and harmonise stages).

:func:`ibrtools.hybrid.variance.vertex_statistics` estimates one per-channel gain per view (the
median ratio of its colours to the vertex means). It cannot tell an exposure change from
view-dependent shading: on a scene whose exposures agree but whose shading varies with the
viewing direction (NeRF lego: gains 0.81-1.12, smooth in azimuth), dividing them out moves
the texture away from the truth. Exposure jitter is independent from view to view; shading is a
smooth function of the viewing direction. :func:`exposure_gains` tests which one the gains look
like:

* each view's log-gain is predicted from the OTHER views' log-gains by a Gaussian kernel on
  the angle between the views' optical axes (leave-one-out kernel regression, ``sigma_deg``);
* ``ratio`` = RMS of the leave-one-out residuals / RMS of the log-gains about their mean (per
  channel, pooled). Independent jitter gives ratio >= ~1 (the neighbours do not predict it);
  a smooth function of direction gives a small ratio.
* ratio >= ``max_ratio``: the gains are taken as exposure and returned unchanged (the previous
  model). ratio < ``max_ratio``: the smooth part is shading and is left in the images; only the
  residual ``exp(log g - prediction)`` (re-centred to geometric mean 1) is divided out.

A view with no neighbour within 3 sigma keeps its prediction at the mean log-gain.

**Is what is left global?** (``half_gains``, optional.) An exposure scales the whole image; a
"gain" that differs between the halves of the image is local appearance (shading, highlights, the
mesh's errors) that a median over the image happened to turn into a number. Given each view's
gain measured on its left / right / top / bottom halves, the noise variance of a view's log-gain
is taken as ``s2`` = mean over views, channels and both splits of (half difference)^2 / 4, and
the gains to divide out (their log, about the views' mean ``c``) are shrunk by the positive-part
James-Stein factor ``f = max(0, 1 - s2 / mean(r^2))``, r = log g - c: ``exp(c + f r)``. On NeRF
lego (no exposure differences) the residual after the shading model is 0.021 rms against a
half-split noise of 0.025: f = 0, nothing is divided out; on a synthetic scene with exposure
jitter 0.1, 0.104 against 0.0003: f = 1.000 (docs/harmonise.md "Is the gain global").
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ibrtools.camera import Camera
from ibrtools.checks import check_float
from ibrtools.errors import BadValueError, ShapeError

SIGMA_DEG = 20.0   # kernel width on the angle between optical axes
MAX_RATIO = 0.5    # leave-one-out residual / spread below this: the spread is shading
GAIN_MODES = ("auto", "exposure", "none")


def _axes(cameras: Mapping[str, Camera], names: list[str]) -> np.ndarray:
    ax = []
    for n in names:
        cam = cameras[n]
        if cam.model != "pinhole":
            raise BadValueError(f"exposure gains: view {n!r} is {cam.model}; only pinhole views have an optical axis")
        a = np.asarray(cam.world_from_cam, np.float64)[:3, 2]
        ax.append(a / np.linalg.norm(a))
    return np.array(ax).reshape(-1, 3)


def gain_smoothness(gains: Mapping[str, np.ndarray], cameras: Mapping[str, Camera],
                    sigma_deg: float = SIGMA_DEG) -> tuple[float, dict[str, np.ndarray]]:
    """(ratio, prediction): the leave-one-out residual ratio described in the module docstring
    and each view's predicted log-gain (3,). Needs at least 3 views."""
    sigma = check_float(sigma_deg, "sigma_deg")
    if not sigma > 0:
        raise BadValueError(f"sigma_deg: expected > 0, got {sigma_deg!r}")
    names = list(gains)
    missing = [n for n in names if n not in cameras]
    if missing:
        raise BadValueError(f"exposure gains: no camera for view(s) {missing}")
    if len(names) < 3:
        raise BadValueError(f"exposure gains: need at least 3 views, got {len(names)}")
    g = np.array([np.asarray(gains[n], np.float64) for n in names])
    if g.shape != (len(names), 3):
        raise ShapeError(f"gains: expected one (3,) gain per view, got shape {g.shape}")
    if not (np.isfinite(g).all() and (g > 0).all()):
        raise BadValueError("gains: expected finite positive values")
    lg = np.log(g)
    mu = lg.mean(0)
    ax = _axes(cameras, names)
    ang = np.degrees(np.arccos(np.clip(ax @ ax.T, -1.0, 1.0)))
    w = np.exp(-0.5 * (ang / sigma) ** 2) * (ang <= 3 * sigma)
    np.fill_diagonal(w, 0.0)
    ws = w.sum(1)
    pred = np.where(ws[:, None] > 0, (w @ lg) / np.where(ws > 0, ws, 1)[:, None], mu[None])
    spread = float(np.sqrt(np.mean((lg - mu) ** 2)))
    resid = float(np.sqrt(np.mean((lg - pred) ** 2)))
    ratio = resid / spread if spread > 0 else 1.0
    return ratio, {n: pred[i] for i, n in enumerate(names)}


HALF_MIN_SAMPLES = 16  # a half with fewer samples keeps the whole image's gain (no evidence either way)


def gain_halves(ratio: np.ndarray, x: np.ndarray, y: np.ndarray, width: int, height: int,
               whole: np.ndarray) -> np.ndarray:
    """(4, 3): the per-channel median of ``ratio`` (n, 3), one row per sample of a view at ``x``,
    ``y`` (pixels, centres at +0.5), over the samples in the left, right, top and bottom half of
    its ``width`` x ``height`` image: the view's gain measured on each half, for
    :func:`global_shrink`. A half with fewer than ``HALF_MIN_SAMPLES`` samples gets ``whole``
    (the gain on the whole image), so that it says nothing against it."""
    out = []
    for part in (x < width / 2, x >= width / 2, y < height / 2, y >= height / 2):
        out.append(np.median(ratio[part], axis=0) if np.count_nonzero(part) >= HALF_MIN_SAMPLES else whole)
    return np.array(out, np.float64).reshape(4, 3)


def global_shrink(gains: Mapping[str, np.ndarray],
                  half_gains: Mapping[str, np.ndarray]) -> tuple[dict[str, np.ndarray], float]:
    """(the gains shrunk towards their common level, f): the "Is what is left global?" step of the
    module docstring. ``half_gains``: per view (4, 3), the gain measured on the image's left,
    right, top and bottom halves (the same convention as ``gains``)."""
    names = list(gains)
    missing = [n for n in names if n not in half_gains]
    if missing:
        raise BadValueError(f"half_gains: no half-image gains for view(s) {missing}")
    lg = np.log(np.array([np.asarray(gains[n], np.float64) for n in names]).reshape(-1, 3))
    hg = np.array([np.asarray(half_gains[n], np.float64) for n in names])
    if hg.shape != (len(names), 4, 3):
        raise ShapeError(f"half_gains: expected one (4, 3) array per view, got shape {hg.shape}")
    if not (np.isfinite(hg).all() and (hg > 0).all()):
        raise BadValueError("half_gains: expected finite positive values")
    lh = np.log(hg)
    s2 = float(np.mean(np.concatenate([lh[:, 0] - lh[:, 1], lh[:, 2] - lh[:, 3]]) ** 2) / 4)
    centre = lg.mean(0)
    r = lg - centre
    ms = float(np.mean(r ** 2))
    f = max(0.0, 1.0 - s2 / ms) if ms > 0 else 0.0
    return {n: np.exp(centre + f * r[i]) for i, n in enumerate(names)}, f


def exposure_gains(gains: Mapping[str, np.ndarray], cameras: Mapping[str, Camera], *, mode: str = "auto",
                   sigma_deg: float = SIGMA_DEG, max_ratio: float = MAX_RATIO,
                   half_gains: Mapping[str, np.ndarray] | None = None) -> tuple[dict[str, np.ndarray], dict]:
    """The gains to divide out of the views and a record {"ratio", "model": "exposure" |
    "shading" | "none", "shrink": f or None}. ``mode``: "auto" (the test of the module docstring),
    "exposure" (the gains unchanged), "none" (every gain 1). Fewer than 3 views or an equirect view:
    "auto" keeps the gains. ``half_gains`` (per view (4, 3): the gain on the image's left / right /
    top / bottom halves): what the model keeps is then shrunk by :func:`global_shrink`."""
    if mode not in GAIN_MODES:
        raise BadValueError(f"gain model: expected one of {GAIN_MODES}, got {mode!r}")
    mr = check_float(max_ratio, "max_ratio")
    if not mr >= 0:
        raise BadValueError(f"max_ratio: expected >= 0, got {max_ratio!r}")
    out = {n: np.asarray(g, np.float64) for n, g in gains.items()}
    if mode == "none":
        return {n: np.ones_like(g) for n, g in out.items()}, {"ratio": None, "model": "none", "shrink": None}
    ratio: float | None = None
    model = "exposure"
    # Fewer than 3 views, or a view without an optical axis (equirect): the test cannot run.
    if not (mode == "exposure" or len(out) < 3
            or any(n in cameras and cameras[n].model != "pinhole" for n in out)):
        ratio, pred = gain_smoothness(out, cameras, sigma_deg)
        if ratio < mr:
            model = "shading"
            res = {n: np.log(out[n]) - pred[n] for n in out}
            centre = np.mean(list(res.values()), axis=0)
            out = {n: np.exp(r - centre) for n, r in res.items()}
    f = None
    if half_gains is not None and len(out) >= 2:
        out, f = global_shrink(out, half_gains)
        f = round(f, 4)
    return out, {"ratio": None if ratio is None else round(ratio, 4), "model": model, "shrink": f}
