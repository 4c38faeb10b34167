"""sRGB encoding and decoding speed (ibrtools.imageio.linear_to_srgb / srgb_to_linear, the C++
kernels _core.linear_to_srgb / srgb_to_linear) vs numpy (the same formulas in float32, ibrtools'
implementation before the kernels) and OpenImageIO's ImageBufAlgo.colorconvert("linear", "sRGB")
and back, same image, same run.

    python benchmarks/bench_srgb.py [--size 2048] [--repeats 7] [--write docs/benchmarks.md]

Every image written as 8 bits, every PSNR / SSIM / FLIP of ibrtools.metrics and every held-out
score of ibr-render encodes linear colour first, so this is on the output path of each frame;
every 8-bit image read (importers) is decoded.
Prints a Markdown table (median of --repeats runs each, after one warm-up) with each
implementation's largest absolute difference from the curve evaluated in float64; with --write,
replaces the "sRGB encoding" section of that file.
"""
from __future__ import annotations

import os
import sys

import numpy as np
from benchlib import load_note, machine, median_ms, size_repeats_main


def numpy_encode(v: np.ndarray) -> np.ndarray:
    v = np.clip(np.nan_to_num(np.asarray(v, dtype=np.float32), nan=0.0), 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * np.power(v, 1 / 2.4) - 0.055).astype(np.float32)


def numpy_decode(e: np.ndarray) -> np.ndarray:
    e = np.asarray(e, dtype=np.float32)
    return np.where(e <= 0.04045, e / 12.92, ((e + 0.055) / 1.055) ** 2.4).astype(np.float32)


def encode64(v: np.ndarray) -> np.ndarray:
    v = np.clip(np.asarray(v, np.float64), 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def decode64(e: np.ndarray) -> np.ndarray:
    e = np.asarray(e, np.float64)
    return np.where(e <= 0.04045, e / 12.92, ((e + 0.055) / 1.055) ** 2.4)


def run(size: int, repeats: int) -> str:
    import OpenImageIO as oiio

    from ibrtools import _core
    from ibrtools.imageio import linear_to_srgb, srgb_to_linear

    img = np.random.default_rng(0).random((size, size, 3), dtype=np.float32)
    cores = os.cpu_count() or 1
    buf = oiio.ImageBuf(img)

    def oiio_convert(src: str, dst: str):
        def call() -> np.ndarray:
            out = oiio.ImageBufAlgo.colorconvert(buf, src, dst)
            if out.has_error:
                raise RuntimeError(out.geterror())
            return out.get_pixels(oiio.FLOAT).reshape(img.shape)
        return call

    rows = []
    for what, ours, numpy_fn, peer, exact in (
            ("encode", linear_to_srgb, numpy_encode, oiio_convert("linear", "sRGB"), encode64),
            ("decode", srgb_to_linear, numpy_decode, oiio_convert("sRGB", "linear"), decode64)):
        want = exact(img)
        times = {}
        for threads in (1, cores):
            _core.set_num_threads(threads)
            times[f"ours{threads}"] = median_ms(lambda: ours(img), repeats)
            oiio.attribute("threads", threads)
            times[f"oiio{threads}"] = median_ms(peer, repeats)
        _core.set_num_threads(0)
        oiio.attribute("threads", 0)
        times["numpy"] = median_ms(lambda: numpy_fn(img), repeats)
        err = {"ours": np.abs(ours(img) - want).max(), "numpy": np.abs(numpy_fn(img) - want).max(),
               "oiio": np.abs(peer() - want).max()}
        base = times["numpy"]
        name = {"encode": ("`linear_to_srgb`", "linear -> sRGB"), "decode": ("`srgb_to_linear`", "sRGB -> linear")}[what]
        for threads in (1, cores):
            t = "thread" if threads == 1 else "threads"
            rows.append(f"| {what} | ibrtools {name[0]}, {threads} {t} | {times[f'ours{threads}']:.1f} | "
                        f"{base / times[f'ours{threads}']:.1f}x | "
                        f"{times[f'oiio{threads}'] / times[f'ours{threads}']:.1f}x | {err['ours']:.1e} |")
            rows.append(f"| {what} | OpenImageIO {oiio.__version__} colorconvert {name[1]}, {threads} {t} | "
                        f"{times[f'oiio{threads}']:.1f} | {base / times[f'oiio{threads}']:.1f}x | 1.0x | "
                        f"{err['oiio']:.1e} |")
        rows.append(f"| {what} | numpy {np.__version__} float32 formula (ibrtools before the kernels), 1 thread | "
                    f"{base:.1f} | 1.0x | | {err['numpy']:.1e} |")
    head = [
        "## sRGB encoding and decoding",
        "",
        f"Float32 RGB {size}x{size} (uniform random in [0, 1)) through the sRGB curve (IEC 61966-2-1) "
        f"each way, median of {repeats} runs after a warm-up, measured by `benchmarks/bench_srgb.py` on "
        f"{machine()}. Speed-ups are numpy's and OpenImageIO's time (same thread count) over the row's, in the "
        "same run; 'max abs diff' is the largest |result - the curve in float64|.",
        "",
        "| way | implementation | time (ms) | vs numpy | vs OpenImageIO | max abs diff |",
        "|---|---|---:|---:|---:|---:|",
    ]
    return "\n".join(head + rows + ["", load_note()]) + "\n"


def main(argv=None) -> int:
    return size_repeats_main(__doc__, "sRGB encoding", run, argv, min_size=1)


if __name__ == "__main__":
    sys.exit(main())
