#!/usr/bin/env python3
"""Peak memory of each render method at 1080p and 4K.

For each size: a synthetic scene (``ibr-preprocess synth:objects --views N``, made once under
--work), then ``/usr/bin/time -v ibr-render SCENE --method M --poses P`` with the first 3
cameras of the scene's ``orbit`` path, resized to the scene size. Reported: the peak resident
set size (VmHWM of the whole process: interpreter, libraries, inputs, frames), the wall time,
and the render job's own estimate (ibrtools.pipeline.plan.estimate_memory) that the early
refusal uses, which must stay above the measurement.

    .venv/bin/python tools/measure_memory.py                      # print the table
    .venv/bin/python tools/measure_memory.py --write-docs         # and update docs/robustness.md
    .venv/bin/python tools/measure_memory.py --sizes 1920x1080 --methods dibr,warp

Methods that need preprocessing stages (tm, ulr, pvm, hybrid) run those stages first
(``ibr-preprocess SCENE -o SCENE --methods M``), which takes minutes at these sizes; they use
their own, smaller scene (``--staged-views``, default 4: the stages at 4K with 8 views did not fit
the time) and the table says how many views each row used (the estimate is per input pixel, so a
row with fewer views still checks the per-pixel figures).

``--write-docs`` replaces the rows of the (size, method) pairs measured in this run and keeps
the other rows of the table in docs/robustness.md, so methods can be measured separately:

    .venv/bin/python tools/measure_memory.py --methods tm,ulr,pvm,hybrid --write-docs
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


def _scene(work: Path, size: str, views: int, staged: bool = False, threads: int = 2) -> Path:
    """The synthetic scene (made once); ``staged``: with the stages of tm, ulr, pvm and hybrid."""
    d = work / f"objects_{size}_{views}{'_staged' if staged else ''}"
    argv = [str(BIN / "ibr-preprocess"), "synth:objects", "-o", str(d), "--views", str(views), "--size", size,
            "-q", "-j", str(threads)]
    if staged:
        argv += ["--methods", ",".join(STAGED)]
    if not (d / "scene.json").is_file() or staged:  # the stages are skipped when up to date
        subprocess.run(argv, check=True)
    return d


def _poses(scene: Path, n: int) -> Path:
    doc = json.loads((scene / "scene.json").read_text())
    cams = [dict(c, name=f"p{i}") for i, c in enumerate(doc["paths"]["orbit"][:n])]
    f = scene / f"poses_{n}.json"
    f.write_text(json.dumps(cams))
    return f


def _estimate(scene: Path, poses: Path, method: str) -> int:
    from ibrtools.formats import native
    from ibrtools.pipeline import job as render_job
    from ibrtools.pipeline import plan as planning
    job = planning.plan(native.load(scene), poses=str(poses))
    return planning.estimate_memory(job, method)["total"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1920x1080,3840x2160")
    ap.add_argument("--methods", default="reference,dibr,warp,depthwarp")
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--staged-views", type=int, default=4,
                    help="input views of the scene for tm, ulr, pvm and hybrid (default 4)")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--work", default=str(Path(tempfile.gettempdir()) / "ibr-measure-memory"))
    ap.add_argument("--write-docs", action="store_true")
    ap.add_argument("--reuse", action="store_true",
                    help="reuse the measurements of an earlier run with the same --work (kept in "
                         "measurements.json there); the estimates are computed again (after a refit)")
    a = ap.parse_args(argv)
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    mib = 2 ** 20
    cache_file = work / "measurements.json"
    cache = json.loads(cache_file.read_text()) if cache_file.is_file() else {}
    base = 0
    for size in a.sizes.split(","):
        base, _, _, _ = _time_v([sys.executable, "-c", "import ibrtools._core, ibrtools.methods, open3d"])
        for m in a.methods.split(","):
            views = a.staged_views if m in STAGED else a.views
            scene = _scene(work, size, views, m in STAGED, a.threads)
            poses = _poses(scene, a.frames)
            out = work / f"out_{size}_{m}"
            key = f"{size} {m} views={views} frames={a.frames} threads={a.threads}"
            if a.reuse and key in cache:
                rss, secs, code, err = cache[key]
            else:
                rss, secs, code, err = _time_v([str(BIN / "ibr-render"), str(scene), "--method", m, "--poses",
                                                str(poses), "-o", str(out), "-q", "-j", str(a.threads)])
                cache[key] = (rss, secs, code, err)
                cache_file.write_text(json.dumps(cache, indent=1))
            est = _estimate(scene, poses, m)
            res = "ok" if code == 0 else f"exit {code}"
            rows.append(((size, m), f"| {size} | {m} | {views} | {rss / mib:.0f} | {est / mib:.0f} | "
                                    f"{est / max(rss, 1):.2f} | {secs:.1f} | {res} |", code))
            status = "ok" if code == 0 else f"exit {code}: {err.splitlines()[-1] if err else ''}"
            print(f"{size:>10} {m:<10} views {views}  peak {rss / mib:8.0f} MiB  wall {secs:6.1f} s  estimate "
                  f"{est / mib:8.0f} MiB  ({status})", flush=True)
    table = _table(rows, a, base)
    print(table)
    if a.write_docs:
        sys.path.insert(0, str(REPO / "benchmarks"))
        from benchlib import write_section

        write_section(SECTION, table, DOC)
    return 0 if all(r[2] == 0 for r in rows) else 1


HEADER = ["| size | method | input views | peak RSS (MiB) | estimate (MiB) | estimate / peak | wall (s) | result |",
          "|---|---|---:|---:|---:|---:|---:|---|"]


def _old_rows() -> dict:
    """The rows of the table now in docs/robustness.md, by (size, method): kept when not re-measured."""
    text = DOC.read_text() if DOC.is_file() else ""
    m = re.search(rf"<!-- {SECTION}:begin -->(.*?)<!-- {SECTION}:end -->", text, re.S)
    rows = {}
    for line in (m.group(1) if m else "").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not (cells and re.fullmatch(r"\d+x\d+", cells[0])):
            continue
        if len(cells) == 6:  # the first table's rows (8 views, no ratio column)
            size, m, rss, est, wall, res = cells
            cells = [size, m, "8", rss, est, f"{float(est) / float(rss):.2f}", wall, res]
        if len(cells) == len(HEADER[0].strip("|").split("|")):
            rows[(cells[0], cells[1])] = "| " + " | ".join(cells) + " |"
    return rows


def _table(rows, a, base: int) -> str:
    merged = _old_rows() if a.write_docs else {}
    merged.update({key: line for key, line, _ in rows})
    order = {m: i for i, m in enumerate(["reference", "dibr", "warp", "depthwarp", "tm", "ulr", "pvm", "hybrid"])}
    keys = sorted(merged, key=lambda k: (int(k[0].split("x")[0]), order.get(k[1], 99), k[1]))
    lines = [f"Measured with `tools/measure_memory.py` (synthetic `objects` scenes at the frame size: "
             f"{a.views} input views for reference/dibr/warp/depthwarp, {a.staged_views} for tm/ulr/pvm/hybrid, "
             f"whose preprocessing stages run first; the first frames of the `orbit` path (this run: {a.frames}), "
             f"-j {a.threads}; peak "
             f"RSS of the whole `ibr-render` process from `/usr/bin/time -v`; the interpreter with the engine, "
             f"open3d and numpy loaded alone peaks at {base / 2 ** 20:.0f} MiB). *Estimate* is the render job's "
             "own figure used to refuse a job early (ibrtools.pipeline.plan.estimate_memory); it must stay above "
             "the measurement, by 1.3-1.5x.", "", *HEADER]
    lines += [merged[k] for k in keys]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
