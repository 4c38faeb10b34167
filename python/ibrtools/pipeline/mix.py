"""The ``mix`` stage's fit: the hybrid composite's PVM weight floor by leave-one-out renders of
input views (the hybrid method is :mod:`ibrtools.hybrid.method`; docs/hybrid.md)."""
from __future__ import annotations

import math

import numpy as np

from ibrtools.errors import BadValueError
from ibrtools.hybrid.method import HybridMethod
from ibrtools.imageio import linear_to_srgb
from ibrtools.inpaint.complete import clean_color
from ibrtools.metrics import psnr
from ibrtools.pipeline.plan import plan
from ibrtools.scene import Scene


# The mix stage (docs/hybrid.md "Twelfth round"): the floors tried, and how much better than the
# smallest a floor must do to be taken (mean PSNR over the held-out input views). The fit renders
# with the hybrid's defaults: a change to them, or to these, changes what the stage writes (bump
# its version in cache.STAGES).
MIX_FLOORS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)


MIX_DEFAULTS = {"views": 6, "tol_db": 0.0}


def check_mix_options(options: dict) -> None:
    """The mix stage's options (``--set mix.KEY=VALUE``): known keys, ``views`` a whole number >= 1,
    ``tol_db`` a finite number >= 0; a BadValueError naming the option otherwise."""
    bad = sorted(set(options) - set(MIX_DEFAULTS))
    if bad:
        raise BadValueError.about("stage_options", f"unknown parameter(s) {bad} (parameters: "
                                                   f"{', '.join(MIX_DEFAULTS)})", "mix.*")
    views, tol = options.get("views", 1), options.get("tol_db", 0.0)
    if isinstance(views, bool) or not isinstance(views, (int, np.integer)) or views < 1:
        raise BadValueError.about("stage_options", "expected a whole number of views >= 1", f"mix.views={views!r}")
    if isinstance(tol, bool) or not isinstance(tol, (int, float, np.number)) or not 0.0 <= float(tol) < math.inf:
        raise BadValueError.about("stage_options", "expected a finite number of dB >= 0", f"mix.tol_db={tol!r}")


def fit_pvm_floor(scene: Scene, views: int = MIX_DEFAULTS["views"], tol_db: float = MIX_DEFAULTS["tol_db"],
                  floors: tuple[float, ...] = MIX_FLOORS) -> dict | str:
    """The hybrid's ``pvm_floor`` for ``scene``, fitted by leave-one-out: ``views`` input views
    spread over the scene's list are each held out in turn (absent from ULR's and PVM's inputs, as
    with ``--holdout``) and rendered by the hybrid at every floor; the floor taken is the smallest
    whose mean PSNR (sRGB, the held-out image as truth) is within ``tol_db`` (default 0: the best)
    of the best. The global mesh and the harmonised images were made with the held-out view, which
    favours ULR at it, so the fit errs towards small floors. Returns {"pvm_floor", "floors",
    "psnr" (views x floors), "views"}, or a reason (str) when the scene has too few views (< 4) to
    hold one out or is a video scene (not built yet for those: the floor is then 0)."""

    check_mix_options({"views": views, "tol_db": tol_db})
    if scene.frames:
        return "video scene: the leave-one-out fit is not built yet for frames"
    names = [v.name for v in scene.views if v.has_color]
    if len(names) < 4:
        return f"{len(names)} views with colour: the fit holds one out and needs >= 4"
    k = min(int(views), len(names))
    picked = [names[int((i + 0.5) * len(names) / k)] for i in range(k)]
    floors = tuple(sorted(set(float(f) for f in floors)))
    table = np.zeros((k, len(floors)))
    base = HybridMethod({"pvm_floor": 0.0})
    base.prepare(scene)  # once: each held-out view's method shares its loaded stages
    for i, name in enumerate(picked):
        job = plan(scene, holdout=[name])
        frame = job.frames[0]
        out, _, colors = base._without_views(job.scene)._render(frame.camera, floors)
        truth = linear_to_srgb(frame.truth.color)
        for j, c in enumerate(colors):
            v = psnr(linear_to_srgb(clean_color({"color": c, "hole": out["hole"]})), truth, 1.0)
            table[i, j] = v if v is not None and np.isfinite(v) else 100.0  # an exact match
    mean = table.mean(axis=0)
    best = float(mean.max())
    floor = next(f for f, v in zip(floors, mean) if v >= best - tol_db)
    return {"pvm_floor": float(floor), "floors": np.array(floors), "psnr": table, "views": np.array(picked)}
