"""A 1080p DIBR job of 64 views: local multithreaded run vs a 2-worker Dask LocalCluster
(target: the cluster within 15 % of the local run on this 2-core machine).

    python benchmarks/bench_distributed.py [--frames 64] [--repeats 5] [--size 1920x1080]
                                           [--views 8] [--scene DIR] [--write-docs]

Scene: ``synth:objects`` with --views input views (colour + depth, 1920x1080) made once into
--scene (kept between runs); the frames are the first --frames cameras of its "orbit" path,
given as a pose file (``ibr-render --poses``). Every run renders them with ``--method dibr``
(4 nearest inputs per frame) and writes the PNGs and report.json, as the command does:

* local: ``job.run(..., threads=2)``: one process, the engine's 2 threads;
* cluster: ``job.run(..., workers=2)``: a LocalCluster of 2 processes x 1 thread started and
  stopped inside the timed call (what ``ibr-render --workers 2`` costs), and
* warm cluster: ``job.run(..., scheduler=ADDRESS)`` on a cluster started beforehand (the
  workers still load the scene and prepare the method: one preparation per worker per job).

Median of --repeats runs each (after one warm-up run of each kind). Also measured: what one
task sends back (its frames' encoded PNG bytes and report entry, vs the float32 colour array it
would be), the time a worker takes to encode a frame's PNG, the cluster's start-up time.
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from benchlib import load_note, machine, write_section


def make_scene(root: Path, size: tuple[int, int], views: int, frames: int) -> Path:
    from ibrtools.pipeline.importing import run_import

    synth = {"preset": "objects", "size": list(size), "views": views, "seed": 0, "reconstructed": False,
             "path_frames": max(frames, 64)}
    r = run_import("synth:objects", root, synth=synth)
    print(f"scene {root}: {r.status} ({r.seconds:.1f} s)", flush=True)
    return root


def poses_file(root: Path, frames: int, dest: Path) -> Path:
    from ibrtools.formats import native

    cams = native.load(root).paths["orbit"][:frames]
    dest.write_text(json.dumps([dict(c.to_dict(), name=f"f{i:03d}") for i, c in enumerate(cams)]))
    return dest


def timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--scene", default=os.path.join(tempfile.gettempdir(), "ibr-bench-distributed"))
    ap.add_argument("--write-docs", action="store_true")
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.lower().split("x"))

    from ibrtools.pipeline import distributed as D
    from ibrtools.formats import native
    from ibrtools.pipeline import job as J
    from ibrtools.pipeline import plan as planning
    from ibrtools.pipeline.job import write_output

    root = make_scene(Path(args.scene) / f"objects_{size[0]}x{size[1]}_{args.views}v_{max(args.frames, 64)}f",
                      size, args.views, args.frames)
    work = Path(tempfile.mkdtemp(prefix="ibr-bench-dist-"))
    poses = poses_file(root, args.frames, work / "poses.json")

    def run(out: str, **kw) -> dict:
        return J.run(planning.plan(native.load(root), poses=str(poses)), "dibr", work / out, **kw)

    results: dict[str, list[float]] = {"local": [], "cluster": [], "warm": []}
    with D.open_client(None, 2) as client:  # the warm cluster; also warms the workers' imports
        address = client.scheduler.address
        run("warm", scheduler=address)
        run("local", threads=2)
        run("cluster", workers=2)
        for r in range(args.repeats):
            for kind, kw in (("local", {"threads": 2}), ("cluster", {"workers": 2}), ("warm", {"scheduler": address})):
                results[kind].append(timed(lambda: run(kind, **kw)))
            print(f"repeat {r + 1}: " + ", ".join(f"{k} {v[-1]:.2f} s" for k, v in results.items()), flush=True)
        # What one task sends back, measured on the last run's outputs: the frame's PNG bytes
        # plus its pickled report entry, vs the float32 colour array (W x H x 3 x 4 bytes).
        rep = json.loads((work / "warm" / "report.json").read_text())
        png = [(work / "warm" / f["image"]).stat().st_size for f in rep["frames"]]
        entry = [len(pickle.dumps(f)) for f in rep["frames"]]
        # Encode time of one frame's PNG (what a worker does instead of sending the array) and the
        # round trip of the float32 array through the cluster.
        from ibrtools.imageio import read_image

        color = read_image(work / "warm" / rep["frames"][0]["image"])
        enc_s = statistics.median(timed(lambda: write_output(work, "enc.png", "image", color)) for _ in range(5))
        fut = client.scatter(color)
        rt_array = statistics.median(timed(lambda: client.submit(np.copy, fut, pure=False).result())
                                     for _ in range(5))
        blob = (work / "warm" / rep["frames"][0]["image"]).read_bytes()
        fb = client.scatter(blob)
        rt_png = statistics.median(timed(lambda: client.submit(bytes, fb, pure=False).result()) for _ in range(5))
    def start_stop() -> None:
        with D.open_client(None, 2):
            pass

    t_start = [timed(start_stop) for _ in range(2)]
    med = {k: statistics.median(v) for k, v in results.items()}
    n = args.frames
    local_per_view = med["local"] / n
    figures = {
        "frames": n, "size": f"{size[0]}x{size[1]}", "inputs": args.views, "repeats": args.repeats,
        "median_s": {k: round(v, 3) for k, v in med.items()},
        "all_s": {k: [round(x, 3) for x in v] for k, v in results.items()},
        "cluster_over_local": round(med["cluster"] / med["local"], 3),
        "warm_over_local": round(med["warm"] / med["local"], 3),
        "local_s_per_view": round(local_per_view, 4),
        "png_bytes_per_task_median": int(statistics.median(png)),
        "entry_bytes_per_task_median": int(statistics.median(entry)),
        "float32_bytes_per_frame": size[0] * size[1] * 3 * 4,
        "png_encode_ms": round(enc_s * 1e3, 1),
        "roundtrip_float32_ms": round(rt_array * 1e3, 1), "roundtrip_png_ms": round(rt_png * 1e3, 1),
        "task_spec_bytes": len(pickle.dumps({"root": str(root), "plan": {"poses": str(poses)}, "method": "dibr"})),
    }
    print(json.dumps(figures, indent=1))
    if args.write_docs:
        f = figures
        ok = "met" if f["cluster_over_local"] <= 1.15 else "missed"
        section = "\n".join([
            "## Distributed rendering (Dask LocalCluster vs local)", "",
            f"`python benchmarks/bench_distributed.py --frames {n} --repeats {args.repeats}` on {machine()}. "
            f"{n} frames of {f['size']} rendered with `--method dibr` from {args.views} input views "
            "(synth:objects, orbit path as a pose file), PNGs and report.json written. Median of "
            f"{args.repeats} runs (s):", "",
            "| run | wall time (s) | vs local |", "|---|---|---|",
            f"| local, 1 process x 2 engine threads | {f['median_s']['local']:.2f} | 1.00 |",
            f"| `--workers 2`: LocalCluster 2 processes x 1 thread, started in the run | "
            f"{f['median_s']['cluster']:.2f} | {f['cluster_over_local']:.2f} |",
            f"| `--scheduler`: the same cluster already running, workers prepared | {f['median_s']['warm']:.2f} | "
            f"{f['warm_over_local']:.2f} |", "",
            f"Target (cluster within 15 % of local): **{ok}** ({(f['cluster_over_local'] - 1) * 100:+.0f} %). "
            f"Time per view (local): {f['local_s_per_view'] * 1e3:.0f} ms. Data per task: "
            f"{f['png_bytes_per_task_median'] / 1e6:.2f} MB of PNG + {f['entry_bytes_per_task_median']} B of report "
            f"entry back, ~{f['task_spec_bytes']} B of spec out (a float32 frame would be "
            f"{f['float32_bytes_per_frame'] / 1e6:.1f} MB); PNG encode on the worker {f['png_encode_ms']:.0f} ms; "
            f"round trip through the cluster: float32 frame {f['roundtrip_float32_ms']:.0f} ms, PNG "
            f"{f['roundtrip_png_ms']:.0f} ms. Cluster start + stop: {statistics.median(t_start):.1f} s.", "",
            load_note()])
        write_section("distributed", section)
        print("wrote docs/benchmarks.md section 'distributed'")


if __name__ == "__main__":
    main()
