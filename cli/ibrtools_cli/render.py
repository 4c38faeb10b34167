"""ibr-render: render new views of a scene and write report.json."""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from ibrtools.errors import BadValueError

from .common import (ArgumentParser, add_common, add_distributed, arg_flag, param_flag, print_json, print_table,
                     progress_bar, run_command, warn_stale)

PROG = "ibr-render"


def build_parser() -> argparse.ArgumentParser:
    from ibrtools.inpaint.complete import DEFAULT_INPAINT, INPAINT
    from ibrtools.methods import BUILT, METHODS
    from ibrtools.paths import DEFAULT_FRAMES
    from ibrtools.metrics import DEFAULT_SCORES

    methods = "\n".join(f"  {k:<10} {v}{'' if k in BUILT or k == 'auto' else '  [not built yet]'}"
                        for k, v in METHODS.items())
    p = ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Render new views of a scene (made by ibr-preprocess): named targets, held-out "
                    "input views (removed from the inputs and used as ground truth), a camera path "
                    "(stored in the scene or generated from its input cameras) or a pose file. Writes <frame>.png per frame and report.json with per-frame "
                    "timings and, where ground truth exists, PSNR/SSIM/coverage.",
        epilog=f"methods:\n{methods}\n\n"
               "examples:\n"
               "  ibr-render scenes/objects --method reference --holdout v003 v009 -o out/holdout\n"
               "  ibr-render scenes/objects --target t000 t001 --depth --float -o out/targets\n"
               "  ibr-render scenes/objects --path orbit -o out/orbit -j 2\n"
               "  ibr-render scenes/garden --method dibr --path interpolate --path-frames 120 -o out/fly\n"
               "  ibr-render scenes/garden --method dibr --poses camera_path.json -o out/ns\n"
               "  ibr-render scenes/rgbd --method dibr --inputs 4 --holdout 4 -o out/dibr\n"
               "  ibr-render scenes/rgbd --method dibr --holdout 4 --inpaint none -o out/holes\n"
               "  ibr-render scenes/crowd --method depthwarp --path walk --layers 4 --seeds 16 --umbra -o out/dw\n"
               "  ibr-render scenes/objects --lightfield 9x8 --baseline 0.02 --mp4 out/lf/lf.mp4 -o out/lf\n"
               "  ibr-render scenes/objects --method hybrid --holdout v003 v009 --report-html -o out/hybrid\n"
               "  ibr-render scenes/objects --path orbit --json -q -o out/orbit > orbit.json\n\n"
               "light fields: --lightfield NxM --baseline B makes N columns x M rows of cameras on the plane\n"
               "of the centre camera (--center NAME: a stored target, else an input view; default the first\n"
               "target, else the first view), B scene units apart, all looking along the centre's direction\n"
               "(parallel optical axes, as light-field displays use); frames lf_0000... row-major from the top\n"
               "left, with row/col in report.json. docs/reports.md describes --report-html.")
    p.add_argument("scene", metavar="SCENE", help="scene directory (ibr-preprocess output), or an RVS synthesis "
                   "config (JSON): its frames imported into OUT/scene, its virtual cameras rendered and written to "
                   "its OutputFiles (YUV) in OUT")
    p.add_argument("-o", "--output", default="render-out", metavar="DIR",
                   help="output directory (default: render-out)")
    p.add_argument("--method", default="auto", choices=list(METHODS), help="method (default: auto)")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="method parameter (repeatable)")
    p.add_argument("--target", nargs="+", metavar="NAME", help="render these stored target cameras")
    p.add_argument("--holdout", nargs="+", metavar="NAME",
                   help="remove these input views from the inputs and render them as ground truth")
    p.add_argument("--path", metavar="NAME",
                   help="render every camera of this path: one stored in the scene, else a generated one: "
                        "interpolate (a smooth path through the input views in order), spiral (the LLFF "
                        "spiral around the mean input pose) or orbit (a circle around the scene's centre); "
                        "docs/render.md \"Camera paths\"")
    p.add_argument("--path-frames", type=int, default=None, metavar="N",
                   help=f"with a generated --path: its number of frames (default {DEFAULT_FRAMES}, at least 2)")
    p.add_argument("--poses", metavar="FILE",
                   help="render these cameras: a JSON list of cameras (scene.json camera format), a nerfstudio "
                        "camera_path.json or a transforms.json (docs/render.md \"Pose files\")")
    lf = p.add_argument_group("light fields and video")
    lf.add_argument("--lightfield", metavar="NxM",
                    help="render an N (columns) x M (rows) grid of cameras around the centre camera")
    lf.add_argument("--baseline", type=float, metavar="B", help="with --lightfield: camera spacing in scene units")
    lf.add_argument("--center", "--centre", dest="center", metavar="NAME",
                    help="with --lightfield: the centre camera (target or input view; default the first "
                         "target, else the first input view)")
    lf.add_argument("--mp4", metavar="FILE", help="also write the frames, in order, as an H.264 MP4 "
                                                  "(needs imageio-ffmpeg: pip install 'ibrtools[video]')")
    lf.add_argument("--fps", type=float, default=None, metavar="F", help="with --mp4: frames per second (default 24)")
    lf.add_argument("--yuv", metavar="FILE", help="also write the frames, in order, as one raw YUV 4:2:0 file "
                                                  "(BT.709 limited range, as RVS writes; docs/render.md); a FILE "
                                                  "with {camera} in its name: one file per camera")
    lf.add_argument("--yuv-bits", type=int, default=None, metavar="B",
                    help="with --yuv: bits per sample, 8 or 10 (.. 16; default 10: little-endian 16-bit words)")
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
    p.add_argument("--inpaint", default=DEFAULT_INPAINT, choices=list(INPAINT),
                   help="fill the pixels no input covers (the background at infinity is rendered, never "
                        "filled; docs/render.md \"Complete images\"): auto (default: the measured best, "
                        "depth-aware push-pull from the background side), pushpull, metameric (noise with the "
                        "steerable-band statistics of the surroundings; docs/inpaint.md), none (holes black). "
                        "<frame>.hole.png marks the holes either way")
    p.add_argument("--background", metavar="COLOR", default=None,
                   help="the background at infinity (sky, a NeRF capture's transparent background; docs/render.md) "
                        "as black, white, R,G,B (sRGB in [0, 1]) or transparent (RGBA images, alpha 0 there); "
                        "default: the scene's background colour (a NeRF capture's compositing colour), else as the inputs "
                        "show it")
    p.add_argument("--foveate", metavar="X,Y",
                   help="foveated ventral metamers (Walton et al. 2021; docs/foveate.md): keep the image "
                        "around the fixation point X,Y (fractions of width and height, e.g. 0.5,0.5 = "
                        "centre) and replace the periphery by noise with the steerable-band statistics "
                        "pooled over regions that grow with eccentricity (after --inpaint)")
    p.add_argument("--pooling", type=float, default=None, metavar="ALPHA",
                   help="with --foveate: pooling region size per degree of eccentricity (default 0.5, "
                        "Bouma's law); the display's horizontal field of view is taken as 90 degrees")
    p.add_argument("--metrics", default=DEFAULT_SCORES, metavar="LIST",
                   help="scores of frames with ground truth: all (default: psnr, ssim, and flip when installed), "
                        "none, or a comma list of psnr, ssim, flip (FLIP takes seconds per 1080p frame; "
                        "coverage is always reported)")
    p.add_argument("--float", action="store_true", help="also write <frame>.exr (linear float)")
    p.add_argument("--depth", action="store_true", help="also write <frame>.depth.exr")
    p.add_argument("--report", action="store_true", help="print the per-frame report table")
    p.add_argument("--report-html", nargs="?", const="", default=None, metavar="FILE",
                   help="write a self-contained HTML report (renders beside ground truth, error heat maps, "
                        "masks, stage times; default FILE: <output>/report.html)")
    p.add_argument("--json", action="store_true",
                   help="print the report (report.json, plus the paths of the video and HTML report) as JSON "
                        "on stdout, and nothing else")
    add_common(p)
    add_distributed(p)
    return p


def _body(args: argparse.Namespace) -> int:
    from ibrtools.pipeline.distributed import check_options
    from ibrtools.formats import native
    from ibrtools.pipeline import job as render_job
    from ibrtools.pipeline import plan as planning
    from ibrtools.pipeline import rvs
    check_options(args.scheduler, args.workers)  # usage errors before the scene is read
    foveate = None
    if args.foveate is not None:
        foveate = _fixation(args.foveate)
    elif args.pooling is not None:
        raise BadValueError("--pooling: only with --foveate X,Y")
    lightfield = _lightfield(args)
    video = html_path = None
    if args.mp4 is not None:
        from ibrtools.pipeline import batches

        batches.require_video()
        video = batches.check_video_path(args.mp4)
        if args.fps is None:
            args.fps = 24.0
        if not (0 < args.fps < float("inf")):
            raise BadValueError(f"--fps: expected a positive frame rate, got {args.fps}")
    elif args.fps is not None:
        raise BadValueError("--fps: only with --mp4 FILE")
    if args.yuv_bits is not None and args.yuv is None:
        raise BadValueError("--yuv-bits: only with --yuv FILE")
    if args.report_html is not None:
        from pathlib import Path

        from ibrtools.pipeline.report_html import check_output

        html_path = check_output(args.report_html or Path(args.output) / "report.html")
    params = _params(args)
    from ibrtools.formats.yuv import DEFAULT_BITS

    yuv, yuv_bits = args.yuv, DEFAULT_BITS if args.yuv_bits is None else args.yuv_bits
    scene_dir = args.scene
    if rvs.is_config(args.scene):  # an RVS synthesis config: imported, rendered and written as RVS would
        if args.yuv is not None or args.yuv_bits is not None:
            raise BadValueError(f"--yuv: {args.scene} is an RVS config, whose OutputFiles name the YUV files")

        def stage_line(msg: str) -> None:
            if not (args.quiet or args.json):
                print(f"{PROG}: {msg}", file=sys.stderr, flush=True)

        run = rvs.prepare(args.scene, args.output, args.method, progress=stage_line)
        scene_dir, yuv, yuv_bits = run.scene_dir, run.yuv or None, run.yuv_bits
        params = {**run.params, **params}  # the flags win over the config
        if not (args.quiet or args.json):
            print(f"{PROG}: RVS config {args.scene}: scene {scene_dir}; YUV outputs "
                  f"{', '.join(str(p) for p in run.yuv.values()) or 'none'}", file=sys.stderr)
            for note in run.notes:
                print(f"{PROG}: note: {note}", file=sys.stderr)
    scene = native.load(scene_dir)
    job = planning.plan(scene, targets=args.target, holdout=args.holdout, path=args.path,
                          path_frames=args.path_frames, poses=args.poses, lightfield=lightfield)
    if video is not None:
        batches.check_same_size([f.camera for f in job.frames])
    warn_stale(PROG, job.scene, args.method, silent=args.quiet or args.json)  # a video: its first frame
    with progress_bar(PROG, "frames", len(job.frames), quiet=args.quiet) as bar:
        report = render_job.run(job, args.method, args.output, params=params, float_out=args.float,
                                depth_out=args.depth, threads=args.threads, inpaint=args.inpaint,
                                background=args.background,
                                foveate=foveate, pooling=args.pooling,
                                progress=lambda i, n, name: bar.update(i, n, name),
                                scheduler=args.scheduler, workers=args.workers, yuv=yuv, yuv_bits=yuv_bits,
                                metrics=args.metrics)
    extra = {}
    if video is not None:
        from pathlib import Path

        images = [Path(args.output) / f["image"] for f in report["frames"] if f.get("image")]
        with progress_bar(PROG, "video", None, quiet=args.quiet):
            extra["video"] = str(batches.write_mp4(images, video, fps=args.fps))
    if html_path is not None:
        from ibrtools.pipeline.report_html import render_report

        truths = {f.name: (lambda v=f.truth: v.color) for f in job.frames
                  if f.truth is not None and f.truth.has_color}
        with progress_bar(PROG, "HTML report", None, quiet=args.quiet):
            extra["report_html"] = str(render_report(report, args.output, html_path, truths=truths))
    status = _report_failed(report)
    if report.get("holdout_note") and not (args.quiet or args.json):
        print(f"{PROG}: note: {report['holdout_note']}", file=sys.stderr)
    if report.get("output") and not (args.quiet or args.json):
        print(f"{PROG}: note: {_output_note(report['output'])}", file=sys.stderr)
    if not (args.quiet or args.json):  # the report keeps them ("warnings" of each frame)
        for f in report["frames"]:
            for w in f.get("warnings", ()):
                print(f"{PROG}: warning: frame {f['name']}: {w}", file=sys.stderr)
    if args.json:
        print_json({**report, **extra})
        return status
    _print_summary(args, report)
    for key, what in (("video", "video"), ("report_html", "HTML report")):
        if key in extra and not args.quiet:
            print(f"{what}: {extra[key]}")
    return status


# The method parameters that have flags of their own (arg_flag spells them: blend_exponent is
# --blend-exponent); the others are --param KEY=VALUE.
DEPTHWARP_FLAGS = ("layers", "seeds", "iters", "forward", "oriented_bounds", "umbra", "cull")
PARAM_FLAGS = ("inputs", "quality", "blend_exponent") + DEPTHWARP_FLAGS


def _param_flag(name: str | None, args: argparse.Namespace) -> str:
    """The flag the user set parameter ``name`` with (its own flag, else --param NAME)."""
    given = {k for k in PARAM_FLAGS if getattr(args, k, None) not in (None, False)}
    return arg_flag(name) if name in given else param_flag(name, args)


def _params(args: argparse.Namespace) -> dict:
    """The method parameters of the flags and --param, checked (methods.check_params) before the
    scene is read when --method names the method."""
    from ibrtools import methods
    from ibrtools_cli.common import parse_options

    params = {k: _number(v) for k, v in parse_options(args.param).items()}
    for key in PARAM_FLAGS:
        value = getattr(args, key)
        if value is True:
            params[key] = True
        elif value is not None and value is not False:
            params[key] = _number(value)
    depthwarp_only = [k for k in DEPTHWARP_FLAGS if k in params]
    if depthwarp_only and args.method != "depthwarp":
        raise BadValueError(f"{arg_flag(depthwarp_only[0])}: only with --method depthwarp")
    if args.method != "auto" and args.method in methods.BUILT:
        methods.check_params(args.method, params)  # bad values: exit 2 before any work
    return params


def _report_failed(report: dict) -> int:
    """Frames whose rendering raised (report.json "failed"): one stderr line naming them, exit 1;
    the other frames were written."""
    failed = report.get("failed") or []
    if not failed:
        return 0
    shown = "; ".join(f"{f['name']}: {f['error']}" for f in failed[:3]) + ("; ..." if len(failed) > 3 else "")
    print(f"{PROG}: {len(failed)} of {len(failed) + len(report['frames'])} frames failed (report.json "
          f"\"failed\"): {shown}", file=sys.stderr)
    return 1


def _output_note(output: dict) -> str:
    """One line on what the run did to the output directory beyond its frames (report.json
    "output"): names mapped to file names, a dead job's temporaries swept, old files replaced
    or removed."""
    def some(names) -> str:
        names = list(names)
        return ", ".join(names[:3]) + (f", ... ({len(names)} in all)" if len(names) > 3 else "")

    parts = []
    if output.get("renamed"):
        parts.append("frame names mapped to file names: " + some(f"{k!r} -> {v}" for k, v in output["renamed"].items()))
    if output.get("swept"):
        parts.append(f"swept {len(output['swept'])} temporaries of a job that died here")
    if output.get("replaced"):
        parts.append(f"replaced {len(output['replaced'])} files of the previous run")
    if output.get("removed"):
        parts.append(f"removed {len(output['removed'])} files of the previous run that this one does not write: "
                     + some(output["removed"]))
    return "; ".join(parts) + " (report.json \"output\")"


def _lightfield(args: argparse.Namespace):
    """--lightfield NxM --baseline B [--center NAME] -> plan()'s plain tuple, checked."""
    if args.lightfield is None:
        for flag, v in (("--baseline", args.baseline), ("--center", args.center)):
            if v is not None:
                raise BadValueError(f"{flag}: only with --lightfield NxM")
        return None
    from ibrtools.pipeline.batches import check_baseline, parse_grid

    n, m = parse_grid(args.lightfield)
    if args.baseline is None:
        raise BadValueError("--lightfield: give the camera spacing with --baseline B (scene units)")
    return (n, m, check_baseline(args.baseline), args.center)


def _print_summary(args: argparse.Namespace, report: dict) -> None:
    """The per-frame table with a totals row: frames, median ms, mean metrics, failed frames."""
    s = report.get("summary") or {}
    nfail = len(report.get("failed") or [])
    label = f"{s.get('frames', len(report['frames']))} frames" + (f", {nfail} failed" if nfail else "")
    med = _fmt((s.get("time_ms") or {}).get("median"), 1)
    if report["method"] == "depthwarp" and (args.report or not args.quiet):
        rows = []
        for f in report["frames"]:
            m, dw = f["metrics"], f.get("depthwarp", {})
            rows.append([f["name"], f"{f['time_ms']['total']:.1f}", _fmt(dw.get("warp_ms"), 1),
                         _fmt(dw.get("reference_ms"), 1), _fmt(m.get("depth_psnr")), _fmt(m.get("depth_ssim"), 4),
                         _fmt(m.get("hole_fraction"), 4)])
        print_table(["frame", "ms", "warp ms", "reference ms", "depth PSNR dB", "depth SSIM", "holes"], rows,
                    title=f"{PROG} --method depthwarp ({report['threads']} threads) -> {args.output}",
                    quiet=args.quiet and not args.report,
                    totals=[label, f"median {med}", "", "", _fmt(s.get("mean_depth_psnr")),
                            _fmt(s.get("mean_depth_ssim"), 4), _fmt(s.get("mean_hole_fraction"), 4)])
    elif args.report or not args.quiet:
        rows = []
        for f in report["frames"]:
            m = f["metrics"]
            rows.append([f["name"], f"{f['time_ms']['total']:.1f}", _fmt(m.get("psnr")),
                         _fmt(m.get("psnr_covered")), _fmt(m.get("ssim"), 4), _fmt(m.get("coverage"), 3),
                         _fmt(m.get("filled"), 3)])
        # "PSNR dB": the image as written; "covered": the pixels the inputs covered (not filled).
        print_table(["frame", "ms", "PSNR dB", "PSNR dB, covered", "SSIM", "coverage", "filled"], rows,
                    title=f"{PROG} --method {report['method']} ({report['threads']} threads) -> {args.output}",
                    quiet=args.quiet and not args.report,
                    totals=[label, f"median {med}", _fmt(s.get("mean_psnr")), _fmt(s.get("mean_psnr_covered")),
                            _fmt(s.get("mean_ssim"), 4), _fmt(s.get("mean_coverage"), 3), _fmt(s.get("mean_filled"), 3)])
    seq = report.get("sequence")
    if seq and (args.report or not args.quiet):
        split = ", ".join(f"{k} {v:.1f}" for k, v in seq["stage_ms_mean"].items() if k != "total")
        print(f"sequence: {seq['frames']} frames in {seq['wall_ms'] / 1e3:.2f} s = {seq['fps']:.2f} fps sustained "
              f"(decode waits {seq['decode_wait_ms']:.0f} ms); mean ms per frame: {split}")


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
    return run_command(PROG, _body, build_parser(), argv, _param_flag)


if __name__ == "__main__":
    sys.exit(main())
