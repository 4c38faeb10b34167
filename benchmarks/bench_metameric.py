"""Metameric inpainting speed at 1024^2 RGB with ~10 % holes: ibrtools.inpaint.metameric (depth-aware and
classic moments) vs ibrtools push-pull and OpenCV's cv2.inpaint (TELEA), same run.

    python benchmarks/bench_metameric.py [--size 1024] [--repeats 7] [--write docs/benchmarks.md | --write-docs]

--write-docs is --write with its default file (docs/benchmarks.md, section "bench_metameric").

The frame is bench_inpaint's (smooth colour texture with fine noise on a background plane at depth
5-8, foreground discs at depth 2, hole discs of radius 2-12 px until 10 % of the pixels are holes,
background depth inside them). Median of --repeats runs after a warm-up (the warm-up also builds the
cached noise pyramid, which depends only on size and seed; its one-off cost is reported apart).
A stage breakdown of one depth-aware call (median over the same repeats) says where the time goes.
'MAE in holes' is the mean absolute error against the unholed frame (information only: metameric
synthesises texture with the surroundings' statistics, it does not aim at the lowest MAE).
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np
from bench_inpaint import frame
from benchlib import load_note, machine, median_ms, size_repeats_main


def _stages(img, hole, depth, repeats: int) -> dict[str, float]:
    """Median time of each stage of metameric() (the same calls, timed one by one)."""
    from ibrtools import _core
    from ibrtools.inpaint import metameric as mm
    from ibrtools.metamers.steerable import SteerablePyramid, analyse, synthesise

    acc: dict[str, list[float]] = {}

    def tick(name, t0):
        acc.setdefault(name, []).append((time.perf_counter() - t0) * 1e3)
        return time.perf_counter()

    h, w = hole.shape
    n_hp, n_bands, _ = mm._noise_pyramid_cached(h, w, 3, 4, 2, 0)
    for _ in range(repeats + 1):
        t = time.perf_counter()
        xs = _core.metameric_encode(img)
        t = tick("display encoding (C++ sRGB curve, whole frame)", t)
        filled, _ = _core.pushpull(xs, hole, depth, 0.04, 0.5, xs, True)
        t = tick("pre-fill push-pull (RGB, in place into the encoded copy)", t)
        pyr = analyse(filled, 4, 2)
        t = tick("steerable analysis", t)
        masks, _ = mm.level_masks(hole, 4)
        t = tick("level masks (numpy)", t)
        for lv in range(4):
            bands = ([pyr.highpass] if lv == 0 else []) + pyr.bands[lv]
            noise = ([n_hp] if lv == 0 else []) + list(n_bands[lv])
            s = 1 << lv
            mask = mm._level_mask(masks[lv], hole, s)
            _core.metameric_pushpull_change(bands, mask.view(np.uint8), np.ascontiguousarray(depth[::s, ::s]),
                                            0.04, 0.5, noise, None, s)
        t = tick("moments push-pull fused with sigma * noise (X, X^2 of the high-pass and 8 bands; "
                 "C++ metameric_pushpull_change, 4 levels)", t)
        pyr.lowpass[...] = 0.0
        change = synthesise(SteerablePyramid(pyr.highpass, pyr.bands, pyr.lowpass))
        t = tick("steerable synthesis (of the change)", t)
        _core.metameric_fill_holes(img, hole, filled, change, True, change)
        tick("decode + copy into the holes (C++ metameric_fill_holes)", t)
    return {k: float(np.median(v[1:])) for k, v in acc.items()}


def run(size: int, repeats: int) -> str:
    import cv2

    from ibrtools import _core
    from ibrtools.inpaint.pushpull import pushpull
    from ibrtools.inpaint.metameric import _noise_pyramid_cached, metameric

    img, hole, depth = frame(size)
    truth = img.copy()
    img = np.where(hole[..., None], 0.0, img).astype(np.float32)
    bgr8 = (np.clip(img[..., ::-1], 0, 1) * 255 + 0.5).astype(np.uint8)
    mask8 = hole.astype(np.uint8) * 255

    _noise_pyramid_cached.cache_clear()
    t = time.perf_counter()
    metameric(img, hole, depth)
    first_ms = (time.perf_counter() - t) * 1e3

    def mae(out):
        return float(np.abs(out[hole] - truth[hole]).mean())

    threads_list = sorted({1, os.cpu_count() or 1}, reverse=True)
    cases = []
    for threads in threads_list:
        t = f"{threads} thread{'s' if threads > 1 else ''}"
        cases += [(f"ibrtools metameric, depth-aware moments, {t}", lambda: metameric(img, hole, depth), threads, "md"),
                  (f"ibrtools metameric, classic moments, {t}", lambda: metameric(img, hole), threads, "mc"),
                  (f"ibrtools push-pull, depth-aware (Alg. 1), {t}", lambda: pushpull(img, hole, depth), threads, "pd"),
                  (f"OpenCV {cv2.__version__} inpaint TELEA r=3 (8-bit), {t}",
                   lambda: cv2.inpaint(bgr8, mask8, 3, cv2.INPAINT_TELEA), threads, "cv")]
    times = {}
    for name, fn, threads, _ in cases:
        _core.set_num_threads(threads)
        cv2.setNumThreads(threads)
        times[name] = median_ms(fn, repeats)
    _core.set_num_threads(threads_list[0])
    stages = _stages(img, hole, depth, repeats)
    _core.set_num_threads(0)
    errs = {"md": mae(metameric(img, hole, depth)), "mc": mae(metameric(img, hole)),
            "pd": mae(pushpull(img, hole, depth)),
            "cv": mae(cv2.inpaint(bgr8, mask8, 3, cv2.INPAINT_TELEA)[..., ::-1].astype(np.float32) / 255)}
    rows = []
    for threads in threads_list:
        names = [(n, key) for n, _, th, key in cases if th == threads]
        peer = times[names[3][0]]
        for name, key in names:
            ms = times[name]
            rows.append(f"| {name} | {ms:.1f} | {peer / ms:.2f}x | {errs[key]:.4f} |")
    stage_rows = [f"| {k} | {v:.1f} |" for k, v in stages.items()]
    best = times[cases[0][0]]
    head = [
        "## Metameric inpainting",
        "",
        f"Metameric inpainting (`ibrtools.inpaint.metameric`, 4 levels, 2 orientations) of a {size}x{size} RGB warped "
        f"frame with {100 * hole.mean():.1f} % holes (bench_inpaint's frame: hole discs of radius 2-12 px, "
        "background depth in the holes), median of "
        f"{repeats} runs after a warm-up, measured by `benchmarks/bench_metameric.py` on {machine()}. "
        "'vs TELEA' is OpenCV's time over the row's, same run. Target: metameric <= 60 ms "
        f"(dos Anjos et al.: 17.9 ms on an RTX 2070). Measured: {best:.0f} ms on "
        f"{threads_list[0]} thread{'s' if threads_list[0] > 1 else ''}"
        + (" - the target is met." if best <= 60 else f" - the target is missed by {best / 60:.2f}x."),
        "",
        "The fill's mean is the push-pull pre-fill and RGB is synthesised on display (sRGB-encoded) values "
        "(docs/inpaint_quality.md), which adds a whole-frame encoding pass.",
        "",
        "| implementation | time (ms) | vs TELEA | MAE in holes |",
        "|---|---:|---:|---:|",
    ]
    mid = ["", f"First call (builds and caches the unit-variance noise pyramid for this size and seed): "
           f"{first_ms:.0f} ms. Stage breakdown of one depth-aware call "
           f"({threads_list[0]} thread{'s' if threads_list[0] > 1 else ''}; the remainder of the total is the "
           "depth sub-sampling per level, mask fall-backs and Python overhead):", "",
           "| stage | time (ms) |", "|---|---:|"]
    tail = ["", load_note()]
    return "\n".join(head + rows + mid + stage_rows + tail) + "\n"


def main(argv=None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    args = ["--write" if a == "--write-docs" else a for a in args]
    return size_repeats_main(__doc__, "bench_metameric", run, args, min_size=32)


if __name__ == "__main__":
    sys.exit(main())
