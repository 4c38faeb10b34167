"""Steerable pyramid speed at 1024^2 RGB, 4 levels, 2 orientations: ibrtools' small-filter pyramid
(analysis + synthesis, YCbCr) vs pyrtools' SteerablePyramidSpace (order 1: build + recon_pyr) and
SteerablePyramidFreq (order 1), same run, with each one's reconstruction error.

    python benchmarks/bench_steerable.py [--size 1024] [--repeats 7] [--write [docs/benchmarks.md]]

Image: scikit-image's astronaut (512^2) up-sampled to --size (bilinear), linear values in [0, 1].
pyrtools pyramids are single-channel: they get the three YCbCr channels one after the other
(the colour conversion is done outside the timed call for them; ours converts inside). Error:
|image - synthesise(analyse(image))| per channel, in YCbCr, interior (> 16 px from an edge) and
border, the largest over the channels (the figures of docs/steerable.md).
"""
from __future__ import annotations

import os
import sys

import numpy as np
from benchlib import load_note, machine, median_ms, size_repeats_main

RGB_TO_YCC = np.array([[0.299, 0.587, 0.114], [-0.168736, -0.331264, 0.5], [0.5, -0.418688, -0.081312]])
BORDER = 16


def test_image(size: int) -> np.ndarray:
    from skimage import data, transform

    rgb = data.astronaut().astype(np.float64) / 255.0
    if rgb.shape[0] != size:
        rgb = transform.resize(rgb, (size, size), order=1, anti_aliasing=False)
    return np.ascontiguousarray(rgb, dtype=np.float32)


def errors(ycc: np.ndarray, rec: np.ndarray) -> dict[str, float]:
    d = np.abs(rec.astype(np.float64) - ycc)
    mask = np.ones(d.shape[:2], bool)
    mask[BORDER:-BORDER, BORDER:-BORDER] = False
    inner, edge = d[~mask], d[mask]
    return {"interior_max": float(inner.max()), "interior_rms": float(np.sqrt((inner ** 2).mean(0)).max()),
            "border_max": float(edge.max())}


def run(size: int, repeats: int, levels: int = 4) -> str:
    import pyrtools as pt

    from ibrtools import _core
    from ibrtools.metamers.steerable import analyse, synthesise

    rgb = test_image(size)
    ycc = (rgb.astype(np.float64) @ RGB_TO_YCC.T).astype(np.float32)
    ycc64 = ycc.astype(np.float64)

    def ours():
        return synthesise(analyse(rgb, levels, 2, ycbcr=True))

    def ours_analyse():
        return analyse(rgb, levels, 2, ycbcr=True)

    def space():
        return np.stack([pt.pyramids.SteerablePyramidSpace(ycc64[..., c], height=levels, order=1).recon_pyr()
                         for c in range(3)], axis=2)

    def freq():
        return np.stack([pt.pyramids.SteerablePyramidFreq(ycc64[..., c], height=levels, order=1).recon_pyr()
                         for c in range(3)], axis=2)

    threads_list = sorted({1, os.cpu_count() or 1})
    rows_time = {}
    for threads in threads_list:
        _core.set_num_threads(threads)
        t = f"{threads} thread{'s' if threads > 1 else ''}"
        total = median_ms(ours, repeats)
        an = median_ms(ours_analyse, repeats)
        rows_time[f"ibrtools 5x5, analysis + synthesis, {t}"] = (total, an)
    _core.set_num_threads(0)
    t_space = median_ms(space, repeats)
    t_freq = median_ms(freq, repeats)
    # Errors (in YCbCr): ours through the YCbCr-space result of the RGB pipeline.
    ours_ycc = ours().astype(np.float64) @ RGB_TO_YCC.T
    err = {"ours": errors(ycc64, ours_ycc), "space": errors(ycc64, space()), "freq": errors(ycc64, freq())}
    fmt = lambda e: f"{e['interior_max']:.4f} / {e['interior_rms']:.4f} | {e['border_max']:.4f}"  # noqa: E731
    rows = []
    for name, (total, an) in rows_time.items():
        rows.append(f"| {name} | {an:.1f} | {total:.1f} | {t_space / total:.1f}x | {t_freq / total:.1f}x | "
                    f"{fmt(err['ours'])} |")
    rows.append(f"| pyrtools {pt.__version__} SteerablePyramidSpace (order 1, 9x9/17x17 taps), build + recon_pyr "
                f"| | {t_space:.1f} | 1.0x | {t_freq / t_space:.1f}x | {fmt(err['space'])} |")
    rows.append(f"| pyrtools {pt.__version__} SteerablePyramidFreq (order 1), build + recon_pyr "
                f"| | {t_freq:.1f} | {t_space / t_freq:.1f}x | 1.0x | {fmt(err['freq'])} |")
    head = [
        "## Steerable pyramid",
        "",
        f"Analysis + synthesis of a {size}x{size} RGB image (scikit-image astronaut, up-sampled), {levels} levels, "
        f"2 orientations, median of {repeats} runs after a warm-up, measured by `benchmarks/bench_steerable.py` on "
        f"{machine()}. Ours converts RGB to YCbCr and back inside the timed call; pyrtools (single-channel, "
        "numpy/C, single-threaded) gets the three YCbCr channels in float64, one pyramid each. Speed-ups are the "
        "peer's time over the row's, same run (target: >= 10x SteerablePyramidSpace). Reconstruction error "
        f"|x - synthesise(analyse(x))| in YCbCr (values in [0, 1]): interior (> {BORDER} px from an edge) max / "
        "rms and border max, largest over the channels.",
        "",
        "| implementation | analysis (ms) | analysis + synthesis (ms) | vs Space | vs Freq | interior max / rms | "
        "border max |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    tail = ["", load_note()]
    return "\n".join(head + rows + tail) + "\n"


def main(argv=None) -> int:
    return size_repeats_main(__doc__, "bench_steerable", run, argv, min_size=64)


if __name__ == "__main__":
    sys.exit(main())
