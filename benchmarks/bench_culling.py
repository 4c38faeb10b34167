"""Warping-based occlusion culling (WOC, Lee et al. 2018 sec. 5) along the camera paths of the
synthetic ``crowd`` and ``city`` scenes: drawn / ideal / falsely culled objects and stage times.

    python benchmarks/bench_culling.py [--width 1920 --height 1080] [--frames 12] [--paths walk,stress]
                                       [--seeds 8] [--csv FILE] [--write-docs]

Per frame t = 1 .. --frames of the scenes' fixed-step paths (``ibrtools.synth``: "walk" 15-35
px/frame and "stress" 100+ px/frame of average maximal motion at 1920x1080; the stress path is the
paper's AWOC case). Per frame: the occlusion map is frame t-1's reference depth warped into frame t
(``ibrtools.depthwarp.warp_depth``, single layer, N = --seeds as in the paper's sec. 5.3, no
dilation (not conservative), holes = far); ``ibrtools.culling.cull_objects`` tests every object's
world box. Rows:

* **WOC**: the warped map (the method);
* **AWOC**: ``approximate=True`` when it is built;
* **exact depth**: frame t's own reference depth as the occlusion map (what a perfect warp would
  give; the culling power of screen-space boxes against an ideal occluder map, like the paper's
  HOM-with-the-precise-depth comparison of Fig. 14).

Ground truth ("ideal"): the object ids the Embree reference renderer hits in frame t
(``ReferenceRenderer.visible_objects``); pixel counts from its object-id buffer. "falsely culled"
= visible in the reference but culled, split into <= 2 px objects (the paper expects those) and
larger ones (target: 0). Times are wall ms medians over the frames: motion + warp (the warp call),
N-buffer (Y-map build), test (frustum + rectangles + queries), and the reference depth render of
the same frame for scale. --csv writes every frame's figures (and the falsely culled ids). With --write-docs, replaces the "bench_culling" section of
docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import csv
import statistics
import time
from pathlib import Path

import numpy as np
from benchlib import DOCS, load_note, machine, write_section

from ibrtools import synth
from ibrtools.culling import cull_objects, object_boxes
from ibrtools.errors import NotBuiltError
from ibrtools.render.reference import ReferenceRenderer

SCENES = ("crowd", "city")


PER_FRAME: list[dict] = []  # every frame's record (--csv)


def run_scene(preset: str, path: str, size: tuple[int, int], frames: int, path_frames: int, seeds: int) -> list[dict]:
    try:
        from ibrtools.depthwarp import DepthWarpParams, motion_buffer, warp_depth
    except ImportError:
        warp_depth = None
    mesh, built = synth.build_mesh(preset, size=size, path_frames=path_frames)
    boxes = object_boxes(mesh)
    ref = ReferenceRenderer(mesh)
    cams = built.paths[path][: frames + 1]
    modes = ["exact depth"] + (["WOC", "AWOC"] if warp_depth is not None else [])
    acc: dict[str, dict[str, list]] = {m: {} for m in modes}
    prev_depth = ref.render(cams[0], outputs=("depth",), lights=[])["depth"]
    for t in range(1, len(cams)):
        cam = cams[t]
        t0 = time.perf_counter()
        out = ref.render(cam, outputs=("depth", "object_id"), lights=[])
        t_ref = (time.perf_counter() - t0) * 1e3
        ids = ref.visible_objects(cam)
        oid = out["object_id"]
        counts = np.bincount(oid[oid >= 0], minlength=len(boxes))
        if warp_depth is not None:
            # One warp per frame serves WOC and AWOC.
            t0 = time.perf_counter()
            w = warp_depth(prev_depth, cams[t - 1], cam, DepthWarpParams(seeds=seeds, dilate=False))
            t_warp = (time.perf_counter() - t0) * 1e3
            motion, valid = motion_buffer(prev_depth, cams[t - 1], cam)
            n = np.linalg.norm(motion, axis=-1)[valid > 0]
            for mode in ("WOC", "AWOC"):
                acc[mode].setdefault("motion_max", []).append(float(n.max()) if n.size else 0.0)
                acc[mode].setdefault("motion_median", []).append(float(np.median(n)) if n.size else 0.0)
        for mode in modes:
            times = {"reference": t_ref}
            kw = {}
            if mode == "exact depth":
                depth, hole = out["depth"], None
            else:
                times["warp"] = t_warp
                depth, hole = w.depth, w.hole
                if mode == "AWOC":
                    kw = dict(approximate=True, source_depth=prev_depth, source_camera=cams[t - 1])
            try:
                res = cull_objects(depth, hole, cam, boxes, **kw)
            except NotBuiltError:
                continue
            times.update(nbuffer=res.times_ms["nbuffer"], test=res.times_ms["test"] + res.times_ms["prepare"])
            ev = res.evaluate(ids, counts)
            a = acc[mode]
            for k in ("drawn", "ideal", "falsely_culled_small", "falsely_culled_large", "frustum_culled",
                      "occlusion_culled", "culled_fraction", "ideal_culled_fraction"):
                a.setdefault(k, []).append(ev[k])
            for k, v in times.items():
                a.setdefault("t_" + k, []).append(v)
            a.setdefault("hole", []).append(res.stats["hole_fraction"])
            PER_FRAME.append({"scene": preset, "path": path, "frame": t, "map": mode,
                              **{k: v for k, v in ev.items() if k != "false_ids"},
                              "false_ids": " ".join(map(str, ev["false_ids"])),
                              "hole_fraction": res.stats["hole_fraction"],
                              **{"ms_" + k: v for k, v in times.items()}})
        prev_depth = out["depth"]
    rows = []
    for mode in modes:
        a = acc[mode]
        if not a:
            rows.append({"scene": preset, "mode": mode, "absent": True})
            continue
        med = lambda k: statistics.median(a[k]) if k in a else float("nan")  # noqa: E731
        rows.append({
            "scene": preset, "mode": mode, "objects": len(boxes), "frames": len(a["drawn"]),
            "drawn": statistics.mean(a["drawn"]), "ideal": statistics.mean(a["ideal"]),
            "frustum": statistics.mean(a["frustum_culled"]), "occlusion": statistics.mean(a["occlusion_culled"]),
            "false_small": sum(a["falsely_culled_small"]), "false_large": sum(a["falsely_culled_large"]),
            "culled": statistics.mean(a["culled_fraction"]), "ideal_culled": statistics.mean(a["ideal_culled_fraction"]),
            "hole": statistics.mean(a["hole"]), "t_warp": med("t_warp"), "t_nbuffer": med("t_nbuffer"),
            "t_test": med("t_test"), "t_reference": med("t_reference"), "path_frames": path_frames,
            "motion": (statistics.mean(a["motion_median"]), statistics.mean(a["motion_max"]))
            if "motion_max" in a else None,
        })
    return rows


def run(width: int, height: int, frames: int, paths: list[str], seeds: int) -> str:
    rows = []
    for preset in SCENES:
        for path in paths:
            # The scene's fixed-step paths (synth, docs/synth.md): "walk" 15-35 px/frame and "stress"
            # 100+ px/frame of average maximal motion at 1920x1080.
            rows += [r | {"mode": f"{r['mode']} ({path})"}
                     for r in run_scene(preset, path, (width, height), frames, frames + 1, seeds)
                     if path == paths[0] or r["mode"] != "exact depth"]
    lines = [
        "## Warping-based occlusion culling (bench_culling)",
        "",
        f"`python benchmarks/bench_culling.py --width {width} --height {height} --frames {frames} "
        f"--paths {','.join(paths)} --seeds {seeds}` on {machine()}. Frames 1..{frames} of each scene's fixed-step "
        "paths (walk: 15-35 px/frame, stress: 100+ px/frame of average maximal motion at 1920x1080); per frame, frame t-1's reference depth warped into frame t "
        "(single layer, holes = far) is the occlusion map (WOC), or frame t's own reference depth (exact depth). "
        "Object counts are means per frame; falsely culled = visible in the Embree reference but culled, summed "
        "over the frames (<= 2 px objects apart; target for larger ones: 0). Times: medians per frame, ms.",
        "",
        "| scene | map (path) | motion px/frame (median / max) | objects | drawn | ideal | frustum culled "
        "| occlusion culled | culled / ideal culled "
        "| falsely culled <= 2 px | falsely culled > 2 px | holes | warp ms | N-buffer ms | test ms | reference ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r.get("absent"):
            lines.append(f"| {r['scene']} | {r['mode']} | not built yet |" + " |" * 13)
            continue
        warp = "-" if r["t_warp"] != r["t_warp"] else f"{r['t_warp']:.1f}"
        mot = "-" if r["motion"] is None else f"{r['motion'][0]:.1f} / {r['motion'][1]:.1f}"
        lines.append(
            f"| {r['scene']} | {r['mode']} | {mot} | {r['objects']} | {r['drawn']:.1f} | {r['ideal']:.1f} | "
            f"{r['frustum']:.1f} | {r['occlusion']:.1f} | {100 * r['culled']:.1f} % / {100 * r['ideal_culled']:.1f} % | "
            f"{r['false_small']} | {r['false_large']} | {100 * r['hole']:.2f} % | {warp} | {r['t_nbuffer']:.2f} | "
            f"{r['t_test']:.2f} | {r['t_reference']:.1f} |")
    lines += ["", load_note()]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--frames", type=int, default=12, help="frames culled per scene (default 12)")
    ap.add_argument("--paths", default="walk,stress", help="the scenes' paths to run (default walk,stress)")
    ap.add_argument("--seeds", type=int, default=8, help="warp seeds N (paper sec. 5.3: 8)")
    ap.add_argument("--csv", type=Path, help="also write every frame's figures to this CSV file")
    ap.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    a = ap.parse_args()
    paths = [p for p in a.paths.split(",") if p]
    if a.frames < 1 or not paths or any(p not in ("walk", "stress") for p in paths):
        ap.error("--frames must be >= 1; --paths: walk and/or stress")
    section = run(a.width, a.height, a.frames, paths, a.seeds)
    print(section)
    if a.csv:
        keys = list(dict.fromkeys(k for r in PER_FRAME for k in r))
        with open(a.csv, "w", newline="") as f:
            w = csv.DictWriter(f, keys)
            w.writeheader()
            w.writerows(PER_FRAME)
        print(f"\nwrote {a.csv} ({len(PER_FRAME)} frame records)")
    if a.write_docs:
        write_section("bench_culling", section)
        print(f"\nwrote {DOCS}")


if __name__ == "__main__":
    main()
