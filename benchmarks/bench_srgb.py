"""sRGB encoding speed (ibrtools.imageio.linear_to_srgb, the C++ kernel _core.linear_to_srgb) vs
numpy (the same formula in float32, ibrtools' implementation before the kernel) and OpenImageIO's
ImageBufAlgo.colorconvert("linear", "sRGB"), same image, same run.

    python benchmarks/bench_srgb.py [--size 2048] [--repeats 7] [--write docs/benchmarks.md]

Every image written as 8 bits, every PSNR / SSIM / FLIP of ibrtools.metrics and every held-out
score of ibr-render encodes linear colour first, so this is on the output path of each frame.
Prints a Markdown table (median of --repeats runs each, after one warm-up) with each
implementation's largest absolute difference from the curve evaluated in float64; with --write,
replaces the "sRGB encoding" section of that file.
"""
from __future__ import annotations

import os
import sys

import numpy as np
from benchlib import load_note, machine, median_ms, size_repeats_main


def numpy_float32(v: np.ndarray) -> np.ndarray:
    v = np.clip(np.nan_to_num(np.asarray(v, dtype=np.float32), nan=0.0), 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * np.power(v, 1 / 2.4) - 0.055).astype(np.float32)


def float64_curve(v: np.ndarray) -> np.ndarray:
    v = np.clip(np.asarray(v, np.float64), 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def run(size: int, repeats: int) -> str:
    import OpenImageIO as oiio

    from ibrtools import _core
    from ibrtools.imageio import linear_to_srgb

    rng = np.random.default_rng(0)
    img = rng.random((size, size, 3), dtype=np.float32)
    want = float64_curve(img)
    cores = os.cpu_count() or 1
    buf = oiio.ImageBuf(img)

    def oiio_convert() -> np.ndarray:
        out = oiio.ImageBufAlgo.colorconvert(buf, "linear", "sRGB")
        if out.has_error:
            raise RuntimeError(out.geterror())
        return out.get_pixels(oiio.FLOAT).reshape(img.shape)

    rows = []
    times = {}
    for threads in (1, cores):
        _core.set_num_threads(threads)
        times[f"ours{threads}"] = median_ms(lambda: linear_to_srgb(img), repeats)
        oiio.attribute("threads", threads)
        times[f"oiio{threads}"] = median_ms(oiio_convert, repeats)
    _core.set_num_threads(0)
    oiio.attribute("threads", 0)
    times["numpy"] = median_ms(lambda: numpy_float32(img), repeats)
    err = {"ours": np.abs(linear_to_srgb(img) - want).max(), "numpy": np.abs(numpy_float32(img) - want).max(),
           "oiio": np.abs(oiio_convert() - want).max()}
    base = times["numpy"]
    for threads in (1, cores):
        t = "thread" if threads == 1 else "threads"
        rows.append(f"| ibrtools `linear_to_srgb`, {threads} {t} | {times[f'ours{threads}']:.1f} | "
                    f"{base / times[f'ours{threads}']:.1f}x | {times[f'oiio{threads}'] / times[f'ours{threads}']:.1f}x | "
                    f"{err['ours']:.1e} |")
        rows.append(f"| OpenImageIO {oiio.__version__} colorconvert linear -> sRGB, {threads} {t} | "
                    f"{times[f'oiio{threads}']:.1f} | {base / times[f'oiio{threads}']:.1f}x | 1.0x | {err['oiio']:.1e} |")
    rows.append(f"| numpy {np.__version__} float32 formula (ibrtools before the kernel), 1 thread | {base:.1f} | "
                f"1.0x | | {err['numpy']:.1e} |")
    head = [
        "## sRGB encoding",
        "",
        f"Linear float32 RGB {size}x{size} (uniform random in [0, 1)) to its sRGB encoding (IEC 61966-2-1), "
        f"median of {repeats} runs after a warm-up, measured by `benchmarks/bench_srgb.py` on {machine()}. "
        "Speed-ups are numpy's and OpenImageIO's time (same thread count) over the row's, in the same run; "
        "'max abs diff' is the largest |result - the curve in float64|.",
        "",
        "| implementation | time (ms) | vs numpy | vs OpenImageIO | max abs diff |",
        "|---|---:|---:|---:|---:|",
    ]
    return "\n".join(head + rows + ["", load_note()]) + "\n"


def main(argv=None) -> int:
    return size_repeats_main(__doc__, "sRGB encoding", run, argv, min_size=1)


if __name__ == "__main__":
    sys.exit(main())
