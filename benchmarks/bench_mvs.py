"""Multi-view stereo (the ``mvs`` stage, ibrtools.mvs.run_mvs) on real data: two-view accuracy on
Middlebury beside OpenCV's StereoSGBM, end to end on fountain-P11 photos, and lego with its depth
withheld.

    python benchmarks/bench_mvs.py [--middlebury] [--fountain] [--lego] [--data DIR] [--keep DIR]
                                   [--reuse] [--json FILE] [--write-docs]

No flag: all three sections. ``--write-docs`` replaces the section between ``<!-- bench_mvs:begin -->``
and ``<!-- bench_mvs:end -->`` of docs/benchmarks.md (appended when absent); a sub-section not run
this time is kept as the file had it. Nothing is tuned: every ibrtools option is its default except
where a protocol below says otherwise.

--middlebury  For each pair of ../shared/data/middlebury (the middlebury importer: focal f = image
  width, B = 1, left camera at the origin, right at +B along x, ground-truth depth z = f B / d for
  both views), the left view's depth by ``run_mvs`` on the two views with ``names=["left"]``, from
  colour and cameras only (the views are rebuilt without their ground-truth depth, else the right
  view's would serve the geometric pass and the filter). With one source the filter's
  ``min_consistent`` is capped at the sources with depth, i.e. 0 (the right view has none): only
  ``max_cost`` filters. Depth range: the default "auto" (the cameras' axes are parallel, so z_c =
  20 x baseline and z in [5 B, 80 B], disparity f/80 .. f/5), and a wide range from the cameras
  alone, disparity 1 .. 300 px (z in [f B / 300, f B]). Never from the ground truth. Disparity
  d = f B / z. Peer: OpenCV StereoSGBM on the stored 8-bit images (BGR), minDisparity 0,
  numDisparities the multiple of 16 covering the auto range (0 .. f/5), blockSize 5, P1 = 8*3*5^2,
  P2 = 32*3*5^2, uniquenessRatio 10, speckleWindowSize 100, speckleRange 2, disp12MaxDiff 1,
  MODE_SGBM_3WAY, its fixed-point output / 16; values below minDisparity (invalid) are unknown.
  Scored pixels ("non-occluded"): the left GT disparity d_L is known (> 0), x - d_L rounded to the
  nearest pixel lies inside the right image, and the right GT disparity there is known and within
  1 px of d_L (the left-right check on the ground truth; occl.png is not used, its agreement is
  reported). bad-1.0 / bad-2.0: % of scored pixels with |d - d_GT| > 1 / 2 px, unknown counted bad
  ("all") or excluded ("known"); completeness: % of scored pixels with a value. Times: wall and
  CPU (process time, every thread) of one left-view estimate, median of 3 runs each.
  Scale check: the GT disparity read as value / s for s in SCALE_CANDIDATES; the s whose
  warp of the right image onto the left (bilinear, at x - d) matches the left best (mean absolute
  grey difference over the scored pixels) must be the README's (4 for 2003, 3 for 2005), and the
  importer's depth must be f B s / value.

--fountain  ``ibr-preprocess fountain_p11 -o DIR --format colmap --methods dibr --holdout NAME``
  for NAME in FOUNTAIN_HELDOUT, one at a time (the other 10 photos are the inputs and get MVS
  depth; the held-out photo is ground truth no stage reads), then ``ibr-render DIR --method dibr``
  and again with ``--inpaint pushpull``. Scores from report.json: psnr / ssim / flip over all
  pixels, psnr_covered over the covered pixels, coverage. MVS time from scene.json (stages.mvs).
  docs/img/mvs/fountain_NAME.png: photo | render | render with push-pull, each 384 px wide.

--lego  ``ibr-preprocess nerf_lego -o A --opt background=black --holdout r_0 r_50 --methods dibr``
  (the held-out protocol of docs/preprocess.md and bench_hybrid_lego, two of its four views), then
  a copy B whose views have no depth ("depth", "depth_stored" removed from every view of
  scene.json, "meshes" and "stages" dropped), ``ibr-preprocess B -o B --methods dibr`` (runs mvs).
  The stage is first timed on LEGO_PROBE alone and extrapolated to every input view; above
  LEGO_BUDGET_S, A and B alike keep only the LEGO_NEAREST input views nearest to each target.
  Scores: ``ibr-render X --method dibr`` report psnr (all pixels) and psnr_covered (covered) on
  r_0, r_50 for A (the data set's depth) and B (MVS depth); MVS depth vs the data set's depth
  (the importer's de-quantised z) on the input views: % of the pixels with GT depth whose MVS
  depth is within 1 % (unknown counts as a miss), % of kept pixels (MVS and GT known) off by more
  than 5 %, completeness (% of GT pixels with MVS depth), and MVS depth on background pixels (a surface's
  or the background's, +inf).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import resource
import shlex
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import DOCS, cpu_name, load_note, shared_data, write_section  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
SECTION = "bench_mvs"
PAIRS = ("Art", "Books", "Cones", "Dolls", "Teddy")
MB_FILES = {"im2.png": ("im2.png", "im6.png", "disp2.png", "disp6.png"),
            "view1.png": ("view1.png", "view5.png", "disp1.png", "disp5.png")}
SCALE_CANDIDATES = (1.0, 2.0, 3.0, 4.0, 6.0, 8.0)
WIDE_DISPARITY = (1.0, 300.0)  # px: the "wide" camera-derived range (no GT)
SGBM_BLOCK = 5
REPEATS = 3
FOUNTAIN_HELDOUT = ("0003", "0005", "0007")
LEGO_HELDOUT = ("r_0", "r_50")
LEGO_PROBE = ("r_5", "r_195")  # two neighbouring input views: the mvs stage timed on them alone
LEGO_BUDGET_S = 15 * 60        # above this estimate for every input view, only LEGO_NEAREST per target
LEGO_NEAREST = 8               # input views nearest (camera centre) to each held-out camera
PANEL_WIDTH = 384
IMG_DIR = REPO / "docs" / "img" / "mvs"


def _timed(fn, repeats: int = REPEATS):
    """(last result, median wall s, median CPU s) over ``repeats`` calls."""
    walls, cpus, out = [], [], None
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    return out, statistics.median(walls), statistics.median(cpus)


def _run(cmd: list[str], log: list[str]) -> tuple[float, float]:
    """Run a CLI, fail loudly; returns (wall s, CPU s of the child: user + system, every thread)."""
    log.append(" ".join(shlex.quote(str(c)) for c in cmd))
    print("+", log[-1], flush=True)
    t = time.perf_counter()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise RuntimeError(f"{log[-1]} failed ({p.returncode}):\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}")
    return time.perf_counter() - t, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


# --------------------------------------------------------------------------- Middlebury

def _disp_png(path: Path) -> np.ndarray:
    import cv2

    a = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return (a[..., 0] if a.ndim == 3 else a).astype(np.float64)


def nonoccluded(d_l: np.ndarray, d_r: np.ndarray) -> np.ndarray:
    """Left pixels whose GT disparity is known and whose match x - d_L (nearest pixel) in the right
    view has a known GT disparity within 1 px of it."""
    h, w = d_l.shape
    y, x = np.mgrid[0:h, 0:w]
    xr = np.rint(x - d_l).astype(int)
    ok = (d_l > 0) & (xr >= 0) & (xr < w)
    at = np.where(ok, d_r[y, np.clip(xr, 0, w - 1)], 0.0)
    return ok & (at > 0) & (np.abs(at - d_l) <= 1.0)


def _warp_error(g_l: np.ndarray, g_r: np.ndarray, d: np.ndarray, mask: np.ndarray) -> float:
    """Mean |left - right(x - d)| (bilinear along x) over ``mask`` pixels whose match is inside."""
    h, w = g_l.shape
    y, x = np.mgrid[0:h, 0:w]
    xs = x - d
    ok = mask & (xs >= 0) & (xs <= w - 1)
    x0 = np.clip(np.floor(xs).astype(int), 0, w - 2)
    t = np.clip(xs - x0, 0, 1)
    v = (1 - t) * g_r[y, x0] + t * g_r[y, x0 + 1]
    return float(np.abs(v - g_l)[ok].mean())


def score_disparity(d: np.ndarray | None, known: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> dict:
    err = np.abs(d - gt)
    k = known & mask
    n = int(mask.sum())
    out = {"completeness": 100.0 * k.sum() / n}
    for t in (1.0, 2.0):
        bad = mask & (~known | (err > t))
        out[f"bad{t:g}_all"] = 100.0 * bad.sum() / n
        out[f"bad{t:g}_known"] = 100.0 * (k & (err > t)).sum() / max(int(k.sum()), 1)
    out["mae_known"] = float(err[k].mean()) if k.any() else float("nan")
    return out


def sgbm(left_bgr: np.ndarray, right_bgr: np.ndarray, num_disp: int):
    import cv2

    bs = SGBM_BLOCK
    m = cv2.StereoSGBM_create(minDisparity=0, numDisparities=num_disp, blockSize=bs, P1=8 * 3 * bs * bs,
                              P2=32 * 3 * bs * bs, disp12MaxDiff=1, uniquenessRatio=10, speckleWindowSize=100,
                              speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    return m.compute(left_bgr, right_bgr)


def middlebury_pair(root: Path, name: str) -> dict:
    import cv2
    from ibrtools.formats import load
    from ibrtools.formats.middlebury import nonoccluded_mask
    from ibrtools.mvs import MvsOptions, run_mvs
    from ibrtools.mvs.stereo import grey
    from ibrtools.scene import View

    path = root / name
    files = next(v for k, v in MB_FILES.items() if (path / k).is_file())
    scale = 4.0 if files[0] == "im2.png" else 3.0  # the data README's value per pixel of disparity
    scene = load(path, "middlebury")
    L, R = scene.view("left"), scene.view("right")
    f = float(L.camera.fx)
    B = float(np.linalg.norm(R.camera.centre - L.camera.centre))
    raw_l, raw_r = _disp_png(path / files[2]), _disp_png(path / files[3])
    gt_l, gt_r = raw_l / scale, raw_r / scale
    mask = nonoccluded(gt_l, gt_r)
    # The importer's conversion: z = f B / (value / scale).
    with np.errstate(divide="ignore"):
        z_expect = np.where(raw_l > 0, f * B * scale / np.where(raw_l > 0, raw_l, 1), 0)
    importer_rel = float(np.max(np.abs(L.depth - z_expect)[raw_l > 0] / z_expect[raw_l > 0]))
    # Image scale vs disparity scale: the divisor whose warp matches best.
    g_l, g_r = grey(L.color).astype(np.float64), grey(R.color).astype(np.float64)
    warp = {s: _warp_error(g_l, g_r, raw_l / s, raw_l > 0) for s in SCALE_CANDIDATES}
    occl = nonoccluded_mask(scene)
    occl_agree = None if occl is None else float(100.0 * np.mean(occl[raw_l > 0] == mask[raw_l > 0]))

    views = [View.create(v.name, v.camera, color=v.color) for v in (L, R)]  # no GT depth
    auto_rng = f / 80.0, f / 5.0  # disparity of the auto depth range [5 B, 80 B] (checked below)
    runs = {}
    for key, opt in (("auto", MvsOptions()),
                     ("wide", MvsOptions(depth_range=f"{f * B / WIDE_DISPARITY[1]:.9g},{f * B / WIDE_DISPARITY[0]:.9g}"))):
        res, wall, cpu = _timed(lambda: run_mvs(views, opt, names=["left"]))
        r = res["left"]
        z = r.depth.astype(np.float64)
        known = z > 0
        d = np.where(known, f * B / np.where(known, z, 1), 0.0)
        runs[key] = {**score_disparity(d, known, gt_l, mask), "wall": wall, "cpu": cpu,
                     "range_disp": (f * B / r.depth_range[1], f * B / r.depth_range[0]), "stats": r.stats,
                     "sources": r.sources}
    lb, rb = cv2.imread(str(path / files[0]), cv2.IMREAD_COLOR), cv2.imread(str(path / files[1]), cv2.IMREAD_COLOR)
    num = int(16 * np.ceil((auto_rng[1] + 1) / 16))
    raw, wall, cpu = _timed(lambda: sgbm(lb, rb, num))
    d = raw.astype(np.float64) / 16.0
    known = d >= 0  # minDisparity 0: invalid pixels are (minDisparity - 1) * 16
    runs["sgbm"] = {**score_disparity(d, known, gt_l, mask), "wall": wall, "cpu": cpu, "num_disp": num}
    gtk = gt_l[gt_l > 0]
    return {"name": name, "size": (L.camera.width, L.camera.height), "f": f, "B": B, "scale": scale,
            "warp_error": warp, "best_scale": min(warp, key=warp.get), "importer_rel": importer_rel,
            "scored": float(100.0 * mask.mean()), "occl_agree": occl_agree,
            "gt_range": (float(gtk.min()), float(gtk.max())),
            "gt_outside_auto": float(100.0 * np.mean((gt_l[mask] < runs["auto"]["range_disp"][0])
                                                     | (gt_l[mask] > runs["auto"]["range_disp"][1]))),
            "runs": runs}


def section_middlebury(data: Path) -> tuple[str, dict]:
    import cv2

    root = data / "middlebury"
    res = [middlebury_pair(root, n) for n in PAIRS if (root / n).is_dir()]
    labels = {"auto": "ours, range auto", "wide": f"ours, disparity {WIDE_DISPARITY[0]:g}..{WIDE_DISPARITY[1]:g} px",
              "sgbm": "OpenCV StereoSGBM"}
    L = ["### Middlebury: two-view disparity (left view from the right) beside OpenCV StereoSGBM", "",
         "| pair | method | bad-1.0 % (unknown = bad) | bad-1.0 % (known only) | bad-2.0 % (unknown = bad) | "
         "bad-2.0 % (known only) | completeness % | MAE px (known) | wall s | CPU s |",
         "|---|---|---|---|---|---|---|---|---|---|"]
    for p in res:
        for k in ("auto", "wide", "sgbm"):
            r = p["runs"][k]
            L.append(f"| {p['name']} | {labels[k]} | {r['bad1_all']:.2f} | {r['bad1_known']:.2f} | {r['bad2_all']:.2f} | "
                     f"{r['bad2_known']:.2f} | {r['completeness']:.2f} | {r['mae_known']:.2f} | {r['wall']:.3f} | "
                     f"{r['cpu']:.3f} |")
    for k in ("auto", "wide", "sgbm"):
        m = {c: np.mean([p["runs"][k][c] for p in res]) for c in ("bad1_all", "bad1_known", "bad2_all", "bad2_known",
                                                                    "completeness", "mae_known", "wall", "cpu")}
        L.append(f"| **mean** | {labels[k]} | {m['bad1_all']:.2f} | {m['bad1_known']:.2f} | {m['bad2_all']:.2f} | "
                 f"{m['bad2_known']:.2f} | {m['completeness']:.2f} | {m['mae_known']:.2f} | {m['wall']:.3f} | "
                 f"{m['cpu']:.3f} |")
    L += ["",
          "Protocol: ibrtools' middlebury importer (f = image width, baseline B = 1); `run_mvs` on the two views rebuilt "
          "without their ground-truth depth, `names=[\"left\"]`, `MvsOptions()` defaults (one source; the filter's "
          "`min_consistent` is capped at the sources with depth = 0, so only `max_cost` filters), depth range either the "
          "default auto (parallel axes: z in [5 B, 80 B], disparity f/80..f/5) or disparity "
          f"{WIDE_DISPARITY[0]:g}..{WIDE_DISPARITY[1]:g} px (z = f B / d), both from the cameras only; disparity = f B / z. "
          f"StereoSGBM (OpenCV {cv2.__version__}): minDisparity 0, numDisparities = the multiple of 16 covering 0..f/5 "
          "(" + ", ".join(f"{p['name']} {p['runs']['sgbm']['num_disp']}" for p in res) + f"), blockSize {SGBM_BLOCK}, "
          "P1 = 8·3·bs², P2 = 32·3·bs², uniquenessRatio 10, speckleWindowSize 100, speckleRange 2, disp12MaxDiff 1, "
          "MODE_SGBM_3WAY, on the stored 8-bit colour images; output / 16, negative (invalid, including its left border "
          "of numDisparities columns) = unknown.",
          "Scored pixels: left GT disparity known, and the right GT disparity at x − d (nearest pixel) known and within "
          "1 px of it (a left-right check of the two GT maps; occl.png is not used). Share of the left image scored: "
          + ", ".join(f"{p['name']} {p['scored']:.1f} %" for p in res) + ". Where occl.png exists, this mask agrees with "
          "it on " + ", ".join(f"{p['name']} {p['occl_agree']:.1f} %" for p in res if p["occl_agree"] is not None)
          + " of the GT-known pixels.",
          f"Times: wall and CPU (process time over all threads) of one left-view estimate, median of {REPEATS} runs each, "
          "MVS and SGBM alike; the machine's 2 cores are shared, so wall times are indicative.",
          "Scale check (GT disparity = value / s; mean |left − right warped by the GT| in sRGB grey over GT-known pixels, "
          "s = " + "/".join(f"{s:g}" for s in SCALE_CANDIDATES) + "): best s "
          + ", ".join(f"{p['name']} {p['best_scale']:g} (README {p['scale']:g}; error "
                      f"{p['warp_error'][p['best_scale']]:.4f} vs {min(v for s, v in p['warp_error'].items() if s != p['best_scale']):.4f} "
                      "next best)" for p in res)
          + ". The importer's depth equals f·B·s / value to a relative "
          f"{max(p['importer_rel'] for p in res):.1e} (float32).",
          "GT disparity range (for the record, used by no method): "
          + ", ".join(f"{p['name']} {p['gt_range'][0]:.1f}..{p['gt_range'][1]:.1f} px (auto range "
                      f"{p['runs']['auto']['range_disp'][0]:.1f}..{p['runs']['auto']['range_disp'][1]:.1f}; "
                      f"{p['gt_outside_auto']:.2f} % of scored pixels outside)" for p in res) + "."]
    return "\n".join(L), {"pairs": res}


# --------------------------------------------------------------------------- fountain

def _frame_metrics(out: Path, name: str) -> dict:
    rep = json.loads((out / "report.json").read_text())
    for fr in rep.get("frames", []):
        if fr.get("name", fr.get("frame")) == name:
            return fr.get("metrics", fr)
    raise KeyError(f"{out}/report.json: no frame {name!r}")


def _panel(path: Path, width: int = PANEL_WIDTH):
    from PIL import Image

    im = Image.open(path).convert("RGB")
    return im.resize((width, round(im.height * width / im.width)), Image.LANCZOS)


def side_by_side(paths: list[Path], out: Path) -> None:
    from PIL import Image

    ps = [_panel(p) for p in paths]
    canvas = Image.new("RGB", (sum(p.width for p in ps), max(p.height for p in ps)))
    x = 0
    for p in ps:
        canvas.paste(p, (x, 0))
        x += p.width
    out.parent.mkdir(parents=True, exist_ok=True)
    # A 256-colour palette (median cut, no dithering): a third of the true-colour file, for the docs only.
    canvas.quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(out, optimize=True)


def _mvs_stage(scene_dir: Path) -> dict:
    st = json.loads((scene_dir / "scene.json").read_text())["stages"]["mvs"]
    return st


def section_fountain(data: Path, keep: Path, reuse: bool, log: list[str]) -> tuple[str, dict]:
    src = data / "fountain_p11"
    rows = []
    for name in FOUNTAIN_HELDOUT:
        if not (src / "images_25" / f"{name}.png").is_file():
            raise FileNotFoundError(f"{src}/images_25/{name}.png")
        d = keep / f"fountain_{name}"
        side = keep / f"fountain_{name}.preprocess.json"  # the run's wall / CPU, for a --reuse run
        if not (reuse and (d / "scene.json").is_file() and "mvs" in json.loads((d / "scene.json").read_text())["stages"]):
            pre = _run([BIN / "ibr-preprocess", src, "-o", d, "--format", "colmap", "--methods", "dibr", "--holdout", name],
                       log)
            side.write_text(json.dumps(pre))
        else:
            pre = tuple(json.loads(side.read_text())) if side.is_file() else None
            log.append(f"(reused {d}: its mvs stage ran in an earlier run of this script)")
        outs = {}
        for key, extra in (("plain", ["--inpaint", "none"]), ("pushpull", ["--inpaint", "pushpull"])):
            o = keep / f"fountain_{name}_render_{key}"
            _run([BIN / "ibr-render", d, "--method", "dibr", "-o", o, *extra], log)
            outs[key] = o
        st = _mvs_stage(d)
        m = {k: _frame_metrics(o, name) for k, o in outs.items()}
        img = IMG_DIR / f"fountain_{name}.png"
        side_by_side([src / "images_25" / f"{name}.png", outs["plain"] / f"{name}.png", outs["pushpull"] / f"{name}.png"],
                     img)
        rows.append({"name": name, "metrics": m, "mvs": st, "preprocess_wall": pre, "image": img.name})
    L = ["### fountain-P11: COLMAP import, MVS depth, DIBR of a held-out photo", "",
         "| held-out | inpaint | PSNR dB (all) | PSNR dB (covered) | SSIM | FLIP | coverage % |",
         "|---|---|---|---|---|---|---|"]
    for r in rows:
        for key, lab in (("plain", "none (holes black)"), ("pushpull", "pushpull")):
            m = r["metrics"][key]
            fl = f"{m['flip']:.4f}" if m.get("flip") is not None else "n/a"
            L.append(f"| {r['name']} | {lab} | {m['psnr']:.2f} | {m['psnr_covered']:.2f} | {m['ssim']:.4f} | {fl} | "
                     f"{100 * m['coverage']:.2f} |")
    L += ["", "| held-out | mvs stage s (scene.json) | setup s | photometric s | geometric s | filter s | "
              "evaluations / s | ibr-preprocess wall / CPU s |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        st = r["mvs"]
        det = st.get("details", {})
        sec = det.get("seconds", {})
        pw = (f"{r['preprocess_wall'][0]:.1f} / {r['preprocess_wall'][1]:.1f}" if r["preprocess_wall"] is not None
              else "n/a")
        L.append(f"| {r['name']} | {st.get('seconds', float('nan')):.1f} | {sec.get('setup', float('nan')):.2f} | "
                 f"{sec.get('photometric', float('nan')):.1f} | {sec.get('geometric', float('nan')):.1f} | "
                 f"{sec.get('filter', float('nan')):.2f} | {det.get('evaluations_per_second', 'n/a')} | {pw} |")
    L += ["", "Protocol: `ibr-preprocess ../shared/data/fountain_p11 -o DIR --format colmap --methods dibr --holdout NAME` "
              "(the 768×512 `images_25` photos, the COLMAP model's intrinsics scaled to them; the other 10 photos are the "
              "inputs and all get MVS depth with the mvs stage's defaults), then `ibr-render DIR --method dibr -o OUT` and "
              "the same with `--inpaint pushpull`; every figure is report.json's for the held-out frame (sRGB PSNR/SSIM "
              "over all pixels, psnr_covered over the covered pixels, FLIP over all pixels, coverage = 1 − holes). "
              "Times: scene.json `stages.mvs.seconds` (the stage) and `details.seconds` per pass; one run each "
              "(2 shared cores).", "",
          "Photo | DIBR (holes black) | DIBR + push-pull, each downscaled to 384 px wide (Lanczos; 256-colour PNG):", ""]
    for r in rows:
        L.append(f"![fountain {r['name']}: photo, DIBR, DIBR with push-pull](img/mvs/{r['image']})")
    return "\n".join(L), {"views": rows}


# --------------------------------------------------------------------------- lego

def strip_depth(src: Path, dst: Path, keep_views: tuple[str, ...] | None = None) -> None:
    """A copy of scene ``src`` whose views have no depth (and no meshes, no stage records)."""
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    s = json.loads((dst / "scene.json").read_text())
    if keep_views is not None:
        s["views"] = [v for v in s["views"] if v["name"] in keep_views]
    for v in s["views"]:
        v.pop("depth", None)
        v.pop("depth_stored", None)
    s.pop("meshes", None)
    s.pop("stages", None)
    for p in dst.iterdir():
        if p.is_dir() and p.name not in ("images", "targets"):
            shutil.rmtree(p)  # stage caches
    (dst / "scene.json").write_text(json.dumps(s, indent=1))


def subset_scene(src: Path, dst: Path, keep_views: tuple[str, ...]) -> None:
    """A copy of scene ``src`` with only the input views ``keep_views`` (depth kept)."""
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    s = json.loads((dst / "scene.json").read_text())
    s["views"] = [v for v in s["views"] if v["name"] in keep_views]
    s.pop("stages", None)
    (dst / "scene.json").write_text(json.dumps(s, indent=1))


def lego_depth_accuracy(with_depth: Path, mvs_scene: Path) -> dict:
    from ibrtools.formats.native import load as load_scene
    from ibrtools.cache import load_npz, mvs_arrays, stage_output

    gt_scene = load_scene(with_depth)
    mvs = mvs_arrays(load_npz(stage_output(mvs_scene, "mvs")), "depth")
    hit = total = kept = off5 = bg = bg_given = bg_inf = 0
    per = {}
    for n, z in mvs.items():
        g = gt_scene.view(n).depth
        known = np.isfinite(g) & (g > 0)  # the background is +inf
        surface = np.isfinite(z) & (z > 0)  # MVS writes +inf outside an RGBA capture's masks: the background
        k = known & surface
        rel = np.abs(z - g) / np.where(known, g, 1)
        per[n] = float(100.0 * (k & (rel <= 0.01)).sum() / known.sum())
        hit += int((k & (rel <= 0.01)).sum())
        total += int(known.sum())
        kept += int(k.sum())
        off5 += int((k & (rel > 0.05)).sum())
        bg += int((~known).sum())
        bg_given += int((~known & surface).sum())
        bg_inf += int((~known & np.isposinf(z)).sum())
    return {"within1": 100.0 * hit / total, "off5_kept": 100.0 * off5 / max(kept, 1),
            "completeness": 100.0 * kept / total, "background_given": 100.0 * bg_given / max(bg, 1),
            "background_inf": 100.0 * bg_inf / max(bg, 1),
            "views": len(mvs), "per_view_within1": per}


def _centre(cam: dict) -> np.ndarray:
    m = np.array(cam["cam_from_world"], dtype=np.float64)
    return -m[:3, :3].T @ m[:3, 3]


def lego_estimate(a: Path, keep: Path, log: list[str]) -> dict:
    """The mvs stage on LEGO_PROBE alone (one source each), extrapolated to every input view with
    the stage's default sources: seconds per view and source x sources x views."""
    from ibrtools.mvs import MvsOptions

    p = keep / "lego_probe"
    strip_depth(a, p, LEGO_PROBE)
    wall, cpu = _run([BIN / "ibr-preprocess", p, "-o", p, "--methods", "dibr"], log)
    st = _mvs_stage(p)
    views = len(json.loads((a / "scene.json").read_text())["views"])
    per = st["seconds"] / len(LEGO_PROBE)
    return {"stage_s": st["seconds"], "wall": wall, "cpu": cpu, "views": views, "sources": MvsOptions().sources,
            "estimate_s": per * MvsOptions().sources * views}


def lego_subset(a: Path) -> tuple[str, ...]:
    """The LEGO_NEAREST input views nearest to each held-out camera (union, in the scene's order)."""
    s = json.loads((a / "scene.json").read_text())
    chosen = set()
    for t in s["targets"]:
        if t["name"] in LEGO_HELDOUT:
            c = _centre(t["camera"])
            near = sorted(s["views"], key=lambda v: (np.linalg.norm(_centre(v["camera"]) - c), v["name"]))
            chosen |= {v["name"] for v in near[:LEGO_NEAREST]}
    return tuple(v["name"] for v in s["views"] if v["name"] in chosen)


def section_lego(data: Path, keep: Path, reuse: bool, log: list[str]) -> tuple[str, dict]:
    a = keep / "lego_depth"
    _run([BIN / "ibr-preprocess", data / "nerf_lego", "-o", a, "--opt", "background=black", "--holdout", *LEGO_HELDOUT,
          "--methods", "dibr"], log)
    est = lego_estimate(a, keep, log)
    subset = lego_subset(a) if est["estimate_s"] > LEGO_BUDGET_S else None
    a_used = a
    if subset is not None:
        a_used = keep / "lego_depth_subset"
        subset_scene(a, a_used, subset)
        _run([BIN / "ibr-preprocess", a_used, "-o", a_used, "--methods", "dibr"], log)
        log.insert(-1, f"(copy of {a} keeping only the input views {' '.join(subset)})")
    b = keep / "lego_mvs"
    if not (reuse and (b / "scene.json").is_file() and "mvs" in json.loads((b / "scene.json").read_text()).get("stages", {})):
        strip_depth(a, b, subset)
        log.append(f"(copy of {a} without depth: 'depth', 'depth_stored' removed from every view, 'meshes', 'stages' "
                   "dropped" + (f", only the views {' '.join(subset)}" if subset else "") + ")")
        _run([BIN / "ibr-preprocess", b, "-o", b, "--methods", "dibr"], log)
    else:
        log.append(f"(reused {b})")
    m = {}
    for key, d in (("gt", a_used), ("mvs", b)):
        o = keep / f"lego_render_{key}"
        _run([BIN / "ibr-render", d, "--method", "dibr", "--inpaint", "none", "-o", o], log)
        m[key] = {n: _frame_metrics(o, n) for n in LEGO_HELDOUT}
    acc = lego_depth_accuracy(a, b)
    st = _mvs_stage(b)
    det = st.get("details", {})
    sec = det.get("seconds", {})
    n_views = len(json.loads((b / "scene.json").read_text())["views"])
    L = ["### lego: the data set's depth withheld, MVS depth instead", "",
         "| held-out | depth | PSNR dB (all) | PSNR dB (covered) | SSIM | coverage % |", "|---|---|---|---|---|---|"]
    for n in LEGO_HELDOUT:
        for key, lab in (("gt", "data set's"), ("mvs", "MVS")):
            r = m[key][n]
            L.append(f"| {n} | {lab} | {r['psnr']:.2f} | {r['psnr_covered']:.2f} | {r['ssim']:.4f} | "
                     f"{100 * r['coverage']:.2f} |")
    L += ["", f"MVS depth against the data set's on the {acc['views']} input views: **{acc['within1']:.2f} %** of the "
              f"pixels with GT depth within 1 % (unknown = miss), {acc['off5_kept']:.2f} % of the kept pixels off by more "
              f"than 5 %, completeness {acc['completeness']:.2f} %; of the background pixels (no GT depth) "
              f"{acc['background_given']:.2f} % were given a surface's depth and {acc['background_inf']:.2f} % the "
              "background's (+inf, outside the views' masks). Within 1 % per view: min "
              f"{min(acc['per_view_within1'].values()):.1f} %, median {statistics.median(acc['per_view_within1'].values()):.1f} %,"
              f" max {max(acc['per_view_within1'].values()):.1f} %.",
          f"mvs stage ({n_views} views, 800×800): {st.get('seconds', float('nan')):.1f} s (photometric "
          f"{sec.get('photometric', float('nan')):.1f} s, geometric {sec.get('geometric', float('nan')):.1f} s, filter "
          f"{sec.get('filter', float('nan')):.2f} s), {det.get('evaluations_per_second', 'n/a')} evaluations / s.", "",
          "Protocol: `ibr-preprocess ../shared/data/nerf_lego -o A --opt background=black --holdout r_0 r_50 --methods dibr` "
          "(docs/preprocess.md's held-out protocol; r_0 and r_50 are targets no stage reads); B = a copy of A whose views "
          "have no depth (`depth`, `depth_stored` removed from every view of scene.json, `meshes` and `stages` dropped), "
          "`ibr-preprocess B -o B --methods dibr` (the mvs stage, defaults); `ibr-render X --method dibr -o OUT` on A and "
          "B; report.json's psnr (all pixels, background black in both), psnr_covered (covered pixels), ssim, coverage. "
          "GT depth = the nerf importer's z (ray distance converted, 8-bit codes de-quantised, steps ≈ 0.75 % at the "
          "object's distance, so 1 % is close to the GT's own resolution)."]
    L.append(f"Time estimate first: the mvs stage on {' and '.join(LEGO_PROBE)} alone (one source each) took "
             f"{est['stage_s']:.1f} s (ibr-preprocess {est['wall']:.1f} s wall, {est['cpu']:.1f} s CPU), i.e. "
             f"{est['stage_s'] / len(LEGO_PROBE):.1f} s per view and source; x {est['sources']} sources x "
             f"{est['views']} input views ≈ {est['estimate_s'] / 60:.0f} min.")
    if subset is not None:
        L.append(f"That is over {LEGO_BUDGET_S // 60} min, so A and B alike keep only the {len(subset)} input views "
                 f"nearest (camera centre) to r_0 or r_50, {LEGO_NEAREST} per target: {' '.join(subset)} (the DIBR "
                 "render chooses its 4 inputs among the nearest, and each of them keeps neighbours to match against). "
                 "The depth accuracy is over these views.")
    else:
        L.append("That is within the budget: every input view is used.")
    return "\n".join(L), {"render": m, "depth": acc, "mvs": st, "estimate": est, "subset": subset}


# --------------------------------------------------------------------------- docs

def _sub_blocks(text: str) -> dict[str, str]:
    return {m.group(1): m.group(2) for m in re.finditer(r"<!-- bench_mvs:(\w+):begin -->\n(.*?)<!-- bench_mvs:\1:end -->",
                                                        text, re.S)}


def code_state() -> str:
    """The ibrtools the run measured: the commit, uncommitted changes to the engine, MvsOptions()."""
    from ibrtools.mvs import MvsOptions

    git = lambda *a: subprocess.run(["git", "-C", str(REPO), *a], capture_output=True, text=True).stdout.strip()  # noqa: E731
    dirty = git("status", "--porcelain", "--", "cpp", "python/ibrtools").splitlines()
    opts = ", ".join(f"{k}={v}" for k, v in MvsOptions().to_dict().items())
    return (f"ibrtools at commit {git('rev-parse', '--short', 'HEAD') or 'unknown'}"
            + (f" with uncommitted changes to {', '.join(line.split(maxsplit=1)[1] for line in dirty)}" if dirty else "")
            + f"; MvsOptions() = {opts}.")


def compose(parts: dict[str, str], commands: dict[str, str], path: Path = DOCS) -> str:
    old = _sub_blocks(path.read_text()) if path.exists() else {}
    today = datetime.date.today().isoformat()
    state = code_state()
    blocks = []
    for key in ("middlebury", "fountain", "lego"):
        if key in parts:
            body = (f"{parts[key].rstrip()}\n\nMeasured {today} on {cpu_name()} ({os.cpu_count()} cores); reproduce with "
                    f"`{commands[key]}`. {load_note()}\n{state}\n")
        elif key in old:
            body = old[key]
        else:
            continue
        blocks.append(f"<!-- bench_mvs:{key}:begin -->\n{body}<!-- bench_mvs:{key}:end -->")
    return ("## Multi-view stereo (benchmarks/bench_mvs.py)\n\n"
            "The `mvs` stage (PatchMatch stereo, `ibrtools.mvs.run_mvs`) on real data; each sub-section says its "
            "machine, date and command.\n\n" + "\n\n".join(blocks))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--middlebury", action="store_true")
    ap.add_argument("--fountain", action="store_true")
    ap.add_argument("--lego", action="store_true")
    ap.add_argument("--data", type=Path, default=shared_data())
    ap.add_argument("--keep", type=Path, default=None, help="work directory kept after the run (default: a temporary one)")
    ap.add_argument("--reuse", action="store_true", help="with --keep: reuse scenes whose mvs stage already ran")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--write-docs", action="store_true", help=f"replace the {SECTION} section of docs/benchmarks.md")
    a = ap.parse_args(argv)
    if not a.data.is_dir():
        print(f"real data not found at {a.data} (set IBR_SHARED_DATA)", file=sys.stderr)
        return 2
    which = [k for k in ("middlebury", "fountain", "lego") if getattr(a, k)] or ["middlebury", "fountain", "lego"]
    import tempfile

    tmp = None
    keep = a.keep
    if keep is None:
        tmp = tempfile.TemporaryDirectory(prefix="bench_mvs_")
        keep = Path(tmp.name)
    keep.mkdir(parents=True, exist_ok=True)
    parts, results, commands = {}, {}, {}
    for k in which:
        log: list[str] = []
        if k == "middlebury":
            parts[k], results[k] = section_middlebury(a.data)
        elif k == "fountain":
            parts[k], results[k] = section_fountain(a.data, keep, a.reuse, log)
        else:
            parts[k], results[k] = section_lego(a.data, keep, a.reuse, log)
        results[k]["commands"] = log
        commands[k] = f"python benchmarks/bench_mvs.py --{k} --write-docs"
        print(parts[k], flush=True)
    if a.json:
        a.json.write_text(json.dumps(results, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    if a.write_docs:
        write_section(SECTION, compose(parts, commands))
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
