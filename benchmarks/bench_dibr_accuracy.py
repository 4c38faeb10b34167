"""DIBR accuracy on real data (issue 3 "Targets"), beside the RVS 4.0 figures of ANCHORS.md.

    python benchmarks/bench_dibr_accuracy.py [--data ../shared/data] [--write docs/dibr.md]

Protocols (the same as the RVS figures in ../shared/ANCHORS.md):
  lego       hold out r_0, r_50, r_100, r_150 in turn; synthesise each from the 4 best of the 39
             other views (our view selection); PSNR/SSIM over all pixels with the ground truth
             composited over black, and PSNR over object pixels (alpha > 0.99 in r_N.png).
  ICL-NUIM   frame 4 from frames 1 and 5; PSNR over all pixels and over visible pixels (not holes).
  Teddy/Cones  right view (im6) from the left view (im2) + its disparity; scored on the pixels
             visible in both views. occl.png marks the *left* view, so the right view's mask
             is the ground-truth left-right consistency test: right pixel (x, y) with disparity
             d is visible in both when the left disparity at (x + d, y) is within 1 px of d.
Holes count as black in every "all pixels" and "object pixels" figure (nothing is inpainted);
"hole %" is the fraction of scored pixels that no input covers.

All comparisons are of sRGB encodings in [0, 1] (ibrtools.metrics.compare).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
LEGO_HELDOUT = ("r_0", "r_50", "r_100", "r_150")
# RVS 4.0 on the same protocols, from ../shared/ANCHORS.md.
RVS = {"lego object": 25.9, "lego all": 23.9, "Teddy visible": 29.6, "Cones visible": 28.2,
       "ICL all": 32.5, "ICL visible": 34.9}


def shared_data() -> Path:
    return Path(os.environ.get("IBR_SHARED_DATA", REPO.parent / "shared" / "data"))


def _sub(scene, keep: list[str]):
    from ibrtools.scene import Scene

    views = [v for v in scene.views if v.name in keep]
    return Scene(views=views, units=scene.units, source=scene.source, root=scene.root)


def _render(scene, inputs, camera, params=None):
    from ibrtools.render.dibr import DibrMethod

    m = DibrMethod({"inputs": inputs, **(params or {})})
    m.prepare(scene)
    t0 = time.perf_counter()
    out, ms = m.render(camera)
    ms["total"] = (time.perf_counter() - t0) * 1e3
    color = np.where(out["hole"][..., None], 0.0, out["color"]).astype(np.float32)
    return color, out["hole"], ms, m.frame_report()


def _psnr(a, b, mask=None):
    from ibrtools import metrics
    from ibrtools.imageio import linear_to_srgb

    return metrics.psnr(linear_to_srgb(a), linear_to_srgb(b), 1.0, mask=mask)


def lego(data: Path, params=None, heldout=LEGO_HELDOUT) -> dict:
    from ibrtools import metrics
    from ibrtools.formats import load
    from ibrtools.imageio import read_pixels

    scene = load(data / "nerf_lego", "nerf", {"background": "black"})
    names = [v.name for v in scene.views]
    rows = []
    for h in heldout:
        truth = scene.view(h)
        color, hole, ms, rep = _render(_sub(scene, [n for n in names if n != h]), 4, truth.camera, params)
        rgba, _ = read_pixels(data / "nerf_lego" / "test" / f"{h}.png")
        alpha = rgba[..., 3].astype(np.float64) / np.iinfo(rgba.dtype).max
        obj = alpha > 0.99
        m = metrics.compare(color, truth.color, hole_mask=hole)
        rows.append({"psnr_all": m["psnr"], "ssim_all": m["ssim"], "psnr_object": _psnr(color, truth.color, obj),
                     "hole_object": float(hole[obj].mean()), "ms": ms, "selected": rep["selected"]})
    return {"rows": rows, **{k: float(np.mean([r[k] for r in rows]))
                             for k in ("psnr_all", "ssim_all", "psnr_object", "hole_object")}}


def icl(data: Path, params=None) -> dict:
    from ibrtools import metrics
    from ibrtools.formats import load

    scene = load(data / "icl_nuim_livingroom")
    truth = scene.view("4")
    color, hole, ms, rep = _render(_sub(scene, ["1", "5"]), ["1", "5"], truth.camera, params)
    m = metrics.compare(color, truth.color, hole_mask=hole)
    return {"psnr_all": m["psnr"], "ssim_all": m["ssim"], "psnr_visible": m["psnr_masked"],
            "ssim_visible": m["ssim_masked"], "hole": float(hole.mean()), "ms": ms, "selected": rep["selected"]}


def visible_in_both_right(scene) -> np.ndarray:
    """Right-view pixels visible in both views, by left-right consistency of the ground-truth
    disparities (see the module doc); False where the right disparity is unknown."""
    left, right = scene.view("left"), scene.view("right")
    fb = left.camera.fx * np.linalg.norm(right.camera.centre - left.camera.centre)
    with np.errstate(divide="ignore"):
        d_r = np.where(right.depth > 0, fb / right.depth, 0.0)
        d_l = np.where(left.depth > 0, fb / left.depth, 0.0)
    h, w = d_r.shape
    y, x = np.mgrid[0:h, 0:w]
    xl = np.rint(x + d_r).astype(int)
    ok = (d_r > 0) & (xl >= 0) & (xl < w)
    d_at = np.where(ok, d_l[y, np.clip(xl, 0, w - 1)], 0.0)
    return ok & (d_at > 0) & (np.abs(d_at - d_r) <= 1.0)


def middlebury(data: Path, name: str, params=None) -> dict:
    from ibrtools import metrics
    from ibrtools.formats import load

    scene = load(data / "middlebury" / name, "middlebury")
    truth = scene.view("right")
    color, hole, ms, rep = _render(_sub(scene, ["left"]), ["left"], truth.camera, params)
    vis = visible_in_both_right(scene)
    m = metrics.compare(color, truth.color, mask=vis, hole_mask=hole)
    return {"psnr_visible": _psnr(color, truth.color, vis), "ssim_visible": m["ssim_masked"],
            "psnr_all": m["psnr"], "hole_visible": float(hole[vis].mean()), "hole": float(hole.mean()),
            "visible": float(vis.mean()), "ms": ms}


def run(data: Path, params=None) -> tuple[str, dict]:
    res = {"lego": lego(data, params), "icl": icl(data, params),
           "teddy": middlebury(data, "Teddy", params), "cones": middlebury(data, "Cones", params)}
    L, I, T, C = res["lego"], res["icl"], res["teddy"], res["cones"]
    f = lambda v: f"{v:.2f}"  # noqa: E731
    lines = [
        "| case | scored pixels | PSNR dB (ours) | RVS 4.0 PSNR dB | SSIM (ours) | hole % (of scored) | ms (ours, 1 frame) |",
        "|---|---|---|---|---|---|---|",
        f"| lego, 4 views → held-out (mean of {', '.join(LEGO_HELDOUT)}) | object (alpha > 0.99) | "
        f"**{f(L['psnr_object'])}** | {RVS['lego object']} | – | {100 * L['hole_object']:.2f} | "
        f"{np.mean([r['ms']['total'] for r in L['rows']]):.0f} |",
        f"| lego, same | all, over black | **{f(L['psnr_all'])}** | {RVS['lego all']} | {L['ssim_all']:.4f} | – | |",
        f"| ICL-NUIM 1 + 5 → 4 | visible (not holes) | **{f(I['psnr_visible'])}** | {RVS['ICL visible']} | "
        f"{I['ssim_visible']:.4f} | 0 | {I['ms']['total']:.0f} |",
        f"| ICL-NUIM, same | all (holes black) | **{f(I['psnr_all'])}** | {RVS['ICL all']} | {I['ssim_all']:.4f} | "
        f"{100 * I['hole']:.2f} | |",
        f"| Middlebury Teddy im2 → im6 | visible in both ({100 * T['visible']:.0f} %) | **{f(T['psnr_visible'])}** | "
        f"{RVS['Teddy visible']} | {T['ssim_visible']:.4f} | {100 * T['hole_visible']:.2f} | {T['ms']['total']:.0f} |",
        f"| Middlebury Cones im2 → im6 | visible in both ({100 * C['visible']:.0f} %) | **{f(C['psnr_visible'])}** | "
        f"{RVS['Cones visible']} | {C['ssim_visible']:.4f} | {100 * C['hole_visible']:.2f} | {C['ms']['total']:.0f} |",
    ]
    sel = "; ".join(f"{h}: {', '.join(r['selected'])}" for h, r in zip(LEGO_HELDOUT, L["rows"]))
    lines.append("")
    lines.append(f"lego views chosen by view selection: {sel}.")
    return "\n".join(lines), res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=shared_data())
    ap.add_argument("--write", type=Path, help="replace the 'Accuracy' section of this Markdown file")
    ap.add_argument("--quality", default="side")
    ap.add_argument("--blend-exponent", type=float, default=5.0)
    a = ap.parse_args(argv)
    if not a.data.is_dir():
        print(f"real data not found at {a.data} (set IBR_SHARED_DATA)", file=sys.stderr)
        return 2
    table, _ = run(a.data, {"quality": a.quality, "blend_exponent": a.blend_exponent})
    print(table)
    if a.write:
        sys.path.insert(0, str(Path(__file__).parent))
        from benchlib import write_section

        write_section("Accuracy", table, a.write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
