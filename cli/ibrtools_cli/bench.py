"""ibr-bench: run time against error for a method on a scene.

Reserved: parameter sweeps with peers measured in the same run arrive with the methods
(DESIGN.md "Commands"). Until then the command exists, explains itself and exits with 2.
"""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from ibrtools.errors import NotBuiltError

from .common import add_common, run_command

PROG = "ibr-bench"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Sweep a method's parameters on a scene and write run time against error "
                    "(CSV, PNG plot, Markdown table). Not built yet: the sweeps come with the "
                    "novel-view methods. For the reference renderer's speed see benchmarks/.")
    p.add_argument("scene", metavar="SCENE", nargs="?", help="scene directory")
    p.add_argument("--method", default="auto")
    add_common(p)
    return p


def _body(args: argparse.Namespace) -> int:
    raise NotBuiltError("ibr-bench is not built yet: parameter sweeps arrive with the novel-view methods; "
                        "run 'make bench' (benchmarks/) for the reference renderer")


def main(argv: Sequence[str] | None = None) -> int:
    return run_command(PROG, _body, build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
