"""Import of a phone capture (docs/benchmarks.md "Import"): N photos of W x H as JPEG in
instant-ngp's layout (``images/NNNN.jpg``, one ``transforms.json``), imported by
``ibr-preprocess`` (import stage only) at full size and with ``--max-size``; wall time of the
import stage (median of the runs, each forced), the scene's size on disk, and the ratio.

    python benchmarks/bench_import.py [--views 50] [--size 1080x1920] [--max-size 960] [--repeats 3] [--write-docs]
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import machine, write_section  # noqa: E402


def make_capture(root: Path, n: int, w: int, h: int) -> None:
    """Photos with texture at every scale (a smooth gradient, edges, noise), so that the JPEGs are
    of a phone photo's size and the decoder, the filter and the PNG encoder see real work."""
    from ibrtools.imageio import write_image

    (root / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.linspace(0, 1, w, dtype=np.float32), np.linspace(0, 1, h, dtype=np.float32))
    frames = []
    for i in range(n):
        img = np.stack([u, v, 0.5 * (u + v)], -1) * 0.6 + 0.2
        img += 0.15 * (np.sin(40 * u + i) * np.cos(30 * v) > 0)[..., None]
        img += rng.normal(0, 0.03, img.shape).astype(np.float32)
        write_image(root / "images" / f"{i:04d}.jpg", np.clip(img, 0, 1))
        c2w = np.eye(4)
        c2w[0, 3] = 0.05 * i
        frames.append({"file_path": f"./images/{i:04d}.jpg", "transform_matrix": c2w.tolist()})
    doc = {"fl_x": 0.8 * max(w, h), "fl_y": 0.8 * max(w, h), "cx": w / 2, "cy": h / 2, "w": w, "h": h,
           "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "frames": frames}
    (root / "transforms.json").write_text(json.dumps(doc))


def import_seconds(src: Path, out: Path, repeats: int, **kw) -> tuple[float, float]:
    from ibrtools.pipeline.stages import preprocess

    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        preprocess(str(src), out, stages=[], force=True, **kw)
        times.append(time.perf_counter() - t)
    mb = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6
    return statistics.median(times), mb


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", type=int, default=50)
    ap.add_argument("--size", default="1080x1920", help="WxH of the photos")
    ap.add_argument("--max-size", type=int, default=960)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write-docs", action="store_true")
    args = ap.parse_args()
    w, h = (int(x) for x in args.size.split("x"))
    load_before = os.getloadavg()[0]
    tmp = Path(tempfile.mkdtemp(prefix="bench-import-"))
    try:
        make_capture(tmp / "capture", args.views, w, h)
        jpeg_mb = sum(p.stat().st_size for p in (tmp / "capture").rglob("*.jpg")) / 1e6
        full_s, full_mb = import_seconds(tmp / "capture", tmp / "full", args.repeats)
        small_s, small_mb = import_seconds(tmp / "capture", tmp / "small", args.repeats, max_size=args.max_size)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    load = f"load average {load_before:.1f} before, {os.getloadavg()[0]:.1f} after (other jobs share the cores)"
    rows = [f"| full size ({w}x{h}) | {full_s:.1f} s | {full_mb:.0f} MB |",
            f"| `--max-size {args.max_size}` | {small_s:.1f} s | {small_mb:.0f} MB |"]
    table = "\n".join(["| import | time (median of %d) | scene on disk |" % args.repeats, "|---|---|---|", *rows])
    print(table)
    print(f"speed-up {full_s / small_s:.1f}x; input JPEGs {jpeg_mb:.0f} MB; {load}")
    if args.write_docs:
        write_section("import", "\n".join([
            "## Import of a phone capture (bench_import.py)",
            "",
            f"{args.views} JPEG photos of {w}x{h} in instant-ngp's layout ({jpeg_mb:.0f} MB), the import stage "
            f"alone (`ibr-preprocess CAPTURE -o SCENE`, forced), {machine()}, {load}:",
            "",
            table,
            "",
            f"`--max-size {args.max_size}`: {full_s / small_s:.1f}x faster (every photo is still decoded at full "
            "size; the area filter, the sRGB encoding and the PNG encoder see a quarter of the pixels). "
            "What is left is mostly OpenImageIO's PNG encoder (~0.13-0.18 s per 540x960 image, ~70 % of the "
            "import; the native format's bytes are kept, so its compression level is not changed here).",
            "Reproduce: `python benchmarks/bench_import.py --write-docs`.",
        ]))


if __name__ == "__main__":
    main()
