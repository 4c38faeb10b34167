"""Soft shadows from warped shadow maps vs Embree (Lee et al. 2018 sec. 6, Table 8).

    python benchmarks/bench_shadows.py [--scenes crowd,city] [--samples 4,16,64,256]
                                       [--resolutions 512,1024] [--view 960x540] [--layers 3]
                                       [--seeds 4] [--repeats 1] [--write-docs]

For each synthetic scene, a rectangular area light above the scene and one view (the first
camera of the scene's path, its reference depth gives the surface points), the visibility image
(fraction of the S light samples each pixel sees; ``ibrtools.depthwarp.shadows.soft_shadows``) by

* **warp** (the paper's): one L-layer deep depth buffer at the light's centre (depth peeling, the
  last layer the ground alone; L = --layers = 3 and N = --seeds = 4 as in the paper's sec. 6),
  warped to each of the S samples (``ibrtools.depthwarp.core.warp_depth``), then the shadow-map test;
* **render**: the S shadow maps rendered by the Embree reference renderer (the paper's "reference
  geometry rendering"), then the same shadow-map test;
* **trace**: one Embree occlusion ray per pixel and sample (exact visibility of the same samples).

Quality: PSNR (data range 1) and SSIM of the visibility image of warp against render (same shadow
maps, the paper's comparison) and of warp and render against trace, over the surface pixels that
face the light's centre (on back faces a traced ray is blocked by the surface itself while a shadow
map seen edge-on is not; shading by max(0, N.L) makes visibility there irrelevant). Times: wall ms of the whole
call (median of --repeats), with the warp's split (layers / maps / shade). With --write-docs,
replaces the "bench_shadows" section of docs/benchmarks_depthwarp.md.
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from benchlib import DOCS, load_note, machine, write_section

from ibrtools import synth
from ibrtools.camera import Camera
from ibrtools.metrics import psnr, ssim
from ibrtools.raycast.reference import ReferenceRenderer
from ibrtools.depthwarp.shadows import AreaLight, soft_shadows

PATHS = {"crowd": "orbit", "city": "street", "objects": "orbit"}


def scene_setup(preset: str, view_size: tuple[int, int]):
    mesh, built = synth.build_mesh(preset, size=view_size)
    view = built.paths[PATHS[preset]][0]
    if preset == "city":
        # Over the street 25 m ahead of the first camera, 45 m up, a 4 x 4 m light.
        c = view.centre
        target = np.array([c[0], 0.0, c[2] + 25.0])
        light = AreaLight(target + [12.0, 45.0, 0.0], target, (4.0, 4.0), up=(0, 0, 1), fov_deg=110.0)
    else:
        # Above the centre of the crowd / objects, a 2 x 2 m light 15 m up; 80 deg covers the crowd's
        # 12 m radius from there (the map's texels spent on what casts and receives shadows).
        light = AreaLight((3.0, 15.0, 0.0), (0.0, 0.0, 0.0), (2.0, 2.0), up=(0, 0, 1), fov_deg=80.0)
    return mesh, view, light


def run(scenes, samples, resolutions, view_size, layers, seeds, repeats) -> str:
    from ibrtools.depthwarp.core import DepthWarpParams

    lines = [
        "## Soft shadows: warped vs rendered shadow maps vs traced (bench_shadows)",
        "",
        f"`python benchmarks/bench_shadows.py --scenes {','.join(scenes)} --samples {','.join(map(str, samples))} "
        f"--resolutions {','.join(map(str, resolutions))} --view {view_size[0]}x{view_size[1]} --layers {layers} "
        f"--seeds {seeds} --repeats {repeats}` on {machine()}. Visibility image of one {view_size[0]}x{view_size[1]} "
        "view (fraction of the S light samples seen); warp = L-layer deep depth at the light centre (last layer "
        f"ground only) warped to each sample (N = {seeds}); render = the S shadow maps rendered by Embree; trace = "
        "Embree occlusion rays (exact). PSNR in dB (range 1) / SSIM over surface pixels facing the light. Times: wall ms per visibility image (median of "
        f"{repeats}); speed-up = render / warp (the paper's Table 8 ratio), and trace / warp.",
        "",
        "| scene | SM res | S | warp ms (layers + maps + shade) | render ms | trace ms | speed-up vs render "
        "| vs trace | warp vs render PSNR / SSIM | warp vs trace | render vs trace | warp holes (incl. empty) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for preset in scenes:
        mesh, view, light = scene_setup(preset, view_size)
        ref = ReferenceRenderer(mesh)
        buf = ref.render(view, outputs=("depth", "normal"), lights=[])
        depth = buf["depth"]
        # Quality over surface pixels that face the light's centre: on back faces ray tracing is dark
        # by self-occlusion while a shadow map seen edge-on is not, and shading by max(0, N.L) makes
        # the visibility there irrelevant.
        c = view.cam_from_world
        v, u = np.mgrid[0:view.height, 0:view.width] + 0.5
        p_cam = np.stack([(u - view.cx) / view.fx * depth, (v - view.cy) / view.fy * depth, depth], -1)
        p_world = (p_cam - c[:3, 3]) @ c[:3, :3]
        facing = np.einsum("hwc,hwc->hw", buf["normal"], light.center - p_world) > 0
        ground = 0  # every preset's ground plane is object 0
        traced: dict[int, tuple] = {}
        for res in resolutions:
            for s in samples:
                out, times = {}, {}
                for method in ("warp", "render", "trace"):
                    if method == "trace" and s in traced:
                        out[method], times[method] = traced[s]  # no shadow map: the same for every SM res
                        continue
                    kw = dict(samples=s, resolution=res, method=method, layers=layers, ground_object=ground,
                              params=DepthWarpParams(seeds=seeds))
                    ts = []
                    for _ in range(repeats):
                        t0 = time.perf_counter()
                        r = soft_shadows(ref, light, view, depth, **kw)
                        ts.append((time.perf_counter() - t0) * 1e3)
                    out[method], times[method] = r, statistics.median(ts)
                    if method == "trace":
                        traced[s] = (r, times[method])
                w, rd, tr = (out[m].visibility for m in ("warp", "render", "trace"))
                mask = (depth > 0) & facing

                def q(a, b):
                    p = psnr(a, b, 1.0, mask)
                    return f"{'inf' if p == float('inf') else f'{p:.1f}'} / {ssim(a, b, 1.0, mask):.4f}"
                wt = out["warp"].times_ms
                lines.append(
                    f"| {preset} | {res} | {s} | {times['warp']:.0f} ({wt['layers']:.0f} + {wt['maps']:.0f} + "
                    f"{wt['shade']:.0f}) | {times['render']:.0f} | {times['trace']:.0f} | "
                    f"{times['render'] / times['warp']:.2f}x | {times['trace'] / times['warp']:.2f}x | {q(w, rd)} | "
                    f"{q(w, tr)} | {q(rd, tr)} | {100 * out['warp'].stats['hole_fraction']:.2f} % |")
                print(lines[-1], flush=True)
    lines += ["", load_note()]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="crowd,city")
    ap.add_argument("--samples", default="4,16,64,256")
    ap.add_argument("--resolutions", default="512,1024")
    ap.add_argument("--view", default="960x540", help="view size WxH (default 960x540)")
    ap.add_argument("--layers", type=int, default=3, help="deep depth layers L at the light (paper: 3)")
    ap.add_argument("--seeds", type=int, default=4, help="warp seeds N (paper: 4)")
    ap.add_argument("--repeats", type=int, default=1, help="timed runs per case (median)")
    ap.add_argument("--write-docs", action="store_true", help="update docs/benchmarks_depthwarp.md")
    a = ap.parse_args()
    scenes = [s for s in a.scenes.split(",") if s]
    for s in scenes:
        if s not in PATHS:
            ap.error(f"--scenes: unknown scene {s!r} (choose from {', '.join(PATHS)})")
    try:
        samples = [int(x) for x in a.samples.split(",")]
        resolutions = [int(x) for x in a.resolutions.split(",")]
        vw, vh = (int(x) for x in a.view.lower().split("x"))
    except ValueError:
        ap.error("--samples, --resolutions: comma-separated integers; --view: WxH")
    if min(samples) < 1 or min(resolutions) < 8 or a.layers < 2 or a.repeats < 1:
        ap.error("--samples >= 1, --resolutions >= 8, --layers >= 2 (the last is the ground), --repeats >= 1")
    section = run(scenes, samples, resolutions, (vw, vh), a.layers, a.seeds, a.repeats)
    print(section)
    if a.write_docs:
        write_section("bench_shadows", section, DOCS.with_name("benchmarks_depthwarp.md"))
        print(f"\nwrote {DOCS.with_name('benchmarks_depthwarp.md')}")


if __name__ == "__main__":
    main()
