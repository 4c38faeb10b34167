"""Solvers against peers: grid max-flow vs PyMaxflow, Poisson vs pyamg and OpenCV seamlessClone.

    python benchmarks/bench_solvers.py [--size 1000] [--repeats 5] [--write-docs]

* Max-flow: a --size^2 4-connected grid (1M pixels by default), two energies: a noisy binary
  segmentation with a Potts prior (the vision case: long paths, many orphans) and i.i.d. random
  capacities; int64 capacities, so the two must give the *same* maximum flow exactly, and the
  energy of our labelling is recomputed from the labels. PyMaxflow is timed with and without
  building its graph (ibrtools builds its compact grid inside the call).
* Poisson: Pérez et al. seamless cloning of one channel on a --size^2 region (1M unknowns by
  default, an image 6 pixels larger with the mask 3 pixels in from the border), to a 1e-6 relative
  residual ||b - A x|| / ||b||; pyamg (Ruge-Stüben and smoothed aggregation, setup + solve,
  accel="cg") solves the same scipy-assembled system from the same initial guess to the same
  tolerance, and every residual is recomputed with scipy from the returned solution.
* OpenCV seamlessClone (NORMAL_CLONE, 512^2 RGB uint8, elliptic mask) is the speed reference for
  the blending use; ibrtools' poisson_blend on the same float32 RGB images and mask.

Median of --repeats (>= 5) timed runs after a warm-up. With --write-docs, replaces the "Solvers"
section of docs/benchmarks_hybrid.md.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import DOCS, machine, median_ms, write_section  # noqa: E402

from ibrtools import _core  # noqa: E402
from ibrtools.solvers import grid_maxflow, poisson_blend, poisson_system  # noqa: E402

RIGHT = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0]])
DOWN = np.array([[0, 0, 0], [0, 0, 0], [0, 1, 0]])


def energy(s, t, r, d, L) -> int:
    return int((s * L).sum() + (t * ~L).sum() + (r[:, :-1] * (L[:, :-1] != L[:, 1:])).sum()
               + (d[:-1] * (L[:-1] != L[1:])).sum())


def maxflow_energies(n: int) -> dict[str, tuple[np.ndarray, ...]]:
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:n, 0:n]
    clean = (np.sin(xx / 60.0) * np.cos(yy / 45.0)) > 0.1
    img = clean + rng.normal(0, 0.8, (n, n))
    seg = (np.round(100 * img ** 2).astype(np.int64), np.round(100 * (img - 1) ** 2).astype(np.int64),
           np.full((n, n), 60, np.int64), np.full((n, n), 60, np.int64))
    rnd = tuple(rng.integers(0, k, (n, n)).astype(np.int64) for k in (100, 100, 40, 40))
    return {"segmentation (Potts 60, noisy data)": seg, "random capacities": rnd}


def bench_maxflow(n: int, repeats: int) -> list[str]:
    import maxflow

    def pm_build(s, t, r, d):
        g = maxflow.Graph[int]()
        ids = g.add_grid_nodes((n, n))
        g.add_grid_edges(ids, weights=r, structure=RIGHT, symmetric=True)
        g.add_grid_edges(ids, weights=d, structure=DOWN, symmetric=True)
        g.add_grid_tedges(ids, s, t)
        return g, ids

    lines = [f"### Max-flow, {n}x{n} 4-connected grid ({n * n / 1e6:.2f} M pixels, int64 capacities)", "",
             "| energy | ibrtools (ms) | PyMaxflow flow only (ms) | PyMaxflow build + flow (ms) | speed-up (flow only) "
             "| same flow | cut energy = flow |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, (s, t, r, d) in maxflow_energies(n).items():
        ours_ms = median_ms(lambda: grid_maxflow(s, t, r, d), repeats)
        flow, side = grid_maxflow(s, t, r, d)
        flow_only, total = [], []
        for _ in range(repeats + 1):
            t0 = time.perf_counter()
            g, ids = pm_build(s, t, r, d)
            t1 = time.perf_counter()
            ref_flow = g.maxflow()
            t2 = time.perf_counter()
            flow_only.append((t2 - t1) * 1e3)
            total.append((t2 - t0) * 1e3)
        pm_flow, pm_total = float(np.median(flow_only[1:])), float(np.median(total[1:]))
        lines.append(f"| {name} | {ours_ms:.0f} | {pm_flow:.0f} | {pm_total:.0f} | {pm_flow / ours_ms:.2f}x | "
                     f"{'yes' if flow == ref_flow else f'NO ({flow} vs {ref_flow})'} | "
                     f"{'yes' if energy(s, t, r, d, side) == flow else 'NO'} |")
    return lines


def test_images(n: int, channels: int = 0):
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[0:n, 0:n] / n
    shape = (n, n) if channels == 0 else (n, n, channels)
    tint = 1.0 if channels == 0 else np.array([1.0, 0.8, 0.6])[:channels]
    base = (0.5 + 0.3 * np.sin(13 * xx) * np.cos(9 * yy))
    source = (base[..., None] * tint if channels else base) + 0.05 * rng.random(shape)
    boundary = (0.3 + 0.4 * yy)[..., None] * tint[::-1] if channels else 0.3 + 0.4 * yy
    boundary = boundary + 0.05 * rng.random(shape)
    return boundary.astype(np.float32), source.astype(np.float32)


def bench_poisson(n: int, repeats: int) -> list[str]:
    import pyamg

    H = W = n + 6
    boundary, source = test_images(H)
    mask = np.zeros((H, W), bool)
    mask[3:-3, 3:-3] = True
    tol = 1e-6
    ours_ms = median_ms(lambda: poisson_blend(boundary, source, mask, tol=tol), repeats)
    out, info = poisson_blend(boundary, source, mask, tol=tol)
    A, b = poisson_system(boundary, source, mask)
    x0 = source[mask].astype(np.float64)

    def rel(x):
        return float(np.linalg.norm(b - A @ x) / np.linalg.norm(b))

    # ibrtools' residual is its own float64 one (its output is rounded to float32, whose residual
    # is rounding-limited); the peers' is recomputed here from their float64 solutions.
    lines = [f"### Poisson blending, {mask.sum() / 1e6:.2f} M unknowns (one channel, {H}x{W} image), "
             f"relative residual {tol:g}", "",
             "| solver | setup (ms) | solve (ms) | total (ms) | iterations | relative residual | ibrtools faster by |",
             "|---|---:|---:|---:|---:|---:|---:|",
             f"| ibrtools poisson_blend (MG-PCG, {_core.get_num_threads()} threads) | - | - | {ours_ms:.0f} | "
             f"{info['iterations']} | {info['relative_residual']:.2e} | ref. |"]
    for name, make in (("pyamg ruge_stuben_solver", pyamg.ruge_stuben_solver),
                       ("pyamg smoothed_aggregation_solver", pyamg.smoothed_aggregation_solver)):
        setups, solves = [], []
        for _ in range(repeats + 1):
            t0 = time.perf_counter()
            ml = make(A)
            t1 = time.perf_counter()
            res: list[float] = []
            x = ml.solve(b, x0=x0, tol=tol, accel="cg", residuals=res)
            t2 = time.perf_counter()
            setups.append((t1 - t0) * 1e3)
            solves.append((t2 - t1) * 1e3)
        su, so = float(np.median(setups[1:])), float(np.median(solves[1:]))
        lines.append(f"| {name} (accel cg) | {su:.0f} | {so:.0f} | {su + so:.0f} | {len(res) - 1} | {rel(x):.2e} | "
                     f"{(su + so) / ours_ms:.1f}x |")
    return lines + [""]


def bench_seamless(repeats: int) -> list[str]:
    import cv2

    n = 512
    boundary, source = test_images(n, 3)
    yy, xx = np.mgrid[0:n, 0:n]
    mask = ((yy - n / 2) ** 2 / (0.42 * n) ** 2 + (xx - n / 2) ** 2 / (0.45 * n) ** 2) < 1
    src8 = np.clip(source * 255, 0, 255).astype(np.uint8)
    dst8 = np.clip(boundary * 255, 0, 255).astype(np.uint8)
    mask8 = (mask * 255).astype(np.uint8)
    center = (n // 2, n // 2)
    cv_ms = median_ms(lambda: cv2.seamlessClone(src8, dst8, mask8, center, cv2.NORMAL_CLONE), repeats)
    ours_ms = median_ms(lambda: poisson_blend(boundary, source, mask, tol=1e-6), repeats)
    ours3_ms = median_ms(lambda: poisson_blend(boundary, source, mask, tol=1e-3), repeats)
    _, info = poisson_blend(boundary, source, mask, tol=1e-6)
    _, info3 = poisson_blend(boundary, source, mask, tol=1e-3)
    return [f"### Blending speed reference, {n}x{n} RGB, elliptic mask ({mask.sum() / 1e3:.0f} k pixels)", "",
            "| implementation | time (ms) | note |", "|---|---:|---|",
            f"| OpenCV seamlessClone NORMAL_CLONE (uint8) | {cv_ms:.1f} | OpenCV's own solver and uint8 rounding |",
            f"| ibrtools poisson_blend, tol 1e-6 (float32) | {ours_ms:.1f} | {info['iterations']} PCG iterations per "
            "channel |",
            f"| ibrtools poisson_blend, tol 1e-3 (float32) | {ours3_ms:.1f} | {info3['iterations']} iterations: "
            "below 8-bit visibility |", ""]


def run(size: int, repeats: int) -> str:
    load0 = os.getloadavg()[0]
    lines = ["## Solvers (bench_solvers.py)", "",
             f"Machine: {machine()}; ibrtools threads: {_core.get_num_threads()} (max-flow is single-threaded). "
             f"Median of {repeats} runs after a warm-up. Command: `python benchmarks/bench_solvers.py --size {size} "
             f"--repeats {repeats} --write-docs`.", ""]
    lines += bench_maxflow(size, repeats) + [""]
    lines += bench_poisson(size, repeats)
    lines += bench_seamless(repeats)
    lines.append(f"1-minute load average at the start / end of the run: {load0:.2f} / {os.getloadavg()[0]:.2f} "
                 "(other work slows every row alike; read the ratios).")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=1000, help="grid / region side (default 1000: 1M pixels)")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs per case, >= 5 (median)")
    ap.add_argument("--write-docs", action="store_true", help="update docs/benchmarks_hybrid.md")
    a = ap.parse_args()
    if a.repeats < 5 or a.size < 16:
        ap.error("--repeats must be >= 5 and --size >= 16")
    section = run(a.size, a.repeats)
    print(section)
    if a.write_docs:
        write_section("bench_solvers", section, DOCS.with_name("benchmarks_hybrid.md"))
        print(f"\nwrote {DOCS.with_name('benchmarks_hybrid.md')}")


if __name__ == "__main__":
    main()
