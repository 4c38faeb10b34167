"""Warping-based occlusion culling (WOC, Lee et al. 2018 sec. 5) along the camera paths of the
synthetic ``crowd`` and ``city`` scenes: drawn / ideal / falsely culled objects and stage times.

    python benchmarks/bench_culling.py [--sizes 1920x1080,960x540] [--frames all] [--paths walk,stress]
                                       [--layers 3] [--seeds 4] [--proof-cost 7] [--csv FILE] [--write-docs]

Per frame t = 1 .. --frames ("all": every frame of the 48-camera paths) of the scenes' fixed-step
paths (``ibrtools.synth``: "walk" 15-35 px/frame and "stress" 100+ px/frame of average maximal
motion at 1920x1080; the stress path is the paper's AWOC case), frame t-1's deep depth buffer (L =
--layers peeled layers with their object ids) is warped into frame t exactly as ``ibr-render --method
depthwarp --cull`` does (``warp_with_far_plane``: N = --seeds, T = 3, no dilation, the kernel's
defaults otherwise) and ``ibrtools.depthwarp.culling.cull_objects`` tests every object's world box against one
of these occlusion maps:

* **WOC**: the warp's proven occluder depth (``WarpResult.occluder``; pixels without a proven depth
  are far): the method's map, conservative;
* **WOC, converged samples**: the warped depth with holes far (every converged sample taken as
  covering its pixel): what the method used before the proof, not conservative (for comparison);
* **AWOC**: ``approximate=True`` on the converged samples (the holes filled from the local search
  bound; not conservative by design);
* **exact depth**: frame t's own reference depth (what a perfect warp would give; the culling power
  of screen-space boxes against an ideal occluder map, like the paper's HOM-with-the-precise-depth
  comparison of Fig. 14).

Ground truth ("ideal"): the object ids the Embree reference renderer hits in frame t; pixel counts
from its object-id buffer. "falsely culled" = visible in the reference but culled, split into
<= 2 px objects and larger ones (target for WOC: 0). Times are wall ms medians over the frames:
the warp call (motion + mipmaps + warp + proof), N-buffer (Y-map build), test (frustum + rectangles +
queries; AWOC: + its motion buffer and fill), and the reference depth render of the same frame for
scale. --proof-cost R: the warp with and without the proof (surface ids), interleaved R times on
frame 1 of each scene's walk path, wall and process CPU medians and their ratio. --csv writes every
frame's figures (and the falsely culled ids). --write-docs replaces the "bench_culling" section of
docs/benchmarks_depthwarp.md.
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
from ibrtools.depthwarp.culling import cull_objects, object_boxes
from ibrtools.depthwarp.core import DepthWarpParams, motion_buffer
from ibrtools.depthwarp.method import warp_with_far_plane
from ibrtools.raycast.reference import ReferenceRenderer

SCENES = ("crowd", "city")
PATH_FRAMES = 48  # synth's default: the stored paths' length
MODES = ("exact depth", "WOC", "WOC, converged samples", "AWOC")

PER_FRAME: list[dict] = []  # every frame's record (--csv)


def _warp(mesh, deep, src, dst, seeds: int, proof: bool = True):
    """The warp of DepthWarpMethod with --cull (depthwarp/method.py)."""
    return warp_with_far_plane(deep.depth, src, dst, mesh.bounds(), "none", DepthWarpParams(seeds=seeds, dilate=False),
                               True, surface_ids=deep.object_id if proof else None)


def run_scene(preset: str, path: str, size: tuple[int, int], frames: int, layers: int, seeds: int) -> list[dict]:
    mesh, built = synth.build_mesh(preset, size=size, views=1, holdout_targets=0, path_frames=PATH_FRAMES)
    boxes = object_boxes(mesh)
    ref = ReferenceRenderer(mesh)
    cams = built.paths[path][: frames + 1]
    acc: dict[str, dict[str, list]] = {m: {} for m in MODES}
    for t in range(1, len(cams)):
        src, cam = cams[t - 1], cams[t]
        deep = ref.peel(src, layers)
        t0 = time.perf_counter()
        out = ref.render(cam, outputs=("depth", "object_id"), lights=[])
        t_ref = (time.perf_counter() - t0) * 1e3
        oid = out["object_id"]
        counts = np.bincount(oid[oid >= 0], minlength=len(boxes))[: len(boxes)]
        ids = np.flatnonzero(counts)
        t0 = time.perf_counter()
        w = _warp(mesh, deep, src, cam, seeds)  # one warp per frame serves every warped map
        t_warp = (time.perf_counter() - t0) * 1e3
        source_depth = deep.depth[0]
        motion, valid = motion_buffer(source_depth, src, cam)
        n = np.linalg.norm(motion, axis=-1)[valid > 0]
        for mode in MODES:
            times = {"reference": t_ref}
            kw: dict = {}
            if mode == "exact depth":
                depth, hole = out["depth"], None
            elif mode == "WOC":
                depth, hole = w.occluder, None
            else:
                depth, hole = w.depth, w.hole
                if mode == "AWOC":
                    kw = dict(approximate=True, source_depth=source_depth, source_camera=src)
            if mode != "exact depth":
                times["warp"] = t_warp
            res = cull_objects(depth, hole, cam, boxes, **kw)
            times.update(nbuffer=res.times_ms["nbuffer"], test=res.times_ms["test"] + res.times_ms["prepare"])
            ev = res.evaluate(ids, counts)
            far = ~(depth > 0) if hole is None else (hole | ~(depth > 0))
            a = acc[mode]
            for k in ("drawn", "ideal", "falsely_culled_small", "falsely_culled_large", "frustum_culled",
                      "occlusion_culled", "culled_fraction", "ideal_culled_fraction"):
                a.setdefault(k, []).append(ev[k])
            for k, v in times.items():
                a.setdefault("t_" + k, []).append(v)
            a.setdefault("far", []).append(float(far.mean()))
            a.setdefault("motion_max", []).append(float(n.max()) if n.size else 0.0)
            a.setdefault("motion_median", []).append(float(np.median(n)) if n.size else 0.0)
            a.setdefault("false_frames", []).append(int(ev["falsely_culled_large"] > 0))
            PER_FRAME.append({"size": f"{size[0]}x{size[1]}", "scene": preset, "path": path, "frame": t, "map": mode,
                              **{k: v for k, v in ev.items() if k != "false_ids"},
                              "false_ids": " ".join(map(str, ev["false_ids"])), "far_fraction": float(far.mean()),
                              **{"ms_" + k: v for k, v in times.items()}})
    rows = []
    for mode in MODES:
        a = acc[mode]
        med = lambda k: statistics.median(a[k]) if k in a else float("nan")  # noqa: E731
        rows.append({
            "scene": preset, "path": path, "mode": mode, "objects": len(boxes), "frames": len(a["drawn"]),
            "drawn": statistics.mean(a["drawn"]), "ideal": statistics.mean(a["ideal"]),
            "frustum": statistics.mean(a["frustum_culled"]), "occlusion": statistics.mean(a["occlusion_culled"]),
            "false_small": sum(a["falsely_culled_small"]), "false_large": sum(a["falsely_culled_large"]),
            "false_frames": sum(a["false_frames"]),
            "culled": statistics.mean(a["culled_fraction"]), "ideal_culled": statistics.mean(a["ideal_culled_fraction"]),
            "far": statistics.mean(a["far"]), "t_warp": med("t_warp"), "t_nbuffer": med("t_nbuffer"),
            "t_test": med("t_test"), "t_reference": med("t_reference"),
            "motion": (statistics.mean(a["motion_median"]), statistics.mean(a["motion_max"])),
        })
    return rows


def proof_cost(size: tuple[int, int], layers: int, seeds: int, repeats: int) -> list[str]:
    """The warp with and without the proof, interleaved, on frame 0 -> 1 of each scene's walk."""
    lines = []
    for preset in SCENES:
        mesh, built = synth.build_mesh(preset, size=size, views=1, holdout_targets=0, path_frames=2)
        ref = ReferenceRenderer(mesh)
        src, dst = built.paths["walk"][:2]
        deep = ref.peel(src, layers)
        _warp(mesh, deep, src, dst, seeds), _warp(mesh, deep, src, dst, seeds, False)  # warm-up
        wall: dict[bool, list] = {True: [], False: []}
        cpu: dict[bool, list] = {True: [], False: []}
        for _ in range(repeats):
            for proof in (False, True):
                c0, t0 = time.process_time(), time.perf_counter()
                _warp(mesh, deep, src, dst, seeds, proof)
                wall[proof].append((time.perf_counter() - t0) * 1e3)
                cpu[proof].append((time.process_time() - c0) * 1e3)
        m = {k: (statistics.median(wall[k]), statistics.median(cpu[k])) for k in (False, True)}
        lines.append(f"| {preset} | {m[False][0]:.1f} / {m[False][1]:.1f} | {m[True][0]:.1f} / {m[True][1]:.1f} | "
                     f"{m[True][0] / m[False][0]:.2f}x / {m[True][1] / m[False][1]:.2f}x |")
    return lines


def table(rows: list[dict]) -> list[str]:
    lines = [
        "| scene | map (path) | motion px/frame (median / max) | drawn | ideal | frustum culled "
        "| occlusion culled | culled / ideal culled | falsely culled <= 2 px | falsely culled > 2 px "
        "(frames with one) | far pixels | warp ms | N-buffer ms | test ms | reference ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        warp = "-" if r["mode"] == "exact depth" else f"{r['t_warp']:.1f}"
        mot = "-" if r["mode"] == "exact depth" else f"{r['motion'][0]:.1f} / {r['motion'][1]:.1f}"
        lines.append(
            f"| {r['scene']} ({r['objects']} objects) | {r['mode']} ({r['path']}) | {mot} | {r['drawn']:.1f} | "
            f"{r['ideal']:.1f} | {r['frustum']:.1f} | {r['occlusion']:.1f} | "
            f"{100 * r['culled']:.1f} % / {100 * r['ideal_culled']:.1f} % | {r['false_small']} | "
            f"{r['false_large']} ({r['false_frames']}) | {100 * r['far']:.2f} % | {warp} | {r['t_nbuffer']:.2f} | "
            f"{r['t_test']:.2f} | {r['t_reference']:.1f} |")
    return lines


def run(sizes: list[tuple[int, int]], frames: int, paths: list[str], layers: int, seeds: int, cost: int) -> str:
    t_start = time.perf_counter()
    frames_arg = "all" if frames == PATH_FRAMES - 1 else str(frames)
    cmd = (f"python benchmarks/bench_culling.py --sizes {','.join(f'{w}x{h}' for w, h in sizes)} --frames {frames_arg} "
           f"--paths {','.join(paths)} --layers {layers} --seeds {seeds}" + (f" --proof-cost {cost}" if cost else ""))
    body = []
    for size in sizes:
        rows = []
        for preset in SCENES:
            for path in paths:
                rows += run_scene(preset, path, size, frames, layers, seeds)
                print(f"bench_culling {size[0]}x{size[1]} {preset} {path}: done", flush=True)
        body += [f"### {size[0]}x{size[1]}", "", *table(rows), ""]
    if cost:
        size = sizes[0]
        body += [f"Proof cost ({size[0]}x{size[1]}, walk frame 0 -> 1, L = {layers}, N = {seeds}; the warp call "
                 f"with and without surface ids, interleaved {cost} times; medians, wall ms / process CPU ms):", "",
                 "| scene | warp without proof | warp with proof (WOC) | ratio |", "|---|---|---|---|",
                 *proof_cost(size, layers, seeds, cost), ""]
    lines = [
        "## Warping-based occlusion culling (bench_culling)",
        "",
        f"`{cmd}` on {machine()} (run took {time.perf_counter() - t_start:.0f} s). Frames 1..{frames} of each "
        f"scene's fixed-step paths (walk: 15-35 px/frame, stress: 100+ px/frame of average maximal motion at "
        f"1920x1080); per frame, frame t-1's {layers}-layer deep depth buffer warped into frame t as "
        f"`ibr-render --method depthwarp --layers {layers} --seeds {seeds} --cull` does (N = {seeds}, T = 3, no "
        "dilation, far plane). Maps: WOC = the warp's proven occluder depth (the method's; unproven pixels far), "
        "WOC, converged samples = the warped depth with holes far (not conservative; for comparison), AWOC = "
        "approximate=True on the converged samples, exact depth = frame t's own reference depth. Object counts "
        "are means per frame; falsely culled = visible in the Embree reference but culled, summed over the "
        "frames (<= 2 px objects apart; target for larger ones: 0); far pixels = the map's pixels that "
        "occlude nothing (mean). Times: medians per frame, ms.",
        "",
        *body,
        load_note(),
    ]
    return "\n".join(lines)


def _size(s: str) -> tuple[int, int]:
    w, h = s.lower().split("x")
    return int(w), int(h)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1920x1080", help="image sizes WxH, comma-separated (default 1920x1080)")
    ap.add_argument("--frames", default="all", help=f"frames culled per path, or 'all' ({PATH_FRAMES - 1}; default)")
    ap.add_argument("--paths", default="walk,stress", help="the scenes' paths to run (default walk,stress)")
    ap.add_argument("--layers", type=int, default=3, help="peeled source layers L (default 3, as ibr-render)")
    ap.add_argument("--seeds", type=int, default=4, help="warp seeds N (default 4)")
    ap.add_argument("--proof-cost", type=int, default=0, help="interleaved rounds of the proof's cost (>= 5; 0: off)")
    ap.add_argument("--csv", type=Path, help="also write every frame's figures to this CSV file")
    ap.add_argument("--write-docs", action="store_true", help="update docs/benchmarks_depthwarp.md")
    a = ap.parse_args()
    paths = [p for p in a.paths.split(",") if p]
    frames = PATH_FRAMES - 1 if a.frames == "all" else int(a.frames)
    try:
        sizes = [_size(s) for s in a.sizes.split(",") if s]
    except ValueError:
        ap.error("--sizes: WxH[,WxH...]")
    if not 1 <= frames < PATH_FRAMES or not paths or any(p not in ("walk", "stress") for p in paths):
        ap.error(f"--frames must be 1..{PATH_FRAMES - 1} or all; --paths: walk and/or stress")
    if a.proof_cost and a.proof_cost < 5:
        ap.error("--proof-cost: >= 5 rounds (or 0)")
    section = run(sizes, frames, paths, a.layers, a.seeds, a.proof_cost)
    print(section)
    if a.csv:
        keys = list(dict.fromkeys(k for r in PER_FRAME for k in r))
        with open(a.csv, "w", newline="") as f:
            w = csv.DictWriter(f, keys)
            w.writeheader()
            w.writerows(PER_FRAME)
        print(f"\nwrote {a.csv} ({len(PER_FRAME)} frame records)")
    if a.write_docs:
        write_section("bench_culling", section, DOCS.with_name("benchmarks_depthwarp.md"))
        print(f"\nwrote {DOCS.with_name('benchmarks_depthwarp.md')}")


if __name__ == "__main__":
    main()
