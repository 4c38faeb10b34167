"""ibr-render: render new views of a scene and write report.json."""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from ibrtools.errors import BadValueError

from .common import add_common, print_table, run_command

PROG = "ibr-render"


def build_parser() -> argparse.ArgumentParser:
    from ibrtools.render.methods import BUILT, METHODS

    methods = "\n".join(f"  {k:<10} {v}{'' if k in BUILT or k == 'auto' else '  [not built yet]'}"
                        for k, v in METHODS.items())
    p = argparse.ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Render new views of a scene (made by ibr-preprocess): named targets, held-out "
                    "input views (removed from the inputs and used as ground truth), a stored camera "
                    "path or a pose file. Writes <frame>.png per frame and report.json with per-frame "
                    "timings and, where ground truth exists, PSNR/SSIM/coverage.",
        epilog=f"methods:\n{methods}\n\n"
               "examples:\n"
               "  ibr-render scenes/objects --method reference --holdout v003 v009 -o out/holdout\n"
               "  ibr-render scenes/objects --target t000 t001 --depth --float -o out/targets\n"
               "  ibr-render scenes/objects --path orbit -o out/orbit -j 2\n"
               "  ibr-render scenes/rgbd --method dibr --inputs 4 --holdout 4 -o out/dibr\n"
               "  ibr-render scenes/rgbd --method dibr --holdout 4 --inpaint pushpull -o out/filled\n"
               "  ibr-render scenes/crowd --method depthwarp --path walk --layers 4 --seeds 16 --umbra -o out/dw")
    p.add_argument("scene", metavar="SCENE", help="scene directory (ibr-preprocess output)")
    p.add_argument("-o", "--output", default="render-out", metavar="DIR",
                   help="output directory (default: render-out)")
    p.add_argument("--method", default="auto", choices=list(METHODS), help="method (default: auto)")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="method parameter (repeatable)")
    p.add_argument("--target", nargs="+", metavar="NAME", help="render these stored target cameras")
    p.add_argument("--holdout", nargs="+", metavar="NAME",
                   help="remove these input views from the inputs and render them as ground truth")
    p.add_argument("--path", metavar="NAME", help="render every camera of this stored path")
    p.add_argument("--poses", metavar="FILE", help="JSON list of cameras (scene.json camera format)")
    d = p.add_argument_group("dibr options (method parameters; also as --param key=value)")
    d.add_argument("--inputs", metavar="K|v1,v2,...",
                   help="the K most similar input views per frame (default 4), or these views")
    d.add_argument("--quality", metavar="Q", help="triangle quality: side, shape, depth or normal (default side)")
    d.add_argument("--blend-exponent", metavar="P", help="blending weight (q/d)^P (default 5, as RVS)")
    w = p.add_argument_group("depthwarp options (iterative depth warping along --poses / --path; "
                             "docs/depthwarp.md; also as --param key=value)")
    w.add_argument("--layers", metavar="L", help="depth layers peeled from the previous frame (default 3)")
    w.add_argument("--seeds", metavar="N", help="stratified search seeds per pixel (default 16)")
    w.add_argument("--iters", metavar="T", help="fixed-point iterations per seed (default 3)")
    w.add_argument("--oriented-bounds", action="store_true", help="PCA-oriented search bounds when smaller")
    w.add_argument("--umbra", action="store_true", help="generalised umbra culling while peeling the layers")
    w.add_argument("--cull", action="store_true",
                   help="warping-based occlusion culling of the objects, scored against the reference")
    w.add_argument("--forward", choices=["vfw", "afw"],
                   help="run a forward-warping baseline (VFW quad splats, AFW point splats) instead")
    p.add_argument("--inpaint", default="none", choices=["none", "pushpull", "metameric"],
                   help="fill the holes a method leaves (dibr): none (default, holes black), pushpull "
                        "(depth-aware push-pull when the method gives depth), metameric (noise with the "
                        "steerable-band statistics of the surroundings; docs/inpaint.md). "
                        "<frame>.mask.png still marks the filled holes")
    p.add_argument("--foveate", metavar="X,Y",
                   help="foveated ventral metamers (Walton et al. 2021; docs/foveate.md): keep the image "
                        "around the fixation point X,Y (fractions of width and height, e.g. 0.5,0.5 = "
                        "centre) and replace the periphery by noise with the steerable-band statistics "
                        "pooled over regions that grow with eccentricity (after --inpaint)")
    p.add_argument("--pooling", type=float, default=None, metavar="ALPHA",
                   help="with --foveate: pooling region size per degree of eccentricity (default 0.5, "
                        "Bouma's law); the display's horizontal field of view is taken as 90 degrees")
    p.add_argument("--float", action="store_true", help="also write <frame>.exr (linear float)")
    p.add_argument("--depth", action="store_true", help="also write <frame>.depth.exr")
    p.add_argument("--report", action="store_true", help="print the per-frame report table")
    add_common(p)
    return p


def _body(args: argparse.Namespace) -> int:
    from ibrtools.formats import native
    from ibrtools.render import job as render_job
    from ibrtools.stages import parse_options

    foveate = None
    if args.foveate is not None:
        foveate = _fixation(args.foveate)
    elif args.pooling is not None:
        raise BadValueError("--pooling: only with --foveate X,Y")
    scene = native.load(args.scene)
    job = render_job.plan(scene, targets=args.target, holdout=args.holdout, path=args.path,
                          poses=args.poses)
    progress = None
    if not args.quiet and sys.stderr.isatty():
        def progress(i: int, n: int, name: str) -> None:
            print(f"\r{PROG}: frame {i}/{n} {name:<24}", end="" if i < n else "\n", file=sys.stderr)
    params = {k: _number(v) for k, v in parse_options(args.param).items()}
    for key, value in (("inputs", args.inputs), ("quality", args.quality),
                       ("blend_exponent", args.blend_exponent), ("layers", args.layers),
                       ("seeds", args.seeds), ("iters", args.iters), ("forward", args.forward)):
        if value is not None:
            params[key] = _number(value)
    for key, flag in (("oriented_bounds", args.oriented_bounds), ("umbra", args.umbra), ("cull", args.cull)):
        if flag:
            params[key] = True
    depthwarp_only = [k for k in ("layers", "seeds", "iters", "forward", "oriented_bounds", "umbra", "cull")
                      if k in params]
    if depthwarp_only and args.method != "depthwarp":
        raise BadValueError(f"--{depthwarp_only[0].replace('_', '-')}: only with --method depthwarp")
    report = render_job.run(job, args.method, args.output, params=params, float_out=args.float,
                            depth_out=args.depth, threads=args.threads, inpaint=args.inpaint,
                            foveate=foveate, pooling=args.pooling, progress=progress)
    if report["method"] == "depthwarp" and (args.report or not args.quiet):
        rows = []
        for f in report["frames"]:
            m, dw = f["metrics"], f.get("depthwarp", {})
            rows.append([f["name"], f"{f['time_ms']['total']:.1f}", _fmt(dw.get("warp_ms"), 1),
                         _fmt(dw.get("reference_ms"), 1), _fmt(m.get("depth_psnr")), _fmt(m.get("depth_ssim"), 4),
                         _fmt(m.get("hole_fraction"), 4)])
        print_table(["frame", "ms", "warp ms", "reference ms", "depth PSNR dB", "depth SSIM", "holes"], rows,
                    title=f"{PROG} --method depthwarp ({report['threads']} threads) -> {args.output}",
                    quiet=args.quiet and not args.report)
    elif args.report or not args.quiet:
        rows = []
        for f in report["frames"]:
            m = f["metrics"]
            rows.append([f["name"], f"{f['time_ms']['total']:.1f}", _fmt(m.get("psnr")),
                         _fmt(m.get("psnr_masked")), _fmt(m.get("ssim"), 4), _fmt(m.get("coverage"), 3)])
        print_table(["frame", "ms", "PSNR dB", "PSNR dB, covered", "SSIM", "coverage"], rows,
                    title=f"{PROG} --method {report['method']} ({report['threads']} threads) -> {args.output}",
                    quiet=args.quiet and not args.report)
    return 0


def _fixation(text: str) -> tuple[float, float]:
    """--foveate X,Y: two numbers in [0, 1] (the library checks the range)."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        return float(parts[0]), float(parts[1])
    except ValueError:
        raise BadValueError(f"--foveate: expected X,Y (two numbers in [0, 1], e.g. 0.5,0.5), got {text!r}") from None


def _number(v: str):
    try:
        return int(v)
    except ValueError:
        try:
            return float(v)
        except ValueError:
            return v


def _fmt(v, digits: int = 2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def main(argv: Sequence[str] | None = None) -> int:
    return run_command(PROG, _body, build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
