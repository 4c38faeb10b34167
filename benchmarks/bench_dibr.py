"""DIBR (forward mesh warp + streaming blend, _core.DibrAccumulator) vs a naive point splat.

    python benchmarks/bench_dibr.py [--repeats 5] [--quick] [--write-docs] [--isa auto|baseline|avx2]
        [--blend-space srgb|linear]

Scene: ``ibrtools.synth.make_scene("objects", views=8)`` (textured ground, boxes, spheres, a
cylinder; 8 input cameras on a ring, one target half-way between two of them; colour and
z-depth rendered by the reference ray caster, so the target's colour is ground truth). The
k inputs nearest to the target (camera centres) are used. For each case, after one warm-up,
the median (and the minimum) of --repeats runs of: reset, per input the sRGB encode when the blend space is
srgb (the renderer's default; ``--blend-space``) and add_view (the kernel's own wall time of the warp +
accumulation, with the colour check, is ``last_add_ms``), result() (normalise, with the decode for srgb). Cases: k = 1, 2, 4, 8 at
1920x1080 and k = 4 at 512x512, 1024x1024, 1920x1080, 3840x2160; on 2 threads and on 1.

Baseline, measured in the same run on the same inputs: a naive forward splat in numpy --
every valid input pixel is un-projected and projected into the target, rounded to the
nearest pixel, and the nearest depth over all inputs wins (a z-buffer by sorting). PSNR is
against the ground-truth target colour, over all pixels and over pixels that both methods
cover; holes = fraction of target pixels no input covers (the ground truth has black
background where no surface is, which both methods leave as holes too).
"""
from __future__ import annotations

import argparse
import math
import os
import statistics
import time

import numpy as np
from benchlib import machine, write_section

from ibrtools import _core, synth


def psnr(a, b, mask=None):
    d = (a.astype(np.float64) - b) ** 2
    d = d[mask] if mask is not None else d
    mse = float(np.mean(d))
    return math.inf if mse == 0 else -10 * math.log10(mse)


def naive_splat(inputs, target):
    h, w = target.height, target.width
    pts, cols, zs = [], [], []
    for v in inputs:
        ok = v.depth > 0
        p = v.camera.unproject(v.depth)[ok]
        xy, z = target.project(p)
        good = np.isfinite(z) & (z > 0)
        xi = np.floor(xy[good, 0]).astype(np.int64)
        yi = np.floor(xy[good, 1]).astype(np.int64)
        inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
        pts.append(yi[inside] * w + xi[inside])
        zs.append(z[good][inside])
        cols.append(v.color[ok][good][inside])
    idx, z, col = np.concatenate(pts), np.concatenate(zs), np.concatenate(cols)
    order = np.lexsort((z, idx))  # by pixel, then nearest first
    idx, col = idx[order], col[order]
    first = np.unique(idx, return_index=True)[1]
    out = np.zeros((h * w, 3), np.float32)
    cov = np.zeros(h * w, bool)
    out[idx[first]] = col[first]
    cov[idx[first]] = True
    return out.reshape(h, w, 3), ~cov.reshape(h, w)


def run_case(scene, k, repeats, threads, space="linear"):
    """One case; ``space`` "srgb": the renderer's default blend space, so each input's sRGB encode
    (``dibr.srgb_encode``) is inside the timed job (every repeat, as for fresh inputs) and result()
    decodes in its resolve."""
    from ibrtools.dibr.method import srgb_encode

    srgb = space == "srgb"
    tgt = scene.targets[0]
    c0 = tgt.camera.centre
    views = sorted(scene.views, key=lambda v: float(np.linalg.norm(v.camera.centre - c0)))[:k]
    ins = [(np.ascontiguousarray(v.color), np.ascontiguousarray(v.depth), v.camera.to_core()) for v in views]
    _core.set_num_threads(threads)
    acc = _core.DibrAccumulator(tgt.camera.to_core())
    opts = _core.WarpOptions()
    runs = []
    load = os.getloadavg()[0]
    for r in range(repeats + 1):
        t0 = time.perf_counter()
        c0 = time.process_time()
        acc.reset()
        per, enc = [], []
        for c, d, cam in ins:
            if srgb:
                te = time.perf_counter()
                c = srgb_encode(c)
                enc.append((time.perf_counter() - te) * 1e3)
            acc.add_view(c, d, cam, opts)
            per.append(acc.last_add_ms)
        t1 = time.perf_counter()
        out = acc.result(srgb_to_linear=srgb)
        t2 = time.perf_counter()
        c2 = time.process_time()
        if r > 0:
            runs.append(((t2 - t0) * 1e3, statistics.mean(per), (t2 - t1) * 1e3, (c2 - c0) * 1e3,
                         statistics.mean(enc) if enc else 0.0))
    _core.set_num_threads(0)
    load = max(load, os.getloadavg()[0])
    total = statistics.median(x[0] for x in runs)
    total_min = min(x[0] for x in runs)
    cpu = statistics.median(x[3] for x in runs)
    warp = statistics.median(x[1] for x in runs)
    norm = statistics.median(x[2] for x in runs)
    encode = statistics.median(x[4] for x in runs)
    col, _, _, hole = out
    gt = tgt.color
    t = time.perf_counter()
    splat, splat_hole = naive_splat(views, tgt.camera)
    splat_ms = (time.perf_counter() - t) * 1e3
    both = ~hole & ~splat_hole
    return dict(total=total, total_min=total_min, cpu=cpu, load=load, warp=warp, norm=norm, encode=encode,
                psnr=psnr(col, gt), psnr_both=psnr(col, gt, both),
                holes=float(hole.mean()), splat_psnr=psnr(splat, gt), splat_psnr_both=psnr(splat, gt, both),
                splat_holes=float(splat_hole.mean()), splat_ms=splat_ms)


def run_renderer(scene, repeats, threads, fresh=False):
    """The renderer's frame (``ibr-render --method dibr``, dibr/method.py): view selection, a new
    accumulator, k = 4 add_view, result(); median stage times over --repeats frames after a warm-up.
    fresh: inputs new every frame (video, e.g. MPEG immersive video: a new DibrMethod per scene
    frame), so each frame also pays prepare() (the views' depth ranges) and the sRGB encode of the
    selected views (blend_space srgb; cached across frames otherwise), both inside the total."""
    from ibrtools.dibr.method import DibrMethod

    _core.set_num_threads(threads)
    m = DibrMethod({"inputs": 4})
    m.prepare(scene)
    cam = scene.targets[0].camera
    runs = []
    for r in range(repeats + 1):
        t0 = time.perf_counter()
        c0 = time.process_time()
        prep = 0.0
        if fresh:
            m = DibrMethod({"inputs": 4})
            m.prepare(scene)
            prep = (time.perf_counter() - t0) * 1e3
        _, st = m.render(cam)
        if r > 0:
            runs.append(((time.perf_counter() - t0) * 1e3, (time.process_time() - c0) * 1e3, dict(st, prepare=prep)))
    _core.set_num_threads(0)
    med = {k: statistics.median(x[2][k] for x in runs) for k in ("prepare", "select", "warp", "blend")}
    return dict(total=statistics.median(x[0] for x in runs), cpu=statistics.median(x[1] for x in runs), **med)


def run_encode(repeats):
    """The sRGB encode of one 1920x1080 RGB input view (blend_space srgb; paid once per view and
    frame with fresh inputs): ``dibr.srgb_encode`` (the table, _core.srgb_encode_unclipped) and the
    curve per value (``_core.metameric_encode`` after numpy's clamp at 0: the per-value
    encode), random values in [0, 1), 1 and 2 threads, interleaved; median ms."""
    from ibrtools.dibr.method import srgb_encode

    def curve(v):
        a = np.maximum(v, np.float32(0.0))
        return _core.metameric_encode(a.reshape(a.shape[0], -1, 1)).reshape(a.shape)

    img = np.random.default_rng(0).random((1080, 1920, 3), dtype=np.float32)
    times = {}
    for _ in range(max(repeats, 5)):
        for threads in (1, 2):
            _core.set_num_threads(threads)
            for name, f in (("table", srgb_encode), ("curve", curve)):
                t = time.perf_counter()
                f(img)
                times.setdefault((name, threads), []).append((time.perf_counter() - t) * 1e3)
    _core.set_num_threads(0)
    return {k: statistics.median(v) for k, v in times.items()}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="fewer cases (no 4K, no 1-thread runs)")
    ap.add_argument("--write-docs", action="store_true")
    ap.add_argument("--isa", default="auto", choices=("auto", "baseline", "avx2"),
                    help="instruction set of the warp's hot loops (_core.set_warp_isa; results are identical)")
    ap.add_argument("--blend-space", default=None, choices=("srgb", "linear"),
                    help="blend space of the timed job (default: the renderer's, dibr/method.py DibrParams)")
    a = ap.parse_args()
    from ibrtools.dibr.method import DibrParams

    space = a.blend_space or DibrParams.blend_space
    _core.set_warp_isa(a.isa)
    cases = [((1920, 1080), k) for k in (1, 2, 4, 8)]
    sizes = [(512, 512), (1024, 1024)] + ([] if a.quick else [(3840, 2160)])
    cases += [(s, 4) for s in sizes]
    scenes = {}
    rows = []
    for size, k in cases:
        if size not in scenes:
            scenes[size] = synth.make_scene("objects", size=size, views=8, holdout_targets=1)
        for threads in ((2,) if a.quick else (2, 1)):
            r = run_case(scenes[size], k, a.repeats, threads, space)
            rows.append((size, k, threads, r))
            print(f"{size[0]}x{size[1]} k={k} threads={threads}: total {r['total']:.1f} ms (min {r['total_min']:.1f}, "
                  f"CPU {r['cpu']:.1f} ms, load {r['load']:.1f}) "
                  f"(encode {r['encode']:.1f}, warp+acc {r['warp']:.1f} ms/view, normalise {r['norm']:.1f} ms); "
                  f"PSNR {r['psnr']:.2f} dB "
                  f"(both-covered {r['psnr_both']:.2f}), holes {100 * r['holes']:.2f} %; naive splat "
                  f"PSNR {r['splat_psnr']:.2f} (both-covered {r['splat_psnr_both']:.2f}), holes "
                  f"{100 * r['splat_holes']:.2f} %, {r['splat_ms']:.0f} ms (numpy)", flush=True)
    lines = [
        "## DIBR (forward mesh warp + blending)",
        "",
        f"`benchmarks/bench_dibr.py`, {machine()}; median of {a.repeats} runs after a warm-up. Scene: "
        "`synth.make_scene(\"objects\", views=8)` (textured planes, boxes, spheres), target half-way between "
        "two ring cameras, the k nearest inputs; the same size for inputs and target. Default options (RVS: "
        "quality 'side', T auto, combined depth test, weight (q/d)^5), blend space "
        f"{space}" + (" (the renderer's default: each input's sRGB encode, `dibr.srgb_encode`, is inside the "
                      "timed job, as for fresh inputs, and result() decodes in its resolve)" if space == "srgb" else "")
        + ". \"total\" is wall time from Python "
        "(reset, k × (encode +) add_view, result()), median and minimum; \"CPU\" is the process CPU time of the same "
        "frames (all threads, median): on a shared machine CPU time and the CPU / wall ratio (≈ 2 when both "
        "threads ran all the time) are the robust figures, wall time is what the load left of the cores; \"load\" "
        "is the larger 1-minute load average at the start and the end of the case (2 = both cores busy). "
        "\"warp\" is the kernel time per view (vertex projection with the "
        "colour's finiteness check, triangle binning, rasterisation, accumulation; the first view after "
        "reset() writes the sums, there is no clearing pass); \"encode\" the sRGB encode per view; \"normalise\" is "
        "result(). Naive splat: nearest-pixel point "
        "splat with a z-buffer over all inputs (numpy, in this script). PSNR against the rendered ground "
        "truth over all pixels, and over the pixels both methods cover. Instruction set of the warp's hot "
        f"loops: {_core.warp_isa()} (`_core.warp_isa()`; AVX2 clones when the CPU has it, bit-identical to "
        "the SSE2 baseline; docs/dibr.md, \"Speed\").",
        "",
        "| size | k | threads | total ms | min ms | CPU ms | load | encode ms/view | warp ms/view | normalise ms | PSNR dB "
        "| PSNR both | holes % | splat PSNR | splat PSNR both | splat holes % |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for size, k, th, r in rows:
        lines.append(f"| {size[0]}×{size[1]} | {k} | {th} | {r['total']:.1f} | {r['total_min']:.1f} | {r['cpu']:.1f} | "
                     f"{r['load']:.1f} | {r['encode']:.1f} | {r['warp']:.1f} | {r['norm']:.1f} | "
                     f"{r['psnr']:.2f} | {r['psnr_both']:.2f} | {100 * r['holes']:.2f} | {r['splat_psnr']:.2f} | "
                     f"{r['splat_psnr_both']:.2f} | {100 * r['splat_holes']:.2f} |")
    rr = run_renderer(scenes[(1920, 1080)], a.repeats, 2)
    lines += ["", f"The renderer's frame (`ibr-render --method dibr`, `DibrMethod.render`: view selection among the 8 "
              f"inputs, a new accumulator, 4 views, result(); the inputs' sRGB encodings from the cache), 1920×1080 on "
              f"2 threads, median of {a.repeats}: "
              f"{rr['total']:.1f} ms wall ({rr['cpu']:.1f} ms CPU): select {rr['select']:.1f}, warp "
              f"{rr['warp']:.1f}, blend {rr['blend']:.1f} ms."]
    rf = run_renderer(scenes[(1920, 1080)], a.repeats, 2, fresh=True)
    lines += ["", f"The same frame with fresh inputs (video: a new `DibrMethod` and `prepare()` per frame, so every "
              f"frame also pays the depth ranges of the 8 views and the sRGB encode of the 4 selected ones, "
              f"`dibr.srgb_encode`, which the frames above take from the cache), median of {a.repeats}: "
              f"{rf['total']:.1f} ms wall ({rf['cpu']:.1f} ms CPU): prepare {rf['prepare']:.1f}, select "
              f"{rf['select']:.1f}, warp with the encode {rf['warp']:.1f}, blend {rf['blend']:.1f} ms."]
    enc = run_encode(a.repeats)
    lines += ["", f"The sRGB encode of one 1920×1080 RGB input view (random values in [0, 1), median of "
              f"{max(a.repeats, 5)}, interleaved): `dibr.srgb_encode` (a table of the curve, "
              f"`_core.srgb_encode_unclipped`) {enc['table', 1]:.1f} ms on 1 thread, {enc['table', 2]:.1f} ms on 2; "
              f"the curve per value (`_core.metameric_encode`, the encode before) {enc['curve', 1]:.1f} / "
              f"{enc['curve', 2]:.1f} ms."]
    lines += ["", "Target: 4 × 1080p → 1080p in ≤ 100 ms on 2 cores (RVS 4.0: 5.0 s single-threaded)."]
    text = "\n".join(lines)
    print(text)
    if a.write_docs:
        write_section("bench_dibr", text)


if __name__ == "__main__":
    main()
