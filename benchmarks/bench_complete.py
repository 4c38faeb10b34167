"""Complete images with the defaults (docs/benchmarks.md "Complete images"): the frame as
``ibr-render --method dibr`` writes it (background at infinity rendered, holes filled by
``--inpaint auto``) beside the same frame with ``--inpaint none`` (holes black) and the covered
pixels only, on the real-data protocols of bench_dibr_accuracy.py and RVS 4.0's figures
(as published), and on the demo's held-out views.

    python benchmarks/bench_complete.py [--data ../shared/data] [--write-docs]

  lego       r_0, r_50, r_100, r_150 held out in turn, each from the 4 best of the other 39
             (background black): PSNR over all pixels and over object pixels (alpha > 0.99).
  Middlebury every pair of ../shared/data/middlebury: right view from the left; PSNR over the
             pixels visible in both (bench_dibr_accuracy.visible_in_both_right).
  demo       synth:objects 12 views 480x360 (make demo), v003 and v009 held out: PSNR over all
             pixels, covered pixels, coverage and filled fraction.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_dibr_accuracy import LEGO_HELDOUT, RVS, visible_in_both_right  # noqa: E402
from benchlib import machine, shared_data, write_section  # noqa: E402



def _psnr(a, b, mask=None):
    from ibrtools import metrics
    from ibrtools.imageio import linear_to_srgb

    v = metrics.psnr(linear_to_srgb(a), linear_to_srgb(b), 1.0, mask=mask)
    return None if v is None or not np.isfinite(v) else float(v)


def _without(scene, names):
    from ibrtools.scene import Scene

    return Scene(views=[v for v in scene.views if v.name not in names], units=scene.units,
                 source=scene.source, shading=scene.shading, root=scene.root)


def _both(scene, camera, **params):
    from ibrtools import api

    done = api.render(scene, camera, method="dibr", **params)
    black = api.render(scene, camera, method="dibr", inpaint="none", **params)
    return done, black


def lego(data: Path) -> dict:
    from ibrtools.formats import load
    from ibrtools.imageio import read_pixels

    scene = load(data / "nerf_lego", "nerf", {"background": "black"})
    rows = []
    for h in LEGO_HELDOUT:
        truth = scene.view(h)
        done, black = _both(_without(scene, [h]), truth.camera, inputs=4)
        rgba, _ = read_pixels(data / "nerf_lego" / "test" / f"{h}.png")
        obj = rgba[..., 3].astype(np.float64) / np.iinfo(rgba.dtype).max > 0.99
        rows.append({"view": h, "all": _psnr(done.color, truth.color), "object": _psnr(done.color, truth.color, obj),
                     "all_black": _psnr(black.color, truth.color), "object_black": _psnr(black.color, truth.color, obj),
                     "object_covered": _psnr(black.color, truth.color, obj & ~black.hole),
                     "filled": float(done.hole.mean()), "background_fg": _bg_foreground(done, truth)})
    return {"rows": rows, **{k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k != "view"}}


def _bg_foreground(done, truth) -> float:
    """Fraction of the truth's background pixels (depth +inf) given a colour other than black."""
    bg = np.isposinf(truth.depth)
    return float((done.color[bg].max(-1) > 1e-3).mean()) if bg.any() else 0.0


def middlebury(data: Path) -> dict:
    from ibrtools.formats import load

    out = {}
    for d in sorted(p for p in (data / "middlebury").iterdir() if p.is_dir()):
        scene = load(d, "middlebury")
        truth = scene.view("right")
        done, black = _both(_without(scene, ["right"]), truth.camera, inputs=["left"])
        vis = visible_in_both_right(scene)
        out[d.name] = {"visible": _psnr(done.color, truth.color, vis), "visible_black": _psnr(black.color, truth.color, vis),
                       "visible_covered": _psnr(black.color, truth.color, vis & ~black.hole),
                       "hole_visible": float(black.hole[vis].mean())}
    return out


def demo() -> dict:
    from ibrtools import synth
    from ibrtools.pipeline import job as J
    from ibrtools.pipeline import plan as planning
    scene = synth.make_scene("objects", views=12, size=(480, 360))
    job = planning.plan(scene, holdout=["v003", "v009"])
    rows = []
    for f in job.frames:
        done, black = _both(job.scene, f.camera)
        rows.append({"view": f.name, "all": _psnr(done.color, f.truth.color), "all_black": _psnr(black.color, f.truth.color),
                     "covered": _psnr(black.color, f.truth.color, ~black.hole), "coverage": float(1 - black.hole.mean()),
                     "written_coverage": 1.0 if not done.hole.any() or done.color[done.hole].any() else float(1 - done.hole.mean()),
                     "filled": float(done.hole.mean()), "background_fg": _bg_foreground(done, f.truth)})
    return {"rows": rows, **{k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k != "view"}}


def _f(v, nd=2):
    return "n/a" if v is None else f"{v:.{nd}f}"


def markdown(res: dict) -> str:
    lg, mb, dm = res["lego"], res["middlebury"], res["demo"]
    lines = ["## Complete images", "",
             "The frame as `ibr-render --method dibr` writes it with the defaults (background at infinity rendered, holes "
             "filled by `--inpaint auto`), beside `--inpaint none` (holes black) and the covered pixels; PSNR (dB) of sRGB "
             f"in [0, 1]. Measured by `benchmarks/bench_complete.py` on {machine()} (protocols in its doc string; "
             "RVS 4.0 from ../shared/ANCHORS.md, with its own hole filling).", "",
             "| case | defaults | holes black | covered only | RVS 4.0 |", "|---|---|---|---|---|",
             f"| lego object pixels (mean of {len(lg['rows'])} held-out views) | {_f(lg['object'])} | {_f(lg['object_black'])} | "
             f"{_f(lg['object_covered'])} | {RVS['lego object']} |",
             f"| lego all pixels | {_f(lg['all'])} | {_f(lg['all_black'])} | | {RVS['lego all']} |"]
    for name, r in mb.items():
        rvs = RVS.get(f"{name} visible")
        lines.append(f"| Middlebury {name}, visible pixels | {_f(r['visible'])} | {_f(r['visible_black'])} | "
                     f"{_f(r['visible_covered'])} | {'' if rvs is None else rvs} |")
    lines.append(f"| demo (synth:objects, v003 v009) all pixels | {_f(dm['all'])} | {_f(dm['all_black'])} | "
                 f"{_f(dm['covered'])} | |")
    lines += ["", f"lego: filled {100 * lg['filled']:.2f} % of the pixels; background pixels (truth at infinity) given a "
                  f"non-black colour: {100 * lg['background_fg']:.3f} %. Demo: coverage by the warp and the background "
                  f"{dm['coverage']:.3f}, filled {100 * dm['filled']:.2f} %, background pixels given a non-black colour "
                  f"{100 * dm['background_fg']:.3f} %.", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument("--write-docs", action="store_true", help="replace the section in docs/benchmarks.md")
    a = ap.parse_args()
    data = a.data or shared_data()
    res = {"lego": lego(data), "middlebury": middlebury(data), "demo": demo()}
    md = markdown(res)
    print(md)
    if a.write_docs:
        write_section("complete", md)


if __name__ == "__main__":
    main()
