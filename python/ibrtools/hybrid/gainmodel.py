"""Which part of the views' estimated global gains is exposure (issue 7, the texture stage).

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
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..camera import Camera
from ..checks import check_float
from ..errors import BadValueError, ShapeError

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


def exposure_gains(gains: Mapping[str, np.ndarray], cameras: Mapping[str, Camera], *, mode: str = "auto",
                   sigma_deg: float = SIGMA_DEG, max_ratio: float = MAX_RATIO
                   ) -> tuple[dict[str, np.ndarray], dict]:
    """The gains to divide out of the views and a record {"ratio", "model": "exposure" |
    "shading" | "none"}. ``mode``: "auto" (the test of the module docstring), "exposure" (the
    gains unchanged), "none" (every gain 1). Fewer than 3 views or an equirect view: "auto"
    keeps the gains."""
    if mode not in GAIN_MODES:
        raise BadValueError(f"gain model: expected one of {GAIN_MODES}, got {mode!r}")
    mr = check_float(max_ratio, "max_ratio")
    if not mr >= 0:
        raise BadValueError(f"max_ratio: expected >= 0, got {max_ratio!r}")
    out = {n: np.asarray(g, np.float64) for n, g in gains.items()}
    if mode == "none":
        return {n: np.ones_like(g) for n, g in out.items()}, {"ratio": None, "model": "none"}
    # Fewer than 3 views, or a view without an optical axis (equirect): the test cannot run.
    if (mode == "exposure" or len(out) < 3
            or any(n in cameras and cameras[n].model != "pinhole" for n in out)):
        return out, {"ratio": None, "model": "exposure"}
    ratio, pred = gain_smoothness(out, cameras, sigma_deg)
    if ratio >= mr:
        return out, {"ratio": round(ratio, 4), "model": "exposure"}
    res = {n: np.log(out[n]) - pred[n] for n in out}
    centre = np.mean(list(res.values()), axis=0)
    return {n: np.exp(r - centre) for n, r in res.items()}, {"ratio": round(ratio, 4), "model": "shading"}
