"""Hybrid IBR quality on held-out NeRF-synthetic lego views: TM, ULR,
PVM (filtered), an unfiltered PVM blend and hybrid, the global mesh made by TSDF fusion of the
input views' depth maps.

    python benchmarks/bench_hybrid_lego.py [--scale 1] [-j N] [--keep DIR] [--validation]
        [--depth-dequantize N] [--methods tm,ulr,...] [--options JSON] [--hybrid-params JSON]
        [--reuse] [--speed-repeats 5] [--write-docs]

Protocol (the DIBR lego protocol of benchmarks/bench_dibr_accuracy.py): the nerf importer on
../shared/data/nerf_lego (or $IBR_SHARED_DATA/nerf_lego), RGBA composited over black; the held-out
views are LEGO_HELDOUT (r_0 r_50 r_100 r_150). They are removed from the scene's input views
BEFORE preprocessing and stored as the scene's targets (ground truth no stage reads): the fusion
(mesh), texture, variance, harmonise and PVM stages and the ULR / PVM blends see only the other
36 views, so no ground truth leaks. No parameter is tuned: every stage and method runs with its
defaults (``--methods tm,ulr,pvm,hybrid``; the mesh stage's source is "auto" = fusion, since the
data set has no mesh).

Validation protocol (``--validation``, for choosing anything; never with --write-docs): the
targets are LEGO_VALIDATION (r_10 r_60 r_110 r_160), removed from the inputs together with the
held-out views (32 inputs), so nothing chosen on it has seen r_0 r_50 r_100 r_150.
Further held-out folds (``--fold K``, K = 1, 3 ... 9; never for choosing, never with --write-docs):
the 40 views as 10 folds of 4 views 50 apart (fold 0 = the held-out views, fold 2 = validation);
fold K's views r_5K r_5K+50 r_5K+100 r_5K+150 are the targets and are removed from the inputs (36
inputs, as in the held-out protocol): how far a result on the held-out views carries over.
``--json PATH`` writes the per-view and mean scores. ``--depth-dequantize N`` passes the nerf
importer's option (bin-constrained smoothing of the 8-bit depth codes; default: the importer's default). ``--options JSON`` passes stage options to
``run_stages`` (e.g. ``'{"mesh": {"k_views": 8}}'``); ``--methods`` limits the rendered methods;
``--reuse`` (with ``--keep DIR``) takes the scene an earlier run with the same protocol saved in
DIR instead of saving it again, so that only the stages whose parameters changed run.
``--hybrid-params JSON`` gives the hybrid method render parameters (e.g. ``'{"tau_var": 0.1}'``;
checked before anything runs; no stage reads them, so ``--reuse`` re-runs no stage), for scoring
a setting chosen on the validation protocol (docs/hybrid.md "Parameters chosen by a sweep on lego
validation views"; the sweep itself: ``ibr-bench DIR --method hybrid --sweep ...`` on the scene
``--keep DIR`` saved).

``--scale S`` (default 1: the full 800x800; 2 min 52 s on 2 cores at load ~1.8 with texture stage
version 7, peak RSS 6.0 GB; ~9 min at load ~4 with version 5) divides the 800x800 images
by S before preprocessing (there is no importer option for it): colour, the held-out ground truth and alpha by the mean of each SxS
block (in linear light, exact for pixel centres at +0.5), the z-depth by the sample at the
block's (S//2, S//2) pixel (0.5 source pixel off the block centre; depth is 8-bit coarse anyway),
the mask (alpha > 0.5) as the block mean >= 0.5; cameras by ``Camera.scaled``. ``--scale 1`` is
the full resolution.

Scores (``ibrtools.metrics``: PSNR and SSIM on sRGB, FLIP): per held-out view and their mean,
over all pixels (holes black, background black in both) and over the object pixels (alpha > 0.99
of the held-out r_N.png, as in the DIBR protocol; holes black; SSIM = the mean of the SSIM map
over them, FLIP = the mean of the FLIP map over them). Hybrid "beats" a method when its mean is
better (PSNR, SSIM higher; FLIP lower). Near occlusion edges (the filtered-vs-unfiltered PVM target),
as in benchmarks/bench_hybrid.py: the pixels within 3 px of a relative step > 5 % of the held-out view's
depth map (or of its object / background boundary), PSNR of the squared error pooled over the views.
With --write-docs, replaces the "Hybrid rendering: lego"
section of docs/benchmarks_hybrid.md.
"""
from __future__ import annotations

import argparse
import json
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchlib import DOCS, load_note, machine, shared_data, write_section

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_dibr_accuracy import LEGO_HELDOUT  # noqa: E402  (the same held-out views)
from bench_hybrid import add_edge_error, depth_edges, edge_lines, frame_color, pvm_method  # noqa: E402  (as in the synthetic bench)

LEGO_VALIDATION = ("r_10", "r_60", "r_110", "r_160")
ORDER = ["tm", "ulr", "pvm", "pvm_unfiltered", "hybrid"]
NAMES = {"tm": "TM (textured mesh)", "ulr": "ULR (per-pixel)", "pvm": "PVM (clustered, filtered)",
         "pvm_unfiltered": "PVM unfiltered", "hybrid": "hybrid"}
# The data set's 40 views r_0, r_5 ... r_195 as 10 folds of 4, 50 apart: fold 0 is LEGO_HELDOUT, fold 2
# LEGO_VALIDATION; the others (--fold) are further held-out sets.
FOLDS = (1, 3, 4, 5, 6, 7, 8, 9)


def fold_views(k: int) -> tuple[str, ...]:
    return tuple(f"r_{5 * k + 50 * i}" for i in range(4))


def _block_mean(a: np.ndarray, s: int) -> np.ndarray:
    if s == 1:
        return a
    h, w = a.shape[0] // s, a.shape[1] // s
    a = a[:h * s, :w * s]
    return a.reshape(h, s, w, s, *a.shape[2:]).mean(axis=(1, 3))


def _scaled_view(v, s: int):
    from ibrtools.scene import View

    if s == 1:
        return v
    cam = v.camera.scaled(v.camera.width // s, v.camera.height // s)
    color = _block_mean(v.color.astype(np.float64), s).astype(np.float32)
    def sample(d):
        return None if d is None else np.ascontiguousarray(d[s // 2::s, s // 2::s][:cam.height, :cam.width])

    mask = None
    if v.has_mask:
        mask = _block_mean(v.mask.astype(np.float64), s) >= 0.5
    return View.create(v.name, cam, color=color, depth=sample(v.depth), mask=mask, depth_stored=sample(v.depth_stored))


def _alpha(data: Path, name: str, s: int) -> np.ndarray:
    from ibrtools.imageio import read_pixels

    rgba, _ = read_pixels(data / "nerf_lego" / "test" / f"{name}.png")
    alpha = rgba[..., 3].astype(np.float64) / np.iinfo(rgba.dtype).max
    return _block_mean(alpha, s)


def score(color: np.ndarray, truth: np.ndarray, obj: np.ndarray) -> dict:
    """All pixels and object pixels (holes already black in ``color``)."""
    from ibrtools import metrics

    m_all = metrics.compare(color, truth)
    m_obj = metrics.compare(color, truth, mask=obj)
    out = {"psnr": m_all["psnr"], "ssim": m_all["ssim"], "psnr_obj": m_obj["psnr_covered"],
           "ssim_obj": m_obj["ssim_covered"], "flip": None, "flip_obj": None}
    if metrics.flip_available():
        f, fmap = metrics.flip(color, truth, return_map=True)
        out["flip"] = f
        out["flip_obj"] = float(fmap[obj].mean(dtype=np.float64))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scale", type=int, default=1, help="divide the 800x800 images by this (default 1: full size)")
    p.add_argument("-j", "--threads", type=int, default=0, help="engine threads (default: all cores)")
    p.add_argument("--keep", default=None, metavar="DIR",
                   help="preprocess into DIR and keep it (default: a temporary directory)")
    p.add_argument("--write-docs", action="store_true", help="replace the section in benchmarks_hybrid.md")
    p.add_argument("--validation", action="store_true",
                   help="targets r_10 r_60 r_110 r_160, inputs without them and the held-out views (for choosing)")
    p.add_argument("--fold", type=int, default=None, metavar="K",
                   help="targets r_5K r_5K+50 r_5K+100 r_5K+150 (K 1, 3-9), removed from the inputs alone: a further "
                        "held-out set, for how far a result carries over (not for choosing)")
    p.add_argument("--json", default=None, metavar="PATH", help="also write the per-view and mean scores as JSON")
    p.add_argument("--depth-dequantize", type=int, default=None, metavar="N",
                   help="nerf importer option depth_dequantize (default: the importer's default)")
    p.add_argument("--methods", default=",".join(ORDER), help=f"methods to render (default {','.join(ORDER)})")
    p.add_argument("--reuse", action="store_true",
                   help="with --keep: reuse the scene DIR holds (same protocol) and its stage cache instead of re-importing")
    p.add_argument("--options", default=None, metavar="JSON", help="stage options for run_stages (JSON object)")
    p.add_argument("--hybrid-params", default=None, metavar="JSON",
                   help="hybrid render parameters (JSON object, e.g. '{\"tau_var\": 0.1}'; default: HybridParams)")
    p.add_argument("--speed-repeats", type=int, default=5, metavar="N",
                   help="after scoring, render every held-out view N more times per method and report the median "
                        "ms per frame (default 5; 0: no speed table)")
    args = p.parse_args(argv)
    if args.speed_repeats < 0:
        p.error("--speed-repeats must be >= 0")
    if args.scale < 1:
        p.error("--scale must be >= 1")
    order = [m for m in args.methods.split(",") if m]
    if not order or any(m not in ORDER for m in order):
        p.error(f"--methods: expected a comma-separated subset of {','.join(ORDER)}")
    if args.reuse and not args.keep:
        p.error("--reuse needs --keep DIR")
    if args.validation and args.write_docs:
        p.error("--write-docs scores the held-out views: not with --validation")
    if args.fold is not None and (args.validation or args.write_docs or args.fold not in FOLDS):
        p.error(f"--fold: expected one of {', '.join(map(str, FOLDS))}, without --validation and --write-docs")
    def json_object(text: str | None, flag: str) -> dict:
        try:
            obj = json.loads(text) if text else {}
        except json.JSONDecodeError as e:
            p.error(f"{flag}: not valid JSON ({e})")
        if not isinstance(obj, dict):
            p.error(f"{flag}: expected a JSON object")
        return obj

    stage_options = json_object(args.options, "--options")
    hybrid_params = json_object(args.hybrid_params, "--hybrid-params")
    from ibrtools.hybrid.method import HybridParams

    HybridParams.from_dict(hybrid_params)  # a bad key or value fails here, before the data is read
    data = shared_data()
    if not (data / "nerf_lego" / "transforms_test.json").exists():
        print(f"skipped: {data / 'nerf_lego'} is absent (set IBR_SHARED_DATA)", file=sys.stderr)
        return 0

    from ibrtools import _core
    from ibrtools.formats import load, native
    from ibrtools import methods
    from ibrtools.scene import Scene
    from ibrtools.pipeline.stages import run_stages

    if args.threads:
        _core.set_num_threads(args.threads)
    t_start = time.perf_counter()
    imp = {"background": "black"}
    if args.depth_dequantize is not None:
        imp["depth_dequantize"] = args.depth_dequantize
    full = load(data / "nerf_lego", "nerf", imp)
    if args.fold is not None:
        targets = fold_views(args.fold)
        excluded = set(targets)
    else:
        targets = LEGO_VALIDATION if args.validation else LEGO_HELDOUT
        excluded = set(LEGO_HELDOUT) | set(targets)
    held = [v for v in full.views if v.name in targets]
    inputs = [v for v in full.views if v.name not in excluded]
    assert len(held) == len(targets), [v.name for v in held]
    s = args.scale
    scene = Scene(views=[_scaled_view(v, s) for v in inputs], targets=[_scaled_view(v, s) for v in held],
                  units=full.units, source={**full.source, "bench_hybrid_lego": {"scale": s,
                                                                                  "heldout": list(targets),
                                                                                  "excluded": sorted(excluded),
                                                                                  "dequantize": args.depth_dequantize}})
    w, h = scene.views[0].camera.width, scene.views[0].camera.height
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.keep) if args.keep else Path(tmp) / "lego"
        if args.reuse and (root / "scene.json").exists():
            # The scene saved by an earlier run with the same protocol (its stage cache is reused
            # for the stages whose parameters did not change).
            prev = native.load(root).source.get("bench_hybrid_lego", {})
            if prev.get("scale") != s or prev.get("heldout") != list(targets) or "dequantize" not in prev \
                    or prev["dequantize"] != args.depth_dequantize:
                print(f"--reuse: {root} was made with other --scale / targets / --depth-dequantize", file=sys.stderr)
                return 1
        else:
            native.save(scene, root)
        t0 = time.perf_counter()
        need = sorted({"pvm" if m.startswith("pvm") else m for m in order})
        rows = run_stages(root, methods=need, options=stage_options)
        prep_s = time.perf_counter() - t0
        failed = [r for r in rows if r.status == "failed"]
        stage_s = {r.name: (r.status, r.seconds) for r in rows}
        details = {r.name: r.details for r in rows}
        print(f"preprocess {prep_s:.1f} s: " + ", ".join(f"{k} {v[0]} {v[1]:.1f}s" for k, v in stage_s.items()),
              file=sys.stderr)
        if failed:
            for r in failed:
                print(f"stage {r.name} failed: {r.reason}", file=sys.stderr)
            return 1
        scene = native.load(root)
        stored_inputs = {v.name for v in scene.views}
        assert not stored_inputs & excluded, "a held-out view is an input"
        renderers = {}
        for name in ("tm", "ulr", "hybrid"):
            if name in order:
                m = methods.create(name, hybrid_params if name == "hybrid" else None)
                m.prepare(scene)
                renderers[name] = m
        if "pvm" in order:
            renderers["pvm"] = pvm_method(scene, filtered=True)
        if "pvm_unfiltered" in order:
            renderers["pvm_unfiltered"] = pvm_method(scene, filtered=False)
        per_view: dict[str, dict[str, dict]] = {n: {} for n in order}
        selection = []
        edge_se = {n: [0.0, 0] for n in order}  # near occlusion edges of the held-out views' true depth
        edge_px = 0
        for t in scene.targets:
            obj = _alpha(data, t.name, s) > 0.99
            edges = depth_edges(t.depth) if t.has_depth else None
            edge_px += 0 if edges is None else int(edges.sum())
            for n in order:
                out, _ = renderers[n].render(t.camera)
                color = frame_color(out)
                per_view[n][t.name] = score(color, t.color, obj)
                add_edge_error(edge_se[n], color, t.color, edges)
                if n == "hybrid":
                    selection.append(renderers[n].frame_report()["selection"])
            print(f"{t.name}: " + ", ".join(f"{n} {per_view[n][t.name]['psnr']:.2f}" for n in order), file=sys.stderr)
        # Speed on real data: the scored renders warmed every method up; each view N times more.
        speed: dict[str, float] = {}
        for n in order if args.speed_repeats else ():
            times = []
            for _ in range(args.speed_repeats):
                for t in scene.targets:
                    t0 = time.perf_counter()
                    renderers[n].render(t.camera)
                    times.append(time.perf_counter() - t0)
            speed[n] = 1e3 * float(np.median(times))
    total_s = time.perf_counter() - t_start
    keys = ["psnr", "ssim", "flip", "psnr_obj", "ssim_obj", "flip_obj"]
    mean = {n: {k: (None if any(r[k] is None for r in per_view[n].values())
                    else float(np.mean([r[k] for r in per_view[n].values()]))) for k in keys} for n in order}

    def f(x, d):
        return "n/a" if x is None else f"{x:.{d}f}"

    views = list(targets)
    cmd = shlex.join(["python", "benchmarks/bench_hybrid_lego.py", *(sys.argv[1:] if argv is None else argv)])
    lines = [f"Hybrid IBR on held-out lego views (`{cmd}`), "
             f"{machine()}, {_core.get_num_threads()} threads. NeRF-synthetic lego (../shared/data/nerf_lego, "
             f"RGBA over black), {len(inputs)} input views at {w}x{h}"
             + ("" if s == 1 else f" (800x800 / {s}, block mean)") + ", held out "
             f"{' '.join(views)} ("
             + ("validation protocol: removed with r_0 r_50 r_100 r_150" if args.validation
                else f"fold {args.fold}: removed from the inputs" if args.fold is not None else "the DIBR lego protocol")
             + "; removed before preprocessing, so no stage reads them). "
             + (f"Importer option depth_dequantize={args.depth_dequantize}. " if args.depth_dequantize is not None else "")
             + (f"Stage options {json.dumps(stage_options)}. " if stage_options else "")
             + (f"Hybrid parameters {json.dumps(hybrid_params)} (the rest at their defaults). " if hybrid_params else "") +
             f"Global mesh by TSDF fusion of the inputs' depth maps (mesh source auto; "
             f"{details.get('mesh', {}).get('render_faces', '?')} render-mesh faces, atlas "
             f"{details.get('texture', {}).get('atlas', '?')}). "
             + ("Default parameters everywhere" if not (stage_options or hybrid_params) else "Other parameters at their defaults")
             + f". Preprocessing (tm, ulr, pvm, hybrid) took {prep_s:.1f} s "
             f"({', '.join(f'{k} {v[1]:.1f} s' + ('' if v[0] == 'ran' else f' {v[0]}') for k, v in stage_s.items())}); "
             f"whole run {total_s:.0f} s.", "",
             "Mean over the held-out views (all pixels: holes and background black; object: alpha > 0.99, "
             "holes black):", "",
             "| method | PSNR dB | SSIM | FLIP | object PSNR dB | object SSIM | object FLIP |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for n in order:
        r = mean[n]
        lines.append(f"| {NAMES[n]} | {f(r['psnr'], 2)} | {f(r['ssim'], 4)} | {f(r['flip'], 4)} | "
                     f"{f(r['psnr_obj'], 2)} | {f(r['ssim_obj'], 4)} | {f(r['flip_obj'], 4)} |")
    lines += ["", "Per view, PSNR dB all / object:", "",
              "| method | " + " | ".join(views) + " |", "|---|" + "---:|" * len(views)]
    for n in order:
        lines.append(f"| {NAMES[n]} | " + " | ".join(
            f"{f(per_view[n][v]['psnr'], 2)} / {f(per_view[n][v]['psnr_obj'], 2)}" for v in views) + " |")
    lines += ["", "Per view, SSIM all / object and FLIP all / object:", "",
              "| method | " + " | ".join(views) + " |", "|---|" + "---:|" * len(views)]
    for n in order:
        lines.append(f"| {NAMES[n]} | " + " | ".join(
            f"{f(per_view[n][v]['ssim'], 3)} / {f(per_view[n][v]['ssim_obj'], 3)}, "
            f"{f(per_view[n][v]['flip'], 3)} / {f(per_view[n][v]['flip_obj'], 3)}" for v in views) + " |")

    lines += edge_lines(edge_se, edge_px, NAMES, "the held-out views' depth maps (the data set's; background = "
                        "no depth, so silhouettes count)")

    def beats(k, lower=False):
        hv = mean["hybrid"][k] if "hybrid" in mean else None
        if hv is None:
            return "n/a"
        won = [n for n in ("tm", "ulr", "pvm") if n in mean and mean[n][k] is not None and (hv < mean[n][k] if lower else hv > mean[n][k])]
        return ", ".join(won) or "none"

    all3 = all(beats(k, k.startswith("flip")) == "tm, ulr, pvm" for k in ("psnr", "ssim", "flip"))
    sel = {k: float(np.mean([x[k] for x in selection])) for k in selection[0]} if selection else {}
    lines += ["", f"Hybrid beats, on the mean over the held-out views: PSNR {beats('psnr')}; SSIM {beats('ssim')}; "
              f"FLIP (lower) {beats('flip', True)}; object PSNR {beats('psnr_obj')}; object SSIM "
              f"{beats('ssim_obj')}; object FLIP {beats('flip_obj', True)}. Target (hybrid better than each of TM, "
              f"ULR and PVM on the all-pixel means): {'met' if all3 else 'missed'}. Mean hybrid selection: "
              + ", ".join(f"{k} {100 * v:.1f} %" for k, v in sel.items()) + "."]
    if "hybrid" in mean:  # the margins unrounded: a "beats" the table's digits cannot show
        lines += ["", "Hybrid minus each method on the all-pixel means (PSNR dB, SSIM, FLIP; FLIP lower is better): "
                  + "; ".join(f"{n} {mean['hybrid']['psnr'] - mean[n]['psnr']:+.3f} / "
                              f"{mean['hybrid']['ssim'] - mean[n]['ssim']:+.5f} / "
                              + ("n/a" if mean[n]['flip'] is None or mean['hybrid']['flip'] is None
                                 else f"{mean['hybrid']['flip'] - mean[n]['flip']:+.5f}")
                              for n in ("tm", "ulr", "pvm") if n in mean) + "."]
    if speed:
        lines += ["", f"Speed on these frames ({w}x{h}; the whole render call, median of {args.speed_repeats} x "
                  f"{len(views)} renders after the scored ones; real data with a "
                  f"{details.get('mesh', {}).get('render_faces', '?')}-face render mesh, unlike the synthetic speed table "
                  "of \"Hybrid rendering\" above):", "", "| method | ms per frame |", "|---|---:|"]
        lines += [f"| {NAMES[n]} | {speed[n]:.1f} |" for n in order]
    lines += ["", load_note()]
    text = "\n".join(lines)
    print(text)
    if args.json:
        Path(args.json).write_text(json.dumps({"targets": list(targets), "inputs": len(inputs), "mean": mean,
                                               "per_view": per_view}, indent=1))
    if args.write_docs:
        write_section("Hybrid rendering: lego", text, DOCS.with_name("benchmarks_hybrid.md"))
        print(f"wrote the 'Hybrid rendering: lego' section of {DOCS.with_name('benchmarks_hybrid.md')}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
