"""Hole-filling speed at 1024^2 RGB with 10 % holes: ibrtools push-pull (classic and depth-aware)
vs OpenImageIO's ImageBufAlgo.fillholes_pushpull and OpenCV's cv2.inpaint (TELEA), same run.

    python benchmarks/bench_inpaint.py [--size 1024] [--repeats 7] [--write docs/benchmarks.md]

The frame: a smooth colour texture with fine noise on a receding background plane (depth 5..8)
and foreground discs (depth 2); holes are discs of radius 2-12 px placed at random until 10 % of
the pixels are holes, with background depth inside (what a warper writes into disocclusions).
Each peer gets the input in its own format, converted outside the timed call: OIIO an RGBA float
ImageBuf with alpha 0 in holes (its hole convention), OpenCV 8-bit BGR + 8-bit mask (TELEA takes
8-bit colour only), radius 3. Median of --repeats runs after a warm-up. 'MAE in holes' is the mean
absolute error against the unholed frame (information only: the methods aim at different things).
"""
from __future__ import annotations

import os
import sys

import numpy as np
from benchlib import load_note, machine, median_ms, size_repeats_main


def frame(size: int, hole_fraction: float = 0.10, seed: int = 0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size].astype(np.float32) / size
    img = np.stack([0.5 + 0.3 * np.sin(9 * xx + 3 * yy), 0.5 + 0.3 * np.cos(7 * yy - 2 * xx),
                    0.4 + 0.2 * np.sin(13 * (xx + yy))], axis=2)
    img += 0.05 * rng.standard_normal(img.shape)
    depth = 5.0 + 3.0 * yy
    for _ in range(12):
        cy, cx, r = rng.random() * size, rng.random() * size, 20 + rng.random() * 80
        disc = (np.mgrid[:size, :size][0] - cy) ** 2 + (np.mgrid[:size, :size][1] - cx) ** 2 < r * r
        img[disc] = rng.random(3)
        depth[disc] = 2.0
    hole = np.zeros((size, size), bool)
    gy, gx = np.ogrid[:size, :size]
    while hole.mean() < hole_fraction:
        cy, cx, r = rng.integers(size), rng.integers(size), rng.integers(2, 13)
        y0, y1, x0, x1 = max(0, cy - r), min(size, cy + r + 1), max(0, cx - r), min(size, cx + r + 1)
        hole[y0:y1, x0:x1] |= (gy[y0:y1] - cy) ** 2 + (gx[:, x0:x1] - cx) ** 2 <= r * r
    depth = np.where(hole, 5.0 + 3.0 * yy, depth)  # background depth in the holes
    return np.clip(img, 0, 1).astype(np.float32), hole, depth.astype(np.float32)


def run(size: int, repeats: int) -> str:
    import cv2
    import OpenImageIO as oiio

    from ibrtools import _core
    from ibrtools.inpaint.pushpull import pushpull

    img, hole, depth = frame(size)
    truth = img.copy()
    img = np.where(hole[..., None], 0.0, img).astype(np.float32)

    rgba = np.concatenate([img, (~hole).astype(np.float32)[..., None]], axis=2)
    buf = oiio.ImageBuf(oiio.ImageSpec(size, size, 4, oiio.FLOAT))
    buf.set_pixels(oiio.ROI(), rgba)
    bgr8 = np.ascontiguousarray((img[..., ::-1] * 255 + 0.5).astype(np.uint8))
    mask8 = hole.astype(np.uint8) * 255

    def oiio_fill():
        return oiio.ImageBufAlgo.fillholes_pushpull(buf)

    def cv_fill():
        return cv2.inpaint(bgr8, mask8, 3, cv2.INPAINT_TELEA)

    def mae(out):
        return float(np.abs(out[hole] - truth[hole]).mean())

    cases = []
    threads_list = sorted({1, os.cpu_count() or 1})
    for threads in threads_list:
        _core.set_num_threads(threads)
        cv2.setNumThreads(threads)
        t = f"{threads} thread{'s' if threads > 1 else ''}"
        cases.append((f"ibrtools push-pull, classic, {t}", lambda: pushpull(img, hole), threads))
        cases.append((f"ibrtools push-pull, depth-aware (Alg. 1), {t}", lambda: pushpull(img, hole, depth), threads))
        cases.append((f"OpenImageIO {oiio.__version__} fillholes_pushpull, {t}",
                      lambda th=threads: oiio.ImageBufAlgo.fillholes_pushpull(buf, nthreads=th), threads))
        cases.append((f"OpenCV {cv2.__version__} inpaint TELEA r=3 (8-bit), {t}", cv_fill, threads))
    times = {}
    for name, fn, threads in cases:
        _core.set_num_threads(threads)
        cv2.setNumThreads(threads)
        times[name] = median_ms(fn, repeats)
    _core.set_num_threads(0)
    errs = {"classic": mae(pushpull(img, hole)), "depth": mae(pushpull(img, hole, depth)),
            "oiio": mae(oiio_fill().get_pixels(oiio.FLOAT)[..., :3]),
            "cv": mae(cv_fill()[..., ::-1].astype(np.float32) / 255)}
    rows = []
    for threads in threads_list:
        t = f"{threads} thread{'s' if threads > 1 else ''}"
        names = [n for n, _, th in cases if th == threads]
        peer_o, peer_c = times[names[2]], times[names[3]]
        for name, key in zip(names, ("classic", "depth", "oiio", "cv")):
            ms = times[name]
            rows.append(f"| {name} | {ms:.2f} | {peer_o / ms:.1f}x | {peer_c / ms:.1f}x | {errs[key]:.4f} |")
    head = [
        "## Inpainting",
        "",
        f"Hole filling of a {size}x{size} RGB frame with {100 * hole.mean():.1f} % holes (discs of radius 2-12 px; "
        "foreground discs at depth 2 over a background plane at depth 5-8, background depth in the holes), "
        f"median of {repeats} runs after a warm-up, measured by `benchmarks/bench_inpaint.py` on {machine()}. "
        "Speed-ups are the peer's time over the row's, in the same run (target: ours >= 5x both peers). "
        "Peers get their input in their own format, converted outside the timed call.",
        "",
        "| implementation | time (ms) | vs OIIO | vs OpenCV | MAE in holes |",
        "|---|---:|---:|---:|---:|",
    ]
    tail = ["", load_note()]
    return "\n".join(head + rows + tail) + "\n"


def main(argv=None) -> int:
    return size_repeats_main(__doc__, "bench_inpaint", run, argv, min_size=32)


if __name__ == "__main__":
    sys.exit(main())
