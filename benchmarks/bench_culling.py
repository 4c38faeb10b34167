"""Warping-based occlusion culling (WOC, Lee et al. 2018 sec. 5) along the camera paths of the
synthetic ``crowd`` and ``city`` scenes: drawn / ideal / falsely culled objects and stage times.

    python benchmarks/bench_culling.py [--width 1920 --height 1080] [--frames 12] [--path-frames 48]
                                       [--seeds 8] [--write-docs]

Per frame t = 1 .. --frames of the scene's path (``--path-frames`` cameras on the whole path,
which sets the motion per frame): the occlusion map is frame t-1's reference depth warped into
frame t (``ibrtools.depthwarp.warp_depth``, single layer, N = --seeds as in the paper's sec. 5.3,
holes = far); ``ibrtools.culling.cull_objects`` tests every object's world box. Rows:

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
the same frame for scale. With --write-docs, replaces the "bench_culling" section of
docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from benchlib import DOCS, load_note, machine, write_section

from ibrtools import synth
from ibrtools.culling import cull_objects, object_boxes
from ibrtools.errors import NotBuiltError
from ibrtools.render.reference import ReferenceRenderer

SCENES = (("crowd", "orbit"), ("city", "street"))


def run_scene(preset: str, path: str, size: tuple[int, int], frames: int, path_frames: int, seeds: int) -> list[dict]:
    try:
        from ibrtools.depthwarp import DepthWarpParams, warp_depth
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
        for mode in modes:
            times = {"reference": t_ref}
            kw = {}
            if mode == "exact depth":
                depth, hole = out["depth"], None
            else:
                t0 = time.perf_counter()
                w = warp_depth(prev_depth, cams[t - 1], cam, DepthWarpParams(seeds=seeds))
                times["warp"] = (time.perf_counter() - t0) * 1e3
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
            "t_test": med("t_test"), "t_reference": med("t_reference"),
        })
    return rows


def run(width: int, height: int, frames: int, path_frames: int, seeds: int) -> str:
    rows = []
    for preset, path in SCENES:
        rows += run_scene(preset, path, (width, height), frames, path_frames, seeds)
    lines = [
        "## Warping-based occlusion culling (bench_culling)",
        "",
        f"`python benchmarks/bench_culling.py --width {width} --height {height} --frames {frames} "
        f"--path-frames {path_frames} --seeds {seeds}` on {machine()}. Frames 1..{frames} of each scene's path "
        f"({path_frames} cameras on the whole path); per frame, frame t-1's reference depth warped into frame t "
        "(single layer, holes = far) is the occlusion map (WOC), or frame t's own reference depth (exact depth). "
        "Object counts are means per frame; falsely culled = visible in the Embree reference but culled, summed "
        "over the frames (<= 2 px objects apart; target for larger ones: 0). Times: medians per frame, ms.",
        "",
        "| scene | map | objects | drawn | ideal | frustum culled | occlusion culled | culled / ideal culled "
        "| falsely culled <= 2 px | falsely culled > 2 px | holes | warp ms | N-buffer ms | test ms | reference ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r.get("absent"):
            lines.append(f"| {r['scene']} | {r['mode']} | not built yet |" + " |" * 12)
            continue
        warp = "-" if r["t_warp"] != r["t_warp"] else f"{r['t_warp']:.1f}"
        lines.append(
            f"| {r['scene']} | {r['mode']} | {r['objects']} | {r['drawn']:.1f} | {r['ideal']:.1f} | "
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
    ap.add_argument("--path-frames", type=int, default=48, help="cameras on the whole path (default 48)")
    ap.add_argument("--seeds", type=int, default=8, help="warp seeds N (paper sec. 5.3: 8)")
    ap.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    a = ap.parse_args()
    if a.frames < 1 or a.path_frames < a.frames + 1:
        ap.error("--frames must be >= 1 and --path-frames > --frames")
    section = run(a.width, a.height, a.frames, a.path_frames, a.seeds)
    print(section)
    if a.write_docs:
        write_section("bench_culling", section)
        print(f"\nwrote {DOCS}")


if __name__ == "__main__":
    main()
