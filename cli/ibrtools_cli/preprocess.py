"""ibr-preprocess: import a data set (or make a synthetic one) and run the stages it needs."""
from __future__ import annotations

import argparse
import re
import sys
from typing import Sequence

from ibrtools.errors import InputError

from .common import ArgumentParser, add_common, add_distributed, print_table, progress_bar, run_command

PROG = "ibr-preprocess"


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)[xX](\d+)", text)
    if not m or int(m.group(1)) <= 0 or int(m.group(2)) <= 0:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT with positive integers, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def build_parser() -> argparse.ArgumentParser:
    from ibrtools.formats import IMPORTERS, importer

    try:
        from ibrtools.synth import PRESETS
        presets = "\n".join(f"  synth:{k:<10} {v}" for k, v in PRESETS.items())
    except ImportError:
        presets = "  (synthetic scenes unavailable)"
    formats = "\n".join(f"  {n:<12} {importer(n).DESCRIPTION}" for n in IMPORTERS)
    p = ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Import a data set into a native ibrtools scene and run the preprocessing "
                    "stages it needs. Prints a stage table: ran / up to date / skipped, with the "
                    "reason and the time. Re-running with unchanged inputs does nothing.",
        epilog=f"formats (detected from INPUT unless --format is given):\n{formats}\n\n"
               f"synthetic scenes (INPUT = synth:PRESET):\n{presets}\n\n"
               "examples:\n"
               "  ibr-preprocess synth:objects -o scenes/objects --views 12 --size 480x360\n"
               "  ibr-preprocess synth:objects -o scenes/objects --methods tm,ulr,pvm,hybrid\n"
               "  ibr-preprocess synth:objects -o scenes/objects --json -q > stages.json\n"
               "  ibr-preprocess ../shared/data/nerf_lego -o scenes/lego\n"
               "  ibr-preprocess ../shared/data/nerf_lego -o scenes/lego-h --methods hybrid --holdout r_0 r_50\n"
               "  ibr-preprocess ../shared/data/icl_nuim_livingroom -o scenes/icl --format rgbd "
               "--opt fx=481.2 --opt fy=-480.0 --opt cx=319.5 --opt cy=239.5 --opt depth_scale=0.0002")
    p.add_argument("input", metavar="INPUT", help="data-set file or directory, or synth:PRESET")
    p.add_argument("-o", "--output", required=True, metavar="SCENE", help="scene directory to write")
    p.add_argument("--format", choices=IMPORTERS, help="input format (default: detect)")
    p.add_argument("--opt", action="append", metavar="KEY=VALUE", default=[],
                   help="importer option (repeatable), e.g. --opt depth_scale=0.0002; see docs/importers.md")
    p.add_argument("--methods", metavar="M[,M...]", default=None,
                   help="render methods to prepare for: their stages run, the others are skipped "
                        "(reference, dibr, warp, depthwarp, tm, ulr, pvm, hybrid; 'all'). Default 'auto': "
                        "the methods that work from the views alone, i.e. the import alone (fast); "
                        "name tm,ulr,pvm,hybrid to prepare those")
    p.add_argument("--stages", metavar="S[,S...]", default=None,
                   help="run exactly these stages (and the stages they read) whatever --methods says: "
                        "mesh, depth, texture, variance, harmonise, pvm (docs/preprocess.md)")
    p.add_argument("--set", action="append", metavar="STAGE.KEY=VALUE", default=[], dest="stage_set",
                   help="stage parameter (repeatable), e.g. --set mesh.source=fusion --set pvm.max_block=8")
    p.add_argument("--force", action="store_true", help="run every selected stage even when up to date")
    p.add_argument("--holdout", nargs="+", metavar="NAME", default=None,
                   help="import these input views as targets (ground truth no stage reads): ibr-render SCENE then "
                        "scores them as unseen views (ibr-render --holdout only removes views from a render, after "
                        "the stages saw them)")
    p.add_argument("--mesh", metavar="FILE", default=None,
                   help="your own reconstruction of the scene (PLY/OBJ in the capture's frame and units), imported "
                        "as its 'reconstructed' mesh: the views without depth get its rendering (depth stage) "
                        "instead of multi-view stereo")
    p.add_argument("--downscale", type=float, default=None, metavar="N",
                   help="import every image N times smaller (N >= 1; intrinsics scaled, colour area-averaged, depth "
                        "the nearest known depth of each block; docs/importers.md \"Downscaling\")")
    p.add_argument("--max-size", type=int, default=None, metavar="PX",
                   help="import images with their longer side at most PX pixels (smaller images are kept)")
    p.add_argument("--frames", default=None, metavar="A:B|N",
                   help="import a video scene (docs/FORMAT.md \"Frames\"): of a video data set (MPEG/RVS YUV), "
                        "frames A to B - 1 (A:B, A:, :B, all, or default: an RVS config's StartFrame and "
                        "NumberOfFrames); of synth:NAME, N frames with the objects moving (default: a still scene)")
    p.add_argument("--json", action="store_true", help="print the stage table as JSON on stdout, and nothing else")
    g = p.add_argument_group("synthetic scenes")
    g.add_argument("--size", type=_size, default=(640, 480), metavar="WxH", help="image size (default 640x480)")
    g.add_argument("--views", type=int, default=16, metavar="N", help="input views (default 16)")
    g.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    g.add_argument("--exposure-jitter", type=float, default=0.0, metavar="SIGMA",
                   help="per-view exposure jitter (std of the log gain; default 0) for harmonisation tests")
    g.add_argument("--wb-jitter", type=float, default=0.0, metavar="SIGMA",
                   help="per-view, per-channel white-balance jitter (std of the log gain; default 0)")
    g.add_argument("--reconstructed", action="store_true",
                   help="also store a degraded 'reconstructed' copy of the mesh")
    add_common(p)
    add_distributed(p)
    return p


def _body(args: argparse.Namespace) -> int:
    import json

    from ibrtools.pipeline.distributed import check_options
    from ibrtools.pipeline.stages import preprocess
    from ibrtools_cli.common import parse_methods, parse_options, parse_stage_options, parse_stages

    check_options(args.scheduler, args.workers)  # usage errors before any work
    synth = None
    if args.input.startswith("synth:"):
        from ibrtools.synth import scene_spec

        n_frames = 1
        if args.frames is not None:
            try:
                n_frames = int(args.frames)
            except ValueError:
                raise InputError(f"--frames {args.frames}: a synthetic video takes a number of frames N") from None
        options = {"size": list(args.size), "views": args.views, "seed": args.seed,
                   "reconstructed": bool(args.reconstructed)}
        # Only when set, so that the import key of scenes made without jitter is unchanged.
        for key, value in (("exposure_jitter", args.exposure_jitter), ("white_balance_jitter", args.wb_jitter)):
            if not value >= 0:
                raise InputError(f"--{key.replace('_', '-').replace('white-balance', 'wb')}: expected >= 0, got {value}")
            if value > 0:
                options[key] = value
        if n_frames != 1:  # only then (a bad count is refused below): the import key of still scenes is unchanged
            options["frames"] = n_frames
        # the preset, the bounds and the memory estimate (docs/synth.md "Size and memory"), before any work
        synth = scene_spec(args.input, options, source_label="INPUT", flags=("--size", "--views", "--frames"))
    methods = parse_methods(args.methods)
    stages = parse_stages(args.stages)
    stage_options = parse_stage_options(args.stage_set)
    with progress_bar(PROG, "stages", None, quiet=args.quiet or args.json) as bar:
        if bar.shown:  # a terminal: the bar names the stage under way and counts the stages run
            bar.update(0, None, "import")

            def progress(msg: str) -> None:
                bar.advance(msg.split(" - ")[0])
        else:  # a log: one line per stage that runs (nothing with --quiet or --json)
            def progress(msg: str) -> None:
                if not (args.quiet or args.json):
                    print(f"{PROG}: {msg}", file=sys.stderr, flush=True)
        results = preprocess(args.input, args.output, fmt=args.format, options=parse_options(args.opt),
                             synth=synth, force=args.force, methods=methods, stages=stages,
                             stage_options=stage_options, progress=progress, scheduler=args.scheduler,
                             workers=args.workers, threads=args.threads, holdout=args.holdout, mesh=args.mesh,
                             downscale=args.downscale, max_size=args.max_size,
                             frames=None if synth is not None else args.frames)
        bar.advance("done")
    if not (args.quiet or args.json):  # the import's summary: what it adapted, what to check
        for r in results[:1]:
            for line in r.details.get("adapted", ()):
                print(f"{PROG}: import: {line}", file=sys.stderr)
            for line in r.details.get("warnings", ()):
                print(f"{PROG}: warning: {line}", file=sys.stderr)
    if args.json:
        print(json.dumps([r.to_dict() for r in results], indent=1))
    else:
        rows = [[r.name, r.status, r.reason, f"{r.seconds:.2f} s",
                 ", ".join(f"{k}={v}" for k, v in r.details.items() if not isinstance(v, (dict, list)))]
                for r in results]  # per-view details (the mvs stage's sources): in --json and scene.json
        print_table(["stage", "status", "reason", "time", "output"], rows,
                    title=f"{PROG} {args.input} -> {args.output}", quiet=args.quiet)
        if all(r.status != "ran" for r in results) and not args.quiet:
            print("nothing to do: every stage is up to date")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run_command(PROG, _body, build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
