"""PVM rendering with clustered depth filtering: per-stage times at 1280x720 and the
quality of filtered vs unfiltered PVM near occlusion edges.

    python benchmarks/bench_pvm_render.py [--size 1280x720] [--views 20] [--runs 3] [--threads 2]
                                          [--quality-size 640x360] [--write-docs]

Scene: ``make_scene("objects", views=V, holdout_targets=3, depth_noise=0.005, reconstructed=True)``
(per-view depth with 0.5 % multiplicative noise; the "reconstructed" mesh is decimated, noisy
and misses the thin object). Tiles: ``hybrid.pvm.build_tiles`` of the views' noisy depth with the
pvm stage's defaults. G-buffer: the reconstructed mesh's z (Embree), as the hybrid method has it.

Speed (on the noisy scene and on the same scene with exact depth): for each held-out target, ``PvmRenderer.render`` (filtered, the defaults) --runs times
after a warm-up, median per stage (voxel lookup, tile sort, per-view depth pass, cluster & blend,
spatial filter) and of the sum, over the targets' medians. The G-buffer is not timed (it is the
TM pass of the hybrid method).

Quality (at --quality-size, same scene preset and seed): PSNR of filtered and unfiltered PVM
(``filtered=False``: the foreground cluster's ULR blend, PVM-H-like) against the held-out
ground truth, over the pixels both cover that lie within 3 px of a reference depth discontinuity
(log-depth range > 0.05 in a 3x3 window, or an empty neighbour), and over all pixels both cover;
and the same for max_angle 180 / 90 / 60 / 50 / 40 degrees and the default. Target: filtered beats unfiltered near
occlusion edges. With --write-docs, replaces the "PVM rendering" section of docs/benchmarks_hybrid.md.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from benchlib import DOCS, load_note, machine, write_section

STAGES = ("voxel lookup", "tile sort", "per-view depth pass", "cluster & blend", "spatial filter")


def parse_size(s: str) -> tuple[int, int]:
    w, h = s.lower().split("x")
    return int(w), int(h)


def build(size, views, depth_noise=0.005):
    from ibrtools.hybrid.pvm import build_tiles
    from ibrtools.raycast.reference import ReferenceRenderer
    from ibrtools.synth import make_scene

    t0 = time.perf_counter()
    scene = make_scene("objects", size=size, views=views, holdout_targets=3, seed=0, depth_noise=depth_noise,
                       reconstructed=True)
    t1 = time.perf_counter()
    tiles = build_tiles({v.name: v.camera for v in scene.views}, {v.name: v.depth for v in scene.views})
    t2 = time.perf_counter()
    rec = ReferenceRenderer(scene.meshes["reconstructed"])
    gbufs = {t.name: np.ascontiguousarray(rec.render(t.camera, outputs=("depth",))["depth"], np.float32)
             for t in scene.targets}
    print(f"scene {size[0]}x{size[1]} x {views} views, depth noise {depth_noise}: {t1 - t0:.1f} s, tiles {t2 - t1:.1f} s "
          f"({tiles.num_tiles} tiles, {len(tiles.faces)} triangles)", file=sys.stderr)
    return scene, tiles, gbufs


def edge_band(depth: np.ndarray, px: int = 3) -> np.ndarray:
    from scipy import ndimage

    ld = np.log(np.where(np.isfinite(depth) & (depth > 0), depth, 1e3))
    edge = (ndimage.maximum_filter(ld, 3) - ndimage.minimum_filter(ld, 3)) > 0.05
    return ndimage.binary_dilation(edge, iterations=px)


def psnr(a, b, m) -> float:
    mse = float(np.mean((a[m] - b[m]) ** 2)) if m.any() else float("nan")
    return 10 * np.log10(1.0 / mse) if mse > 0 else float("inf")


def speed(scene, tiles, gbufs, runs):
    from ibrtools.hybrid.pvm_render import PvmRenderer

    r = PvmRenderer(scene, tiles=tiles, images={v.name: v.color for v in scene.views})
    per_target = []
    stats = []
    for t in scene.targets:
        r.render(t.camera, gbuffer_depth=gbufs[t.name])  # warm-up
        rows = []
        for _ in range(runs):
            res = r.render(t.camera, gbuffer_depth=gbufs[t.name])
            rows.append(res.times_ms)
        stats.append(res.stats)
        med = {s: statistics.median(row[s] for row in rows) for s in STAGES}
        med["total"] = statistics.median(sum(row[s] for s in STAGES) for row in rows)
        per_target.append(med)
    out = {k: statistics.median(m[k] for m in per_target) for k in (*STAGES, "total")}
    return out, stats


def quality(scene, tiles, gbufs, angles):
    from ibrtools.hybrid.pvm_render import PvmRenderer

    rows = []
    for ang in angles:
        r = PvmRenderer(scene, {"max_angle": ang}, tiles=tiles, images={v.name: v.color for v in scene.views})
        acc = {"f_edge": [], "u_edge": [], "f_all": [], "u_all": [], "cov": [], "edge_px": []}
        for t in scene.targets:
            f = r.render(t.camera, gbuffer_depth=gbufs[t.name], filtered=True)
            u = r.render(t.camera, gbuffer_depth=gbufs[t.name], filtered=False)
            surface = np.isfinite(t.depth) & (t.depth > 0)  # sky is +inf: background, not surface
            both = f.valid & u.valid & surface
            band = both & edge_band(t.depth)
            acc["f_edge"].append(psnr(f.color, t.color, band))
            acc["u_edge"].append(psnr(u.color, t.color, band))
            acc["f_all"].append(psnr(f.color, t.color, both))
            acc["u_all"].append(psnr(u.color, t.color, both))
            acc["cov"].append(float((f.valid & surface).sum() / max(1, surface.sum())))
            acc["edge_px"].append(int(band.sum()))
        rows.append((ang, acc))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--quality-size", default="640x360")
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--write-docs", action="store_true")
    a = ap.parse_args(argv)
    from ibrtools import _core

    _core.set_num_threads(a.threads)
    size, qsize = parse_size(a.size), parse_size(a.quality_size)
    scene, tiles, gbufs = build(size, a.views)
    sp, stats = speed(scene, tiles, gbufs, a.runs)
    del scene, tiles, gbufs
    # The same scene with exact depth: the PVM stage merges planar blocks (0.1 % tolerance), which
    # 0.5 % noise defeats; this shows the renderer's cost on merged PVMs.
    scene, tiles, gbufs = build(size, a.views, 0.0)
    sp0, stats0 = speed(scene, tiles, gbufs, a.runs)
    del scene, tiles, gbufs
    qscene, qtiles, qgbufs = build(qsize, a.views)
    from ibrtools.hybrid.pvm_render import PvmParams

    default_angle = float(PvmParams.max_angle)  # always measured: the target is checked there
    angles = tuple(sorted({180.0, 90.0, 60.0, 50.0, 40.0, default_angle}, reverse=True))
    qrows = quality(qscene, qtiles, qgbufs, angles)

    lines = ["## PVM rendering", "",
             f"`python benchmarks/bench_pvm_render.py --size {a.size} --quality-size {a.quality_size} --views "
             f"{a.views} --runs {a.runs} --threads {a.threads}`. synth:objects, {a.views} views, 3 held-out targets, "
             "0.5 % depth noise; G-buffer = z of the degraded reconstructed mesh (not timed). "
             f"{machine()}, {a.threads} threads. docs/pvm_render.md.", "",
             f"Per stage at {size[0]}x{size[1]}, filtered (median of {a.runs} runs per target, median over targets), "
             "with the 0.5 % depth noise and with exact depth:",
             "", "| stage | ms, 0.5 % depth noise | ms, exact depth |", "|---|---:|---:|"]
    lines += [f"| {s} | {sp[s]:.1f} | {sp0[s]:.1f} |" for s in STAGES]
    lines += [f"| **total** | **{sp['total']:.1f}** | **{sp0['total']:.1f}** |", ""]
    for label, st in (("0.5 % depth noise", stats), ("exact depth", stats0)):
        lines.append(f"Per target, {label}: " + "; ".join(f"{s['visible_coarse']} coarse cells, {s['tiles']} tiles, "
                                                           f"{s['triangles']} triangles drawn" for s in st) + ".")
    lines += ["", f"Quality at {qsize[0]}x{qsize[1]} (PSNR dB, mean over the 3 targets; edge = pixels within 3 px "
              "of a reference depth discontinuity that both versions cover):", "",
              "| max_angle | filtered, edge | unfiltered, edge | gain | filtered, all | unfiltered, all | coverage |",
              "|---:|---:|---:|---:|---:|---:|---:|"]
    for ang, acc in qrows:
        fe, ue = np.mean(acc["f_edge"]), np.mean(acc["u_edge"])
        mark = " (default)" if ang == default_angle else ""
        lines.append(f"| {ang:g}{mark} | {fe:.2f} | {ue:.2f} | {fe - ue:+.2f} | {np.mean(acc['f_all']):.2f} | "
                     f"{np.mean(acc['u_all']):.2f} | {np.mean(acc['cov']):.3f} |")
    d = dict(qrows)[default_angle]
    gain = np.mean(d["f_edge"]) - np.mean(d["u_edge"])
    lines += ["", f"Target \"filtered beats unfiltered near occlusion edges\" (defaults): "
              f"{'met' if gain > 0 else 'missed'} ({gain:+.2f} dB; per target "
              + ", ".join(f"{f - u:+.2f}" for f, u in zip(d['f_edge'], d['u_edge'])) + ").", "", load_note()]
    text = "\n".join(lines)
    print(text)
    if a.write_docs:
        write_section("pvm_render", text, DOCS.with_name("benchmarks_hybrid.md"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
