"""Hole-filling quality on real disocclusions (docs/inpaint_quality.md).

    python benchmarks/bench_inpaint_quality.py [--data ../shared/data] [--write docs/inpaint_quality.md |
                                               --write-docs] [--cases teddy,cones,art,books,dolls,lego_r_0,...]

--write-docs is --write docs/inpaint_quality.md (the table between its inpaint_quality markers).

Cases (real data from ../shared/data, or $IBR_SHARED_DATA; the script exits cleanly when absent):
  Middlebury  Teddy, Cones (im2 -> im6), Art, Books, Dolls (view1 -> view5): the left view and its
              ground-truth disparity are warped into the right camera by ``_core.warp_with_holes``
              (the kernel of ``--method warp``: stretched quads written with the background depth).
              Holes to fill = every pixel the warp did not cover (disoccluded or uncovered); scored
              pixels = the disoccluded ones (``WARP_DISOCCLUDED``), against the real right view.
  lego        held-out views r_0, r_50, r_100 (``--method warp`` with the other 39 views as inputs:
              the most similar one is warped). Holes to fill = every uncovered pixel (the black
              background has no depth, so it is a hole too); scored pixels = disoccluded pixels that
              are object pixels of the ground truth (alpha > 0.99 in r_N.png).

Methods: no fill (holes black), classic push-pull, depth-aware push-pull (Alg. 1, the warp's
background depth in the holes), metameric (depth-aware moments; 4 levels, 2 orientations, seeds
0, 1, 2: the table gives the mean over seeds), OpenCV TELEA (``cv2.inpaint`` radius 3 on the 8-bit
sRGB image, as in bench_inpaint.py). ibrtools fills linear RGB (the engine's colour); every score
compares sRGB encodings in [0, 1] (``ibrtools.imageio.linear_to_srgb``, as ibrtools.metrics).
Two diagnostic rows take metameric apart (docs/inpaint_quality.md, "Why metameric loses on FLIP"):
  sigma = 0       metameric's mean alone: its pre-fill, the depth-aware push-pull of the display
                  (sRGB-encoded) values, decoded; metameric = this + the noise.
  truth's sigma   metameric's synthesis (same pre-fill, same noise, same masks, same collapse) with
                  sigma taken from the *ground truth* instead of the push-pulled moments: the local
                  standard deviation of each truth band (Gaussian window of 2 samples at the band's
                  level, E[X^2] - E[X]^2). An oracle: the best the moment estimate could be.
The criteria lines also give metameric's signed log variance ratio per band (fill vs truth, the
terms of Dvar with their sign, mean over Y, Cb, Cr and seeds): > 0 = more variance than the truth.

Scores, over the scored hole pixels only. Every method is scored on the *composite*: the ground
truth outside the scored holes, the method's fill inside them, so nothing but the fill differs:
  PSNR    ``metrics.psnr`` over the scored pixels.
  SSIM    ``metrics.ssim`` with the mask (mean of the SSIM map over the scored pixels; windows at the
          hole's rim read the ground truth outside it).
  FLIP    mean of the LDR-FLIP map (``metrics.flip(..., return_map=True)``, 67 ppd) over the scored
          pixels (the whole-image mean would be diluted by the identical pixels outside the holes).
  stats   statistics distance D = Dmean + Dvar between the filled region and the ground truth in the
          same region, on the steerable pyramid (``ibrtools.metamers.steerable.analyse``, 4 levels, 2
          orientations, YCbCr of the sRGB values): bands = high-pass, 4 x 2 band-pass, low-pass
          (10 bands) x 3 channels (Y, Cb, Cr) = 30 band-channels. Region at level l: the samples of
          which at least half the 2^l x 2^l block is a scored hole pixel (the high-pass: level 0, the
          low-pass: level 4); a band-channel is used when its region has >= 16 samples.
          Dmean = mean over used band-channels of |mean_fill - mean_truth|;
          Dvar  = mean over used band-channels of |ln(var_fill + eps) - ln(var_truth + eps)|,
          eps = (1/255)^2 / 12 (the variance of 8-bit rounding: below it the ground truth's own
          variance is not measured). Dvar in nepers: 0.69 = a factor 2 in variance.
  bleed   component mean error: per connected scored-hole component (8-connected, >= 32 pixels),
          |mean colour of the fill - mean colour of the truth| (sRGB, mean over channels), averaged
          over components weighted by their size. The issue's depth-aware criterion is "the hole
          takes the background's mean"; a fill that bleeds the foreground beside a disocclusion
          into it moves the hole's mean away from the (background) truth.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
METHODS = ("none", "pushpull", "pushpull_depth", "metameric", "telea", "metameric_mean", "metameric_oracle")
LABELS = {"none": "no fill (black)", "pushpull": "push-pull, classic", "pushpull_depth": "push-pull, depth-aware",
          "metameric": "metameric (depth-aware)", "telea": "OpenCV TELEA r=3",
          "metameric_mean": "diagnostic: metameric, sigma = 0",
          "metameric_oracle": "diagnostic: metameric, truth's sigma"}
SEEDED = ("metameric", "metameric_oracle")
ORACLE_WINDOW = 2.0  # Gaussian sigma, in samples of the band's level, of the truth's local variance
SEEDS = (0, 1, 2)
LEVELS, ORIENTATIONS = 4, 2
EPS_VAR = (1.0 / 255.0) ** 2 / 12.0
MIN_SAMPLES = 16
MIN_COMPONENT = 32
MIDDLEBURY = ("Teddy", "Cones", "Art", "Books", "Dolls")
LEGO_HELDOUT = ("r_0", "r_50", "r_100")


def shared_data() -> Path:
    return Path(os.environ.get("IBR_SHARED_DATA", REPO.parent / "shared" / "data"))


# --- cases --------------------------------------------------------------------------------------
def middlebury_case(data: Path, name: str) -> dict | None:
    """Left view warped into the right camera. Returns the warped frame, its depth, the fill mask,
    the scored mask and the right view (linear RGB); None when the data is absent."""
    from ibrtools import _core
    from ibrtools.formats import load

    path = data / "middlebury" / name
    if not path.is_dir():
        return None
    scene = load(path, "middlebury")
    left, right = scene.view("left"), scene.view("right")
    color, depth, mask = _core.warp_with_holes(
        np.ascontiguousarray(left.color, np.float32), np.ascontiguousarray(left.depth, np.float32),
        left.camera.to_core(), right.camera.to_core(), 2.0, 0.1)
    return {"name": f"Middlebury {name}", "color": color, "depth": depth, "hole": mask != _core.WARP_SURFACE,
            "scored": mask == _core.WARP_DISOCCLUDED, "truth": np.ascontiguousarray(right.color, np.float32),
            "source": "left"}


def lego_case(data: Path, held: str, scene=None) -> dict | None:
    """Held-out lego view rendered by ``--method warp`` from the most similar of the other views."""
    from ibrtools.formats import load
    from ibrtools.imageio import read_pixels
    from ibrtools.dibr.warp import WarpMethod
    from ibrtools.scene import Scene

    path = data / "nerf_lego"
    if not (path / "test" / f"{held}.png").is_file():
        return None
    scene = scene or load(path, "nerf", {"background": "black"})
    truth = scene.view(held)
    views = [v for v in scene.views if v.name != held]
    m = WarpMethod()
    m.prepare(Scene(views=views, units=scene.units, source=scene.source, root=scene.root))
    out, _ = m.render(truth.camera)
    rgba, _ = read_pixels(path / "test" / f"{held}.png")
    obj = rgba[..., 3].astype(np.float64) / np.iinfo(rgba.dtype).max > 0.99
    return {"name": f"lego {held}", "color": np.ascontiguousarray(out["color"], np.float32),
            "depth": np.ascontiguousarray(out["depth"], np.float32), "hole": out["hole"],
            "scored": out["disoccluded"] & obj, "truth": np.ascontiguousarray(truth.color, np.float32),
            "source": m.frame_report()["selected"][0]}


# --- methods ------------------------------------------------------------------------------------
def fill(case: dict, method: str, seed: int = 0) -> np.ndarray:
    """The frame with its holes filled by ``method`` (linear RGB float32)."""
    from ibrtools.imageio import linear_to_srgb, srgb_to_linear
    from ibrtools.inpaint.pushpull import pushpull
    from ibrtools.inpaint.metameric import metameric

    color, hole, depth = case["color"], case["hole"], case["depth"]
    if method == "none":
        return np.where(hole[..., None], 0.0, color).astype(np.float32)
    if method == "pushpull":
        return pushpull(color, hole)
    if method == "pushpull_depth":
        return pushpull(color, hole, depth)
    if method == "metameric":
        return metameric(color, hole, depth, levels=LEVELS, orientations=ORIENTATIONS, seed=seed)
    if method == "metameric_mean":
        return _metameric_parts(case, None)
    if method == "metameric_oracle":
        return _metameric_parts(case, seed)
    if method == "telea":
        import cv2

        bgr8 = np.ascontiguousarray((linear_to_srgb(color)[..., ::-1] * 255 + 0.5).astype(np.uint8))
        out = cv2.inpaint(bgr8, hole.astype(np.uint8) * 255, 3, cv2.INPAINT_TELEA)
        lin = srgb_to_linear(out[..., ::-1].astype(np.float32) / 255.0).astype(np.float32)
        return np.where(hole[..., None], lin, color).astype(np.float32)
    raise ValueError(method)


def _metameric_parts(case: dict, seed: int | None) -> np.ndarray:
    """Metameric's pipeline (ibrtools.inpaint.metameric.metameric, steps 0-5) from its public pieces, with the
    noise's sigma from the ground truth (seed given) or without noise (seed None: the pre-fill
    alone). Both reuse metameric's own pre-fill, noise pyramid, level masks and collapse; only
    sigma differs from :func:`fill`'s "metameric"."""
    from ibrtools import _core
    from ibrtools.inpaint.pushpull import pushpull
    from ibrtools.inpaint.metameric import _level_mask, level_masks, noise_pyramid
    from ibrtools.metamers.steerable import SteerablePyramid, analyse, synthesise
    from scipy import ndimage

    color, hole, depth = case["color"], case["hole"], case["depth"]
    x = np.ascontiguousarray(color, np.float32)
    filled = pushpull(_core.metameric_encode(x), hole, depth)  # display values, depth-aware (step 1)
    if seed is None:
        change = np.zeros_like(filled)
    else:
        h, w = hole.shape
        truth = analyse(_core.metameric_encode(np.ascontiguousarray(case["truth"], np.float32)), LEVELS,
                        ORIENTATIONS, ycbcr=True)
        noise = noise_pyramid(h, w, 3, LEVELS, ORIENTATIONS, seed)
        masks, _ = level_masks(hole, LEVELS)

        def band(t: np.ndarray, n: np.ndarray, level: int) -> np.ndarray:
            win = (ORACLE_WINDOW, ORACLE_WINDOW, 0)
            m, q = ndimage.gaussian_filter(t, win), ndimage.gaussian_filter(t * t, win)
            mask = _level_mask(masks[level], hole, 1 << level)
            return np.where(mask[..., None], np.sqrt(np.maximum(q - m * m, 0)) * n, 0).astype(np.float32)

        change = synthesise(SteerablePyramid(
            band(truth.highpass, noise.highpass, 0),
            [[band(t, n, l) for t, n in zip(truth.bands[l], noise.bands[l])] for l in range(LEVELS)],
            np.zeros_like(truth.lowpass), ycbcr=True))
    return _core.metameric_fill_holes(x, hole, filled, np.ascontiguousarray(change, np.float32), True)


# --- scores -------------------------------------------------------------------------------------
def _region_at(mask: np.ndarray, shape: tuple[int, int], scale: int) -> np.ndarray:
    """Level samples of which at least half the scale x scale block is in ``mask`` (ceil sizes)."""
    h, w = shape
    pad = np.zeros((h * scale, w * scale), np.float32)
    pad[:mask.shape[0], :mask.shape[1]] = mask
    return pad.reshape(h, scale, w, scale).mean(axis=(1, 3)) >= 0.5


def band_stats(srgb: np.ndarray, mask: np.ndarray) -> list[tuple[float, float] | None]:
    """(mean, variance) inside the region of every band-channel (high-pass, bands, low-pass; Y, Cb,
    Cr), None where the region has fewer than MIN_SAMPLES samples."""
    from ibrtools.metamers.steerable import analyse

    pyr = analyse(np.ascontiguousarray(srgb, np.float32), LEVELS, ORIENTATIONS, ycbcr=True)
    bands = [(pyr.highpass, 1)] + [(b, 1 << l) for l, lvl in enumerate(pyr.bands) for b in lvl] \
        + [(pyr.lowpass, 1 << LEVELS)]
    out = []
    for b, scale in bands:
        r = _region_at(mask, b.shape[:2], scale)
        for c in range(b.shape[2]):
            if r.sum() < MIN_SAMPLES:
                out.append(None)
                continue
            v = b[..., c][r].astype(np.float64)
            out.append((float(v.mean()), float(v.var())))
    return out


def signed_log_var(fill_stats, truth_stats) -> list[float | None]:
    """ln(var_fill + eps) - ln(var_truth + eps) per band-channel (the terms of Dvar with their sign),
    None where either has too few samples."""
    return [None if f is None or t is None else float(np.log(f[1] + EPS_VAR) - np.log(t[1] + EPS_VAR))
            for f, t in zip(fill_stats, truth_stats)]


def stats_distance(fill_stats, truth_stats) -> tuple[float, float]:
    """(Dmean, Dvar) over the band-channels both have (module doc)."""
    dm, dv = [], []
    for f, t in zip(fill_stats, truth_stats):
        if f is None or t is None:
            continue
        dm.append(abs(f[0] - t[0]))
        dv.append(abs(np.log(f[1] + EPS_VAR) - np.log(t[1] + EPS_VAR)))
    return float(np.mean(dm)), float(np.mean(dv))


def component_mean_error(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
    """Size-weighted mean over 8-connected components of ``mask`` (>= MIN_COMPONENT pixels) of
    |mean(a) - mean(b)| (mean over channels)."""
    from scipy import ndimage

    lab, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if n == 0:
        return None
    idx = np.arange(1, n + 1)
    size = ndimage.sum_labels(mask, lab, idx)
    err = np.zeros(n)
    for c in range(a.shape[2]):
        err += np.abs(ndimage.mean(a[..., c], lab, idx) - ndimage.mean(b[..., c], lab, idx))
    err /= a.shape[2]
    keep = size >= MIN_COMPONENT
    if not keep.any():
        return None
    return float(np.sum(err[keep] * size[keep]) / np.sum(size[keep]))


def score(filled: np.ndarray, case: dict, truth_stats=None) -> dict:
    """Scores of one filled frame over the case's scored holes (module doc)."""
    from ibrtools import metrics
    from ibrtools.imageio import linear_to_srgb

    truth, scored = case["truth"], case["scored"]
    comp = np.where(scored[..., None], filled, truth).astype(np.float32)
    a, b = linear_to_srgb(comp), linear_to_srgb(truth)
    _, fmap = metrics.flip(comp, truth, return_map=True)
    truth_stats = truth_stats if truth_stats is not None else band_stats(b, scored)
    fill_stats = band_stats(a, scored)
    dmean, dvar = stats_distance(fill_stats, truth_stats)
    return {"psnr": metrics.psnr(a, b, 1.0, mask=scored), "ssim": metrics.ssim(a, b, 1.0, mask=scored),
            "flip": float(fmap[scored].mean(dtype=np.float64)), "dmean": dmean, "dvar": dvar,
            "stats": dmean + dvar, "bleed": component_mean_error(a, b, scored),
            "signed": signed_log_var(fill_stats, truth_stats)}


def evaluate(case: dict, methods=METHODS, seeds=SEEDS) -> dict:
    """{method: mean scores (over seeds for metameric), plus "ms": fill time}."""
    from ibrtools.imageio import linear_to_srgb

    truth_stats = band_stats(linear_to_srgb(case["truth"]), case["scored"])
    res = {}
    for m in methods:
        rows, ms = [], []
        for seed in (seeds if m in SEEDED else (0,)):
            t0 = time.perf_counter()
            f = fill(case, m, seed)
            ms.append((time.perf_counter() - t0) * 1e3)
            rows.append(score(f, case, truth_stats))
        res[m] = {k: (None if any(r[k] is None for r in rows) else float(np.mean([r[k] for r in rows])))
                  for k in rows[0] if k != "signed"}
        res[m]["signed"] = [None if any(r["signed"][i] is None for r in rows)
                            else float(np.mean([r["signed"][i] for r in rows])) for i in range(len(rows[0]["signed"]))]
        res[m]["ms"] = float(np.median(ms))
        if m in SEEDED:
            res[m]["per_seed"] = rows
    return res


def cases(data: Path, which: list[str] | None = None):
    """Yield the available cases (generator: each case's arrays are freed after scoring)."""
    names = [n.lower() for n in which] if which else [n.lower() for n in MIDDLEBURY] + [f"lego_{h}" for h in LEGO_HELDOUT]
    lego_scene = None
    for n in names:
        if n.startswith("lego_"):
            if not (data / "nerf_lego").is_dir():
                continue
            if lego_scene is None:
                from ibrtools.formats import load

                lego_scene = load(data / "nerf_lego", "nerf", {"background": "black"})
            c = lego_case(data, n[5:], lego_scene)
        else:
            c = middlebury_case(data, {m.lower(): m for m in MIDDLEBURY}.get(n, n))
        if c is not None:
            yield c


# --- report -------------------------------------------------------------------------------------
def _f(v, fmt):
    return "–" if v is None else format(v, fmt)


def table(results: list[tuple[dict, dict]]) -> str:
    lines = [("| case (scored holes) | method | PSNR dB ↑ | SSIM ↑ | FLIP ↓ | stats D ↓ (Dmean + Dvar) | "
              "bleed ↓ | fill ms |"), "|---|---|---|---|---|---|---|---|"]
    for case, res in results:
        n = int(case["scored"].sum())
        head = f"{case['name']} ({n} px, {100 * n / case['scored'].size:.1f} %)"
        for i, m in enumerate(m for m in METHODS if m in res):
            r = res[m]
            lines.append(f"| {head if i == 0 else ''} | {LABELS[m]} | {_f(r['psnr'], '.2f')} | {_f(r['ssim'], '.3f')} | "
                         f"{_f(r['flip'], '.3f')} | {r['stats']:.3f} ({r['dmean']:.3f} + {r['dvar']:.3f}) | "
                         f"{_f(r['bleed'], '.4f')} | {r['ms']:.0f} |")
    return "\n".join(lines)


def band_groups(signed: list[float | None]) -> str:
    """Signed log variance ratios per band (mean over Y, Cb, Cr; '–' where absent): high-pass,
    level 0..3 (mean over orientations), low-pass."""
    k = 3 * ORIENTATIONS
    groups = [("hp", signed[0:3])] + [(f"L{l}", signed[3 + l * k:3 + (l + 1) * k]) for l in range(LEVELS)] \
        + [("lo", signed[3 + LEVELS * k:])]
    out = []
    for name, vals in groups:
        v = [x for x in vals if x is not None]
        out.append(f"{name} {'–' if not v else format(float(np.mean(v)), '+.2f')}")
    return " ".join(out)


def criteria(results: list[tuple[dict, dict]]) -> list[str]:
    """The issue's relations, case by case, and metameric taken apart (module doc)."""
    out = []
    for case, res in results:
        mm, pp, pd = res["metameric"], res["pushpull"], res["pushpull_depth"]
        seeds = mm["per_seed"]
        line = (f"{case['name']}: stats metameric {mm['stats']:.3f} vs push-pull classic {pp['stats']:.3f} / "
                f"depth-aware {pd['stats']:.3f} (every seed below both: "
                f"{all(s['stats'] < min(pp['stats'], pd['stats']) for s in seeds)}); "
                f"FLIP metameric {mm['flip']:.3f} vs {pp['flip']:.3f} / {pd['flip']:.3f} "
                f"(seeds {', '.join(format(s['flip'], '.3f') for s in seeds)}); "
                f"bleed depth-aware {_f(pd['bleed'], '.4f')} vs classic {_f(pp['bleed'], '.4f')}")
        if "metameric_mean" in res and "metameric_oracle" in res:
            z, o = res["metameric_mean"], res["metameric_oracle"]
            line += (f"; FLIP sigma = 0 {z['flip']:.3f} → metameric {mm['flip']:.3f} → truth's sigma {o['flip']:.3f} "
                     f"(stats {z['stats']:.3f} → {mm['stats']:.3f} → {o['stats']:.3f}); "
                     f"metameric signed ln var ratio: {band_groups(mm['signed'])}")
        out.append(line)
    return out


def run(data: Path, which=None) -> tuple[str, list]:
    results = []
    t_all = time.perf_counter()
    for case in cases(data, which):
        t0 = time.perf_counter()
        res = evaluate(case)
        print(f"{case['name']}: {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        light = {k: case[k] for k in ("name", "scored", "source")}
        results.append((light, res))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    note = (f"(run: {time.perf_counter() - t_all:.0f} s for {len(results)} cases; 1-minute load average at the end "
            f"{load:.2f}; fill ms are medians of the calls and depend on that load)")
    return table(results) + "\n\n" + note, results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=shared_data())
    ap.add_argument("--cases", default="", help="comma-separated subset (teddy, cones, art, books, dolls, lego_r_0, ...)")
    ap.add_argument("--write", type=Path, default=None, help="replace the <!-- inpaint_quality --> table in this file")
    ap.add_argument("--write-docs", action="store_true", help="--write docs/inpaint_quality.md")
    a = ap.parse_args(argv)
    if a.write_docs and a.write is None:
        a.write = REPO / "docs" / "inpaint_quality.md"
    if not a.data.is_dir():
        print(f"bench_inpaint_quality: no shared data at {a.data} (set IBR_SHARED_DATA); nothing measured")
        return 0
    try:
        import cv2  # noqa: F401
        import flip_evaluator  # noqa: F401
    except ImportError as e:
        print(f"bench_inpaint_quality: needs opencv-python and flip-evaluator ({e}); nothing measured")
        return 0
    text, results = run(a.data, [c for c in a.cases.split(",") if c] or None)
    if not results:
        print(f"bench_inpaint_quality: no case found under {a.data}; nothing measured")
        return 0
    crit = criteria(results)
    print(text)
    print("\n".join(crit))
    if a.write:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from benchlib import write_section

        write_section("inpaint_quality", text + "\n\n" + "\n".join(f"* {c}" for c in crit), a.write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
