"""Interactive frame rate of ``ibr-view`` (docs/viewer.md): the server in this process, frames
asked over HTTP as the page asks them while the camera moves (JPEG) and when it stops (PNG).

    python benchmarks/bench_view.py [--frames 24] [--repeats 5] [--write-docs]

Scene: synth:objects, 12 views at 1280 x 720, prepared for dibr and hybrid (ibr-preprocess
--methods hybrid; made once under benchmarks/.cache). Poses: an orbit of ``--frames`` cameras
between the inputs. Per method and size: the median over the poses of the wall time from the
request to the last byte received (render + encode + HTTP), median of ``--repeats`` runs, and the
frames per second it gives; the render alone (X-Render-Ms) beside it.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import load_note, machine  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
CACHE = REPO / "benchmarks" / ".cache" / "view_objects_1280"
SIZES = ((640, 360), (1280, 720))


def scene():
    from ibrtools.pipeline import stages as S
    from ibrtools.formats import native

    S.preprocess("synth:objects", CACHE, synth={"preset": "objects", "size": [1280, 720], "views": 12, "seed": 0,
                                                "reconstructed": False}, methods=["dibr", "hybrid"])
    return native.load(CACHE)


def orbit(sc, n: int):
    from ibrtools.camera import Camera, look_at

    c0 = sc.views[0].camera
    centre = np.mean([v.camera.centre for v in sc.views], axis=0)
    r = float(np.mean([np.linalg.norm(v.camera.centre[[0, 2]] - centre[[0, 2]]) for v in sc.views]))
    h = float(np.mean([v.camera.centre[1] for v in sc.views]))
    cams = []
    for i in range(n):
        a = 2 * np.pi * (i + 0.5) / n
        eye = (centre[0] + r * np.cos(a), h, centre[2] + r * np.sin(a))
        cams.append(Camera.pinhole(c0.width, c0.height, c0.fx, c0.fy, c0.cx, c0.cy, look_at(eye, (0.0, 0.5, 0.0))))
    return cams


_SEQ = iter(range(1 << 62))  # the page's request numbers: always increasing (an older one is dropped)


def run(viewer, cams, method: str, size, fmt: str) -> tuple[float, float]:
    """(median request ms, median render ms) over the poses."""
    base = viewer.url.split("?")[0]
    wall, render = [], []
    for cam in cams:
        q = urllib.parse.urlencode({"t": viewer.token, "pose": json.dumps(cam.to_dict()), "w": size[0], "h": size[1],
                                    "method": method, "fmt": fmt, "client": "bench", "seq": next(_SEQ)})
        t0 = time.perf_counter()
        with urllib.request.urlopen(base + "frame?" + q, timeout=300) as r:
            r.read()
            render.append(float(r.headers["X-Render-Ms"]))
        wall.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(wall)), float(np.median(render))


def main() -> None:
    from ibrtools.viewer import Viewer

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--write-docs", action="store_true")
    a = ap.parse_args()
    sc = scene()
    cams = orbit(sc, a.frames)
    v = Viewer(sc, "dibr", port=0)
    t = threading.Thread(target=v.serve_forever, daemon=True)
    t.start()
    rows = []
    try:
        for method in ("dibr", "hybrid"):
            run(v, cams[:2], method, SIZES[0], "jpeg")  # warm-up: preparation, first-use costs
            for size in SIZES:
                for fmt in ("jpeg", "png"):
                    res = [run(v, cams, method, size, fmt) for _ in range(a.repeats)]
                    w = float(np.median([r[0] for r in res]))
                    rr = float(np.median([r[1] for r in res]))
                    rows.append((method, f"{size[0]}x{size[1]}", fmt, w, rr))
                    print(f"{method} {size} {fmt}: {w:.1f} ms ({1000 / w:.1f} fps), render {rr:.1f} ms", flush=True)
    finally:
        v.shutdown()
    lines = ["## Interactive frame rate", "",
             f"`ibr-view` frames over HTTP (request to last byte: render + encode + transfer) on {machine()}; "
             f"synth:objects 12 views 1280x720, an orbit of "
             f"{a.frames} poses between the inputs, median over the poses, median of {a.repeats} runs; measured by "
             "`benchmarks/bench_view.py`. The page asks JPEG frames at half size while the camera moves and a PNG "
             "frame at full size when it stops.", "",
             "| method | size | format | ms per frame | frames/s | render ms |", "|---|---|---|---|---|---|"]
    lines += [f"| {m} | {s} | {f} | {w:.1f} | {1000 / w:.1f} | {r:.1f} |" for m, s, f, w, r in rows]
    lines += ["", "Render ms includes the completion (background pass and hole filling; docs/render.md). "
              + load_note()]
    md = "\n".join(lines) + "\n"
    print(md)
    if a.write_docs:
        p = REPO / "docs" / "viewer.md"
        text = p.read_text()
        i = text.find("## Interactive frame rate")
        j = text.find("\n## ", i + 1) if i >= 0 else -1
        p.write_text((text[:i] if i >= 0 else text.rstrip() + "\n\n") + md + (text[j + 1:] if j >= 0 else ""))


if __name__ == "__main__":
    sys.exit(main())
