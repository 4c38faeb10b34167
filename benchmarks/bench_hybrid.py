"""Hybrid IBR rendering: quality of TM, ULR, PVM (filtered), unfiltered PVM and hybrid on
held-out targets of a degraded synthetic scene, and speed at 1280x720 with a per-stage table
(the paper's Table 2).

    python benchmarks/bench_hybrid.py [--size 640x480] [--views 16] [--targets 4] [--depth-noise 0.01]
        [--exposure-jitter 0.1] [--speed-size 1280x720] [--repeats 3] [-j N] [--write-docs]

Scene: ``synth:objects`` (diffuse and glossy objects on a textured ground) made with
``reconstructed=True`` (the global mesh is the degraded reconstruction: decimated, displaced,
with a missing object; docs/synth.md), multiplicative depth noise on the input depth maps
(which the PVMs are built from), per-view exposure jitter (which harmonisation removes) and
``--targets`` held-out target cameras between the inputs that no preprocessing stage reads. The
scene is preprocessed from scratch in a temporary directory for ``--methods tm,ulr,pvm,hybrid``
(timed, reported). Quality: each method renders every target at the input resolution; metrics
(``ibrtools.metrics.compare``: PSNR and SSIM on sRGB, FLIP) over the whole frame, holes black,
averaged over the targets. PVM alone is ``PvmRenderer.render`` with the global mesh's G-buffer
depth (its holes: pixels without candidates). Speed: the targets' cameras scaled to
``--speed-size``, median over ``--repeats`` x targets of each method's render call, and the hybrid
method's own per-stage times (G-buffer, TM shade, the PVM stages, masking, ULR blend, composite).
With --write-docs, replaces the "Hybrid rendering" section of docs/benchmarks_hybrid.md.
"""
from __future__ import annotations

import argparse
import shlex
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchlib import DOCS, load_note, machine, write_section

TARGETS_MS = {"tm": 20.0, "ulr": 80.0, "hybrid": 250.0}


EDGE_PX = 3


def depth_edges(depth) -> np.ndarray:
    """Pixels within EDGE_PX of a relative depth step > 5 % (or a hit / miss boundary)."""
    from scipy.ndimage import binary_dilation

    d = np.nan_to_num(np.asarray(depth, np.float64), nan=0.0, posinf=0.0)
    e = np.zeros(d.shape, bool)
    for a, b, sl_a, sl_b in ((d[:, 1:], d[:, :-1], (slice(None), slice(1, None)), (slice(None), slice(None, -1))),
                             (d[1:], d[:-1], (slice(1, None), slice(None)), (slice(None, -1), slice(None)))):
        step = (np.abs(a - b) > 0.05 * np.maximum(np.minimum(a, b), 1e-9)) | ((a > 0) != (b > 0))
        e[sl_a] |= step
        e[sl_b] |= step
    return binary_dilation(e, iterations=EDGE_PX) if e.any() else e


def frame_color(out: dict) -> np.ndarray:
    """A method's output colour as it is scored: float32, NaN -> 0, holes black."""
    color = np.nan_to_num(out["color"]).astype(np.float32)
    hole = out.get("hole")
    return color if hole is None else np.where(hole[..., None], 0.0, color).astype(np.float32)


def add_edge_error(acc: list, color, truth, edges) -> None:
    """acc = [squared error, count]: += the sRGB squared error of color against truth on the edge pixels."""
    if edges is not None and edges.any():
        d = srgb(color)[edges] - srgb(truth)[edges]
        acc[0] += float(np.sum(d.astype(np.float64) ** 2))
        acc[1] += int(d.size)


def edge_lines(edge_se: dict, edge_px: int, names: dict, what: str) -> list[str]:
    """The near-occlusion-edge table (pooled squared error -> PSNR per method) and the
    filtered-vs-unfiltered PVM sentence. what: whose true depth the edges come from."""
    edge_psnr = {n: (float("nan") if cnt == 0 else float("inf") if se <= 0 else 10 * np.log10(cnt / se))
                 for n, (se, cnt) in edge_se.items()}
    lines = ["", f"Near occlusion edges ({edge_px} pixels within {EDGE_PX} px of a depth step > 5 % in {what}; "
             "PSNR of the pooled squared error on sRGB):", "", "| method | edge PSNR dB |", "|---|---:|"]
    lines += [f"| {names[n]} | {edge_psnr[n]:.2f} |" for n in edge_se]
    if "pvm" in edge_psnr and "pvm_unfiltered" in edge_psnr:
        gain = edge_psnr["pvm"] - edge_psnr["pvm_unfiltered"]
        lines += ["", f"Filtered PVM {'beats' if gain > 0 else 'does not beat'} the unfiltered blend near occlusion "
                  f"edges ({gain:+.2f} dB)."]
    return lines


def srgb(img) -> np.ndarray:
    from ibrtools.imageio import linear_to_srgb

    return linear_to_srgb(np.asarray(img, np.float32))


def _size(text: str) -> tuple[int, int]:
    w, h = text.lower().split("x")
    return int(w), int(h)


def pvm_method(scene, filtered: bool):
    """PVM alone (filtered or not) for the comparison: ``--method pvm``, prepared (its G-buffer depth
    is the hybrid's, hybrid/pvm_method.py)."""
    from ibrtools import methods

    m = methods.create("pvm", {"filtered": filtered})
    m.prepare(scene)
    return m


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", default="640x480", help="WxH of the input views and quality targets (default 640x480)")
    p.add_argument("--views", type=int, default=16, help="input views (default 16)")
    p.add_argument("--targets", type=int, default=4, help="held-out targets (default 4)")
    p.add_argument("--depth-noise", type=float, default=0.01, help="multiplicative depth noise (default 0.01)")
    p.add_argument("--exposure-jitter", type=float, default=0.1, help="per-view exposure jitter (default 0.1)")
    p.add_argument("--speed-size", default="1280x720", help="WxH of the timed frames (default 1280x720)")
    p.add_argument("--repeats", type=int, default=3, help="timed renders per target and method (default 3)")
    p.add_argument("--max-edge-voxels", type=float, default=None,
                   help="mesh.max_edge_voxels of the mesh stage (the dense mesh of the per-vertex statistics; "
                        "default: the pipeline's, 1)")
    p.add_argument("-j", "--threads", type=int, default=0, help="engine threads (default: all cores)")
    p.add_argument("--write-docs", action="store_true", help="replace the section in benchmarks_hybrid.md")
    args = p.parse_args(argv)

    from ibrtools import _core
    from ibrtools.formats import native
    from ibrtools.metrics import compare
    from ibrtools import methods
    from ibrtools.pipeline.stages import preprocess

    if args.threads:
        _core.set_num_threads(args.threads)
    size, speed_size = _size(args.size), _size(args.speed_size)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "scene"
        synth = {"preset": "objects", "size": list(size), "views": args.views, "seed": 0, "reconstructed": True,
                 "holdout_targets": args.targets, "depth_noise": args.depth_noise,
                 "exposure_jitter": args.exposure_jitter}
        t0 = time.perf_counter()
        stage_options = {"mesh": {"max_edge_voxels": args.max_edge_voxels}} if args.max_edge_voxels else None
        rows = preprocess("synth:objects", root, synth=synth, methods=["tm", "ulr", "pvm", "hybrid"],
                          stage_options=stage_options)
        prep_s = time.perf_counter() - t0
        stage_s = {r.name: (r.status, r.seconds) for r in rows}
        details = {r.name: r.details for r in rows}
        print(f"preprocess {prep_s:.1f} s: " + ", ".join(f"{k} {v[0]} {v[1]:.1f}s" for k, v in stage_s.items()),
              file=sys.stderr)
        scene = native.load(root)
        targets = [t for t in scene.targets if t.has_color]
        renderers = {}
        for name in ("tm", "ulr", "hybrid"):
            m = methods.create(name)
            m.prepare(scene)
            renderers[name] = m
        renderers["pvm"] = pvm_method(scene, filtered=True)
        renderers["pvm_unfiltered"] = pvm_method(scene, filtered=False)
        order = ["tm", "ulr", "pvm", "pvm_unfiltered", "hybrid"]

        # ---- quality at the input resolution -----------------------------------------------
        quality = {n: {"psnr": [], "ssim": [], "flip": []} for n in order}
        # Near occlusion edges (the filtered-vs-unfiltered PVM target): pixels within EDGE_PX of a
        # depth discontinuity of the target's true depth (relative step > 5 %); squared error on
        # sRGB pooled over the targets' edge pixels.
        edge_se = {n: [0.0, 0] for n in order}
        edge_px = 0
        selection = []
        for t in targets:
            edges = depth_edges(t.depth) if t.has_depth else None
            edge_px += 0 if edges is None else int(edges.sum())
            for n in order:
                out, _ = renderers[n].render(t.camera)
                color = frame_color(out)
                m = compare(color, t.color)
                for k in quality[n]:
                    quality[n][k].append(float(m[k]))
                add_edge_error(edge_se[n], color, t.color, edges)
                if n == "hybrid":
                    selection.append(renderers[n].frame_report()["selection"])
        mean = {n: {k: float(np.mean(v)) for k, v in quality[n].items()} for n in order}

        # ---- speed at --speed-size ------------------------------------------------------------
        # Wall time and the process's CPU time (all threads) per frame: under load the wall time
        # is inflated by waiting for a core, the CPU time much less; CPU / threads is the wall time
        # a quiet machine would give if the frame parallelised perfectly (a lower bound).
        speed = {n: [] for n in order}
        cpu = {n: [] for n in order}
        stages: dict[str, list] = {}
        for t in targets:
            cam = t.camera.scaled(*speed_size)
            for n in order:
                renderers[n].render(cam)  # warm-up (first touch of the buffers of this size)
                for _ in range(args.repeats):
                    t1, c1 = time.perf_counter(), time.process_time()
                    _, st = renderers[n].render(cam)
                    speed[n].append((time.perf_counter() - t1) * 1e3)
                    cpu[n].append((time.process_time() - c1) * 1e3)
                    if n == "hybrid":
                        for k, v in st.items():
                            stages.setdefault(k, []).append(v)
        med = {n: statistics.median(v) for n, v in speed.items()}
        med_cpu = {n: statistics.median(v) for n, v in cpu.items()}

    names = {"tm": "TM (textured mesh)", "ulr": "ULR (per-pixel)", "pvm": "PVM (clustered, filtered)",
             "pvm_unfiltered": "PVM unfiltered (PVM-H-like)", "hybrid": "hybrid"}
    cmd = shlex.join(["python", "benchmarks/bench_hybrid.py", *(sys.argv[1:] if argv is None else argv)])
    lines = [f"Hybrid IBR rendering (`{cmd}`), {machine()}, "
             f"{_core.get_num_threads()} threads. Scene: synth:objects, {args.views} input views of "
             f"{size[0]}x{size[1]}, reconstructed (degraded) global mesh (mesh.max_edge_voxels "
             f"{args.max_edge_voxels or 'default'}; {details.get('mesh', {}).get('render_faces', '?')} render-mesh faces, "
             f"atlas {details.get('texture', {}).get('atlas', '?')}), depth noise {args.depth_noise}, "
             f"exposure jitter {args.exposure_jitter}, glossy objects; {len(targets)} held-out targets no "
             f"stage reads. Preprocessing (tm, ulr, pvm, hybrid) took {prep_s:.1f} s "
             f"({', '.join(f'{k} {v[1]:.1f} s' + ('' if v[0] == 'ran' else f' {v[0]}') for k, v in stage_s.items())}).",
             "", f"Quality at {size[0]}x{size[1]} (mean over the targets; whole frame, holes black):", "",
             "| method | PSNR dB | SSIM | FLIP |", "|---|---:|---:|---:|"]
    for n in order:
        lines.append(f"| {names[n]} | {mean[n]['psnr']:.2f} | {mean[n]['ssim']:.4f} | {mean[n]['flip']:.4f} |")
    lines += edge_lines(edge_se, edge_px, names, "the targets' true depth")
    beats = [n for n in ("tm", "ulr", "pvm") if mean["hybrid"]["psnr"] > mean[n]["psnr"]]
    beats_ssim = [n for n in ("tm", "ulr", "pvm") if mean["hybrid"]["ssim"] > mean[n]["ssim"]]
    beats_flip = [n for n in ("tm", "ulr", "pvm") if mean["hybrid"]["flip"] < mean[n]["flip"]]
    sel = {k: float(np.mean([s[k] for s in selection])) for k in selection[0]} if selection else {}
    lines += ["", f"Hybrid beats on mean PSNR: {', '.join(beats) or 'none'}; on mean SSIM: "
              f"{', '.join(beats_ssim) or 'none'}; on mean FLIP (lower): {', '.join(beats_flip) or 'none'} "
              "(target: tm, ulr and pvm in PSNR and SSIM). "
              f"Mean selection: " + ", ".join(f"{k} {100 * v:.1f} %" for k, v in sel.items()) + ".",
              "", f"Speed at {speed_size[0]}x{speed_size[1]} (median of {args.repeats} x {len(targets)} frames, "
              "whole render call; CPU = the process's CPU time, all threads):", "",
              "| method | ms per frame | CPU ms per frame | target |", "|---|---:|---:|---|"]
    for n in order:
        tgt = TARGETS_MS.get(n)
        verdict = "" if tgt is None else f"<= {tgt:.0f} ms: {'met' if med[n] <= tgt else 'missed'}"
        lines.append(f"| {names[n]} | {med[n]:.1f} | {med_cpu[n]:.1f} | {verdict} |")
    lines += ["", "Hybrid per stage (Table 2 analogue; median ms):", "", "| stage | ms |", "|---|---:|"]
    for k, v in stages.items():
        lines.append(f"| {k} | {statistics.median(v):.2f} |")
    lines += ["", load_note()]
    text = "\n".join(lines)
    print(text)
    if args.write_docs:
        write_section("Hybrid rendering", text, DOCS.with_name("benchmarks_hybrid.md"))
        print(f"wrote the 'Hybrid rendering' section of {DOCS.with_name('benchmarks_hybrid.md')}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
