#!/usr/bin/env python3
"""Peak memory of each render method at 1080p and 4K (issue 9, item 4).

For each size: a synthetic scene (``ibr-preprocess synth:objects --views N``, made once under
--work), then ``/usr/bin/time -v ibr-render SCENE --method M --poses P`` with the first 3
cameras of the scene's ``orbit`` path, resized to the scene size. Reported: the peak resident
set size (VmHWM of the whole process: interpreter, libraries, inputs, frames), the wall time,
and the render job's own estimate (ibrtools.render.job.estimate_memory) that the early
refusal uses, which must stay above the measurement.

    .venv/bin/python tools/measure_memory.py                      # print the table
    .venv/bin/python tools/measure_memory.py --write-docs         # and update docs/robustness.md
    .venv/bin/python tools/measure_memory.py --sizes 1920x1080 --methods dibr,warp

Methods that need preprocessing stages (tm, ulr, pvm, hybrid) run those stages first
(``ibr-preprocess SCENE -o SCENE --methods M``), which takes minutes at these sizes.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
DOC = REPO / "docs" / "robustness.md"
SECTION = "peak-memory"
STAGED = ("tm", "ulr", "pvm", "hybrid")


def _time_v(argv: list[str]) -> tuple[int, float, int, str]:
    """(peak RSS bytes, wall seconds, exit code, stderr tail) of ``argv`` under /usr/bin/time -v."""
    p = subprocess.run(["/usr/bin/time", "-v"] + argv, capture_output=True, text=True)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", p.stderr)
    secs = 0.0
    if wall:
        for part in wall.group(1).split(":"):
            secs = secs * 60 + float(part)
    return (int(rss.group(1)) * 1024 if rss else 0), secs, p.returncode, p.stderr.strip()[-300:]


def _scene(work: Path, size: str, views: int) -> Path:
    d = work / f"objects_{size}_{views}"
    if not (d / "scene.json").is_file():
        subprocess.run([str(BIN / "ibr-preprocess"), "synth:objects", "-o", str(d), "--views", str(views),
                        "--size", size, "-q"], check=True)
    return d


def _poses(scene: Path, n: int) -> Path:
    doc = json.loads((scene / "scene.json").read_text())
    cams = [dict(c, name=f"p{i}") for i, c in enumerate(doc["paths"]["orbit"][:n])]
    f = scene / f"poses_{n}.json"
    f.write_text(json.dumps(cams))
    return f


def _estimate(scene: Path, poses: Path, method: str) -> int:
    from ibrtools.formats import native
    from ibrtools.render import job as render_job

    job = render_job.plan(native.load(scene), poses=str(poses))
    return render_job.estimate_memory(job, method)["total"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1920x1080,3840x2160")
    ap.add_argument("--methods", default="reference,dibr,warp,depthwarp")
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--work", default=str(Path(tempfile.gettempdir()) / "ibr-measure-memory"))
    ap.add_argument("--write-docs", action="store_true")
    a = ap.parse_args(argv)
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for size in a.sizes.split(","):
        scene = _scene(work, size, a.views)
        poses = _poses(scene, a.frames)
        base, _, _, _ = _time_v([sys.executable, "-c", "import ibrtools._core, ibrtools.render.methods, open3d"])
        for m in a.methods.split(","):
            if m in STAGED:
                subprocess.run([str(BIN / "ibr-preprocess"), str(scene), "-o", str(scene), "--methods", m, "-q"],
                               check=True)
            out = work / f"out_{size}_{m}"
            rss, secs, code, err = _time_v([str(BIN / "ibr-render"), str(scene), "--method", m, "--poses",
                                            str(poses), "-o", str(out), "-q", "-j", str(a.threads)])
            est = _estimate(scene, poses, m)
            rows.append((size, m, rss, secs, est, code, err, base))
            status = "ok" if code == 0 else f"exit {code}: {err.splitlines()[-1] if err else ''}"
            print(f"{size:>10} {m:<10} peak {rss / 2**20:8.0f} MiB  wall {secs:6.1f} s  estimate "
                  f"{est / 2**20:8.0f} MiB  ({status})", flush=True)
    mib = 2 ** 20
    lines = [f"Measured with `tools/measure_memory.py` ({a.views} input views, {a.frames} frames of the "
             f"`orbit` path at the scene size, -j {a.threads}; peak RSS of the whole `ibr-render` process "
             f"from `/usr/bin/time -v`; the interpreter with the engine, open3d and numpy loaded alone "
             f"peaks at {rows[0][7] / mib:.0f} MiB). *Estimate* is the render job's own figure used to "
             "refuse a job early; it must stay above the measurement.", "",
             "| size | method | peak RSS (MiB) | estimate (MiB) | wall (s) | result |",
             "|---|---|---:|---:|---:|---|"]
    for size, m, rss, secs, est, code, err, _ in rows:
        res = "ok" if code == 0 else f"exit {code}"
        lines.append(f"| {size} | {m} | {rss / mib:.0f} | {est / mib:.0f} | {secs:.1f} | {res} |")
    table = "\n".join(lines)
    print(table)
    if a.write_docs:
        sys.path.insert(0, str(REPO / "benchmarks"))
        from benchlib import write_section

        write_section(SECTION, table, DOC)
    return 0 if all(r[5] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
