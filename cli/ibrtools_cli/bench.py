"""ibr-bench: run time against error of a method over a sweep of its parameters on held-out
views (ibrtools.pipeline.sweep; Prakash et al. 2021 sec. 7).

    ibr-bench SCENE --method hybrid --sweep sigma=1:3:5,alpha=7 --sweep tau_var=0:0.1:0.82 -o out/sweep
"""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

import numpy as np

from ibrtools.errors import BadValueError

from .common import (ArgumentParser, add_common, param_flag, print_json, print_table, progress_bar, run_command,
                     warn_stale)

PROG = "ibr-bench"


def build_parser() -> argparse.ArgumentParser:
    from ibrtools.methods import METHODS

    p = ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Sweep a method's parameters on a scene and write run time against error "
                    "(sweep.csv, sweep.png plot, sweep.md Markdown table, report.html: the plot, the "
                    "table and the frames of the best configuration beside their ground truth with "
                    "error heat maps; docs/reports.md) into -o DIR. Frames: the --holdout views "
                    "(removed from the inputs), else the scene's targets with ground truth.",
        epilog="sweep grammar: --sweep key=v1:v2:v3 gives a parameter its values; groups are separated by\n"
               "commas (--sweep sigma=1:3:5,alpha=7) or given as repeated --sweep flags; the configurations\n"
               "are the Cartesian product. Any --param key=value of the method can be swept.\n\n"
               "examples:\n"
               "  ibr-bench scenes/objects --method hybrid --sweep sigma=1:3:5,gamma=3:7 "
               "--sweep tau_var=0:0.1:0.82 -o out/sweep\n"
               "  ibr-bench scenes/objects --method ulr --sweep k=2:4:8 --holdout v003 -o out/ulr --json -q > ulr.json\n"
               "  (then open out/sweep/report.html in a browser)")
    p.add_argument("scene", metavar="SCENE", help="scene directory (ibr-preprocess output)")
    p.add_argument("--method", default="auto", choices=list(METHODS), help="method (default: auto)")
    p.add_argument("--sweep", action="append", metavar="KEY=V1:V2,...", help="parameter values to sweep (repeatable)")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="fixed method parameter (repeatable)")
    p.add_argument("--holdout", nargs="+", metavar="NAME", help="input views to hold out and score")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    p.add_argument("--report-frames", type=int, default=8, metavar="N",
                   help="frames of the best configuration shown in report.html (default 8)")
    p.add_argument("--json", action="store_true",
                   help="print the sweep (one row per configuration, the output files) as JSON on stdout, "
                        "and nothing else")
    add_common(p)
    return p


def _param_flag(name: str | None, args: argparse.Namespace) -> str:
    """--sweep NAME for a swept parameter, else --param NAME."""
    swept = {g.split("=", 1)[0].strip() for spec in args.sweep or () for g in spec.split(",") if "=" in g}
    return f"--sweep {name}" if name in swept else param_flag(name, args)


def _body(args: argparse.Namespace) -> int:
    from ibrtools.formats import native
    from ibrtools.outputs import OutputDir, check_output_dir
    from ibrtools.pipeline.sweep import _value, parse_sweep, sweep
    from ibrtools_cli.common import parse_options

    out = check_output_dir(args.output)
    grid = parse_sweep(args.sweep)
    base = {k: _value(v) for k, v in parse_options(args.param).items()}
    both = sorted(set(base) & set(grid))
    if both:
        raise BadValueError(f"--param and --sweep both set {both}")
    from ibrtools import methods
    from ibrtools.pipeline.sweep import configurations

    if args.method != "auto" and args.method in methods.BUILT:
        for config in configurations(grid, base):  # bad values: exit 2 before the scene is read
            methods.check_params(args.method, config)
    if args.report_frames < 0:
        raise BadValueError(f"--report-frames: expected a number >= 0, got {args.report_frames}")
    from ibrtools.pipeline.report_html import check_output

    check_output(out / "report.html", "output")
    # The output directory is held for the run (a second job there is refused) and a dead run's
    # temporaries are swept (ibrtools.outputs).
    with OutputDir(out, stems={"sweep", "report"}):
        scene = native.load(args.scene)
        stale = warn_stale(PROG, scene, args.method, silent=args.quiet or args.json)
        keep = _BestFrames(args.report_frames)
        with progress_bar(PROG, "configurations x frames", None, quiet=args.quiet) as bar:
            def progress(ci: int, nc: int, fi: int, nf: int) -> None:
                bar.update(ci * nf + fi, nc * nf, f"configuration {min(ci + 1, nc)}/{nc}")

            rows = sweep(scene, args.method, grid, holdout=args.holdout, base=base, out_dir=out, progress=progress,
                         frame_hook=keep)
        keep.finish()
        from ibrtools.pipeline.plan import holdout_note
        from ibrtools.methods import resolve
        from ibrtools.pipeline.sweep import bench_report

        name = resolve(args.method, scene)
        note = holdout_note(scene, args.holdout or [], name)
        if note and not (args.quiet or args.json):
            print(f"{PROG}: note: {note}", file=sys.stderr)
        keys = list(grid)
        html = bench_report(rows, keys, out, out / "report.html", panels=keep.panels, panels_config=keep.config,
                            title=f"{PROG} --method {name}: {len(rows)} configurations on "
                                  f"{rows[0]['frames'] if rows else 0} frames")
        if args.json:
            print_json({"method": name, "swept": keys, "configurations": rows, **({"holdout_note": note} if note else {}),
                        **({"stale_note": stale} if stale else {}),
                        "files": {k: str(out / k) for k in ("sweep.csv", "sweep.md", "sweep.png")} | {"report.html": str(html)}})
            return 0
        best = min(range(len(rows)), key=lambda i: (rows[i]["mean_flip"] is None, rows[i]["mean_flip"] or 0), default=None)
        print_table(["config", *keys, "median ms", "PSNR dB", "SSIM", "FLIP"],
                    [[r["config"], *[r[k] for k in keys], r["median_ms"], r["mean_psnr"], r["mean_ssim"], r["mean_flip"]]
                     for r in rows], quiet=args.quiet,
                    title=f"{PROG} --method {name}: {len(rows)} configurations x {rows[0]['frames'] if rows else 0} "
                          f"frames -> {out}",
                    totals=None if best is None else
                    [f"best: {rows[best]['config']}",
                     *[""] * len(keys), f"fastest {min(r['median_ms'] for r in rows)}",
                     max((r["mean_psnr"] for r in rows if r["mean_psnr"] is not None), default="-"),
                     max((r["mean_ssim"] for r in rows if r["mean_ssim"] is not None), default="-"),
                     rows[best]["mean_flip"] if rows[best]["mean_flip"] is not None else "-"])
        if not args.quiet:
            print(f"HTML report: {html}")
        return 0


class _BestFrames:
    """``sweep(frame_hook=...)``: keeps shrunk copies (at most 640 pixels wide) of the first ``n``
    frames of the configuration with the lowest mean FLIP so far (mean PSNR, higher, when FLIP
    is not available); one configuration's copies are held at a time besides the best's. The
    panels (error maps: FLIP costs ~0.6 s per 640x480 frame) are made at the end, for the best
    configuration only."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.config = None
        self._kept: list = []
        self._best = None
        self._ci = None
        self._cur: list = []
        self._scores: list = []

    def __call__(self, ci, fi, frame, out, stage_ms, metrics) -> None:
        from ibrtools.pipeline.report_html import shrink

        if ci != self._ci:
            self.finish()
            self._ci, self._cur, self._scores = ci, [], []
        flip, psnr = metrics.get("flip"), metrics.get("psnr")
        self._scores.append(flip if flip is not None else (-psnr if psnr is not None else None))
        if fi < self.n:
            numbers = {k: metrics.get(k) for k in ("psnr", "ssim", "flip", "coverage") if k in metrics}
            small = {k: None if out.get(k) is None else shrink(np.asarray(out[k], np.float32))
                     for k in ("color", "selection", "hole")}
            self._cur.append((frame.name, small, shrink(frame.truth.color),
                              {k: v for k, v in stage_ms.items() if k != "total"},
                              {**numbers, "ms": round(stage_ms["total"], 2)}))

    def finish(self) -> None:
        if self._ci is None:
            return
        vals = [v for v in self._scores if v is not None]
        score = sum(vals) / len(vals) if vals else float("inf")
        if self._best is None or score < self._best:
            self._best, self.config, self._kept = score, self._ci, self._cur
        self._ci, self._cur = None, []

    @property
    def panels(self) -> list:
        from ibrtools.pipeline.report_html import frame_panel

        return [frame_panel(name, small["color"], truth, selection=small["selection"],
                            hole=small["hole"],
                            stage_ms=stage, numbers=numbers)
                for name, small, truth, stage, numbers in self._kept]


def main(argv: Sequence[str] | None = None) -> int:
    return run_command(PROG, _body, build_parser(), argv, _param_flag)


if __name__ == "__main__":
    sys.exit(main())
