"""Interleaved A/B of the DIBR kernels (forward warp + streaming blend) without Python in the loop.

    python benchmarks/dibr_ab.py [--base REV] [--rounds 5] [--repeats 5] [--threads 1] [--views 4]
                                 [--size 1920x1080] [--plain] [--srgb | --srgb-b]

Builds benchmarks/dibr_ab/dibr_ab.cpp twice with the release flags of the engine (g++ -O3, no
-march): once against cpp/kernels/dibr/{forward_warp,blend}.{h,cpp} and cpp/ibr/colour.{h,cpp} of git revision --base (default
HEAD), once against the working tree, and runs them alternately --rounds times on the scene of
benchmarks/bench_dibr.py (``synth.make_scene("objects", views=8)``, target half-way between two
ring cameras, the --views nearest inputs). Each run prints the minimum over --repeats of the
process CPU time and the wall time of ClearBlend + views x ForwardWarp (accumulating) +
ResolveBlend with the options of ``--method dibr``, and a hash of the outputs: the two builds must
print the same hash (bit-identical results). On a shared machine compare the CPU times (the wall
time of one thread is what the load leaves of a core); the script reports the minimum and median
over the rounds, the median CPU / wall ratio (≈ the thread count when both threads ran all the time) and
the load average at the start and the end. Needs g++ and TBB's headers (the engine's build dependencies).
--srgb runs both sides in the blend space "srgb" of ``--method dibr`` (inputs sRGB-encoded before the timing,
as the renderer caches them; the result decoded: inside ResolveBlend where the kernels have it, else by a
separate SrgbToLinear pass, timed: the hashes of the two forms differ, the resolve's decoding reads the
curve from a table, cpp/kernels/dibr/blend.h); --srgb-b only the B side (the cost of srgb against linear; the
hashes then differ by design). The sRGB curve is cpp/ibr/colour.{h,cpp}, taken from the same revision.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from ibrtools import synth

ROOT = Path(__file__).resolve().parents[1]
# The A side's files, under cpp/ of revision --base (the family layout: kernels/dibr/, the sRGB curve in ibr/).
KERNEL_FILES = ("kernels/dibr/forward_warp.h", "kernels/dibr/forward_warp.cpp", "kernels/dibr/blend.h",
                "kernels/dibr/blend.cpp", "ibr/colour.h", "ibr/colour.cpp")


def dump_scene(out: Path, size: tuple[int, int], k: int) -> None:
    sc = synth.make_scene("objects", size=size, views=8, holdout_targets=1)
    tgt = sc.targets[0]
    c0 = tgt.camera.centre
    views = sorted(sc.views, key=lambda v: float(np.linalg.norm(v.camera.centre - c0)))[:k]
    lines = []
    for i, v in enumerate(views + [tgt]):
        c = v.camera
        nums = [c.width, c.height, c.fx, c.fy, c.cx, c.cy] + list(np.asarray(c.cam_from_world)[:3, :4].ravel())
        lines.append(" ".join(repr(float(x)) for x in nums))
        if i < k:
            np.ascontiguousarray(v.color, np.float32).tofile(out / f"c{i}.raw")
            np.ascontiguousarray(v.depth, np.float32).tofile(out / f"d{i}.raw")
    (out / "cams.txt").write_text("\n".join(lines) + "\n")


def build(kernels: Path, exe: Path) -> None:
    """kernels: a directory holding KERNEL_FILES (as under cpp/); the rest of the engine from the tree."""
    cmd = ["g++", "-std=c++17", "-O3", "-DGLM_FORCE_XYZW_ONLY", f"-I{kernels}", f"-I{ROOT / 'cpp'}",
           "-o", str(exe), str(ROOT / "benchmarks" / "dibr_ab" / "dibr_ab.cpp"),
           *[str(kernels / f) for f in KERNEL_FILES if f.endswith(".cpp")],
           str(ROOT / "cpp" / "ibr" / "parallel.cpp"), str(ROOT / "cpp" / "ibr" / "simd.cpp"), "-ltbb", "-lpthread"]
    subprocess.run(cmd, check=True)


def run(exe: Path, data: Path, threads: int, repeats: int, views: int, plain: bool = False, srgb: bool = False) -> dict:
    cmd = [str(exe), str(data), str(threads), str(repeats), str(views)] + (["plain"] if plain else []) + \
        (["srgb"] if srgb else [])
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.split()
    r = dict(zip(out[::2], out[1::2]))
    return {"cpu": float(r["cpu_ms"]), "wall": float(r["wall_ms"]), "resolve": float(r["resolve_ms"]), "hash": r["hash"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", default="HEAD", help="git revision of the A side (B = working tree)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--plain", action="store_true",
                    help="blend without the visibility rules (bench_dibr.py's DibrAccumulator() defaults) instead of "
                         "--method dibr's stretched_quality 0.1 + stretched_holes")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--srgb", action="store_true", help="both sides in the blend space srgb (see the module doc)")
    g.add_argument("--srgb-b", action="store_true", help="only the B side (working tree) in the blend space srgb")
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.lower().split("x"))
    with tempfile.TemporaryDirectory(prefix="dibr_ab_") as tmp:
        tmp = Path(tmp)
        data = tmp / "data"
        data.mkdir()
        dump_scene(data, (w, h), a.views)
        base = tmp / "base"
        for f in KERNEL_FILES:
            got = subprocess.run(["git", "-C", str(ROOT), "show", f"{a.base}:cpp/{f}"], capture_output=True,
                                 check=False)
            if got.returncode != 0:
                raise SystemExit(f"git show {a.base}:cpp/{f} failed (a revision older than the family layout of "
                                 f"cpp/kernels/ is not supported): {got.stderr.decode().strip()}")
            (base / f).parent.mkdir(parents=True, exist_ok=True)
            (base / f).write_bytes(got.stdout)
        exes = {"A (" + a.base + ")": tmp / "a.bin", "B (working tree)": tmp / "b.bin"}
        build(base, exes["A (" + a.base + ")"])
        build(ROOT / "cpp", exes["B (working tree)"])
        res: dict[str, list[dict]] = {k: [] for k in exes}
        print(f"1-minute load average at the start: {os.getloadavg()[0]:.2f}", flush=True)
        for r in range(a.rounds):
            for name, exe in exes.items():
                srgb = a.srgb or (a.srgb_b and name.startswith("B"))
                res[name].append(run(exe, data, a.threads, a.repeats, a.views, a.plain, srgb))
                x = res[name][-1]
                print(f"round {r}: {name}: cpu {x['cpu']:.1f} ms, wall {x['wall']:.1f} ms, resolve wall "
                      f"{x['resolve']:.2f} ms, hash {x['hash']}", flush=True)
        for name, rs in res.items():
            cpu = [x["cpu"] for x in rs]
            wall = [x["wall"] for x in rs]
            ratio = statistics.median(c / w for c, w in zip(cpu, wall))
            res_w = [x["resolve"] for x in rs]
            print(f"{name}: cpu min {min(cpu):.1f} median {statistics.median(cpu):.1f} ms; "
                  f"wall min {min(wall):.1f} median {statistics.median(wall):.1f} ms; cpu / wall median {ratio:.2f} "
                  f"(≈ threads when the machine is free); resolve wall min {min(res_w):.2f} median "
                  f"{statistics.median(res_w):.2f} ms")
        print(f"1-minute load average at the end: {os.getloadavg()[0]:.2f}")
        hashes = {x["hash"] for rs in res.values() for x in rs}
        if a.srgb_b:
            print("outputs differ by design (--srgb-b)" if len(hashes) == 2 else f"hashes: {sorted(hashes)}")
        else:
            print("outputs identical" if len(hashes) == 1 else f"OUTPUTS DIFFER: {sorted(hashes)}")


if __name__ == "__main__":
    main()
