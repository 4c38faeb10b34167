"""ibr-bench: run time against error of a method over a sweep of its parameters on held-out
views (ibrtools.render.sweep; Prakash et al. 2021 sec. 7).

    ibr-bench SCENE --method hybrid --sweep sigma=1:3:5,alpha=7 --sweep tau_var=0.5:0.82 -o out/sweep
"""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from ibrtools.errors import BadValueError

from .common import add_common, print_table, run_command

PROG = "ibr-bench"


def build_parser() -> argparse.ArgumentParser:
    from ibrtools.render.methods import METHODS

    p = argparse.ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Sweep a method's parameters on a scene and write run time against error "
                    "(sweep.csv, sweep.png plot, sweep.md Markdown table) into -o DIR. Frames: the "
                    "--holdout views (removed from the inputs), else the scene's targets with ground truth.",
        epilog="sweep grammar: --sweep key=v1:v2:v3 gives a parameter its values; groups are separated by\n"
               "commas (--sweep sigma=1:3:5,alpha=7) or given as repeated --sweep flags; the configurations\n"
               "are the Cartesian product. Any --param key=value of the method can be swept.\n\n"
               "example:\n"
               "  ibr-bench scenes/objects --method hybrid --sweep sigma=1:3:5,gamma=3:7 "
               "--sweep tau_var=0.5:0.82 -o out/sweep")
    p.add_argument("scene", metavar="SCENE", help="scene directory (ibr-preprocess output)")
    p.add_argument("--method", default="auto", choices=list(METHODS), help="method (default: auto)")
    p.add_argument("--sweep", action="append", metavar="KEY=V1:V2,...", help="parameter values to sweep (repeatable)")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="fixed method parameter (repeatable)")
    p.add_argument("--holdout", nargs="+", metavar="NAME", help="input views to hold out and score")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    add_common(p)
    return p


def _body(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ibrtools.formats import native
    from ibrtools.render.sweep import _value, parse_sweep, sweep
    from ibrtools.stages import parse_options

    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise BadValueError(f"-o {out}: exists and is not a directory")
    grid = parse_sweep(args.sweep)
    base = {k: _value(v) for k, v in parse_options(args.param).items()}
    both = sorted(set(base) & set(grid))
    if both:
        raise BadValueError(f"--param and --sweep both set {both}")
    scene = native.load(args.scene)

    def progress(ci: int, nc: int, fi: int, nf: int) -> None:
        if not args.quiet and sys.stderr.isatty():
            print(f"\r{PROG}: configuration {ci + 1}/{nc} frame {fi + 1}/{nf}   ", end="", file=sys.stderr)

    rows = sweep(scene, args.method, grid, holdout=args.holdout, base=base, out_dir=out, progress=progress)
    if not args.quiet and sys.stderr.isatty():
        print(file=sys.stderr)
    keys = list(grid)
    print_table(["config", *keys, "median ms", "PSNR dB", "SSIM", "FLIP"],
                [[r["config"], *[r[k] for k in keys], r["median_ms"], r["mean_psnr"], r["mean_ssim"], r["mean_flip"]]
                 for r in rows], title=f"{PROG} --method {args.method} -> {out}", quiet=args.quiet)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run_command(PROG, _body, build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
