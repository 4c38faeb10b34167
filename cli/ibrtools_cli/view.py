"""ibr-view: look around a scene in the browser, the engine rendering every frame."""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from .common import ArgumentParser, add_common, run_command

PROG = "ibr-view"


def build_parser() -> argparse.ArgumentParser:
    from ibrtools.methods import METHODS

    p = ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Serve a scene as a web page: the current frame (rendered by the engine), orbit and fly "
                    "controls, the input cameras on a map, a method switch, hole / method-choice overlays and "
                    "camera-path recording (saved as a poses file for ibr-render --poses). Prints the page's "
                    "URL (with a random token); bound to localhost unless --host says otherwise; Ctrl-C stops "
                    "it (docs/viewer.md).",
        epilog="examples:\n"
               "  ibr-view scenes/objects                  # then open the printed URL\n"
               "  ibr-view scenes/hybrid --method hybrid --port 8765\n"
               "  ssh -L 8765:localhost:8765 server 'ibr-view scenes/objects --port 8765'   # a headless machine")
    p.add_argument("scene", metavar="SCENE", help="scene directory (ibr-preprocess output)")
    p.add_argument("--method", default="auto", choices=list(METHODS), help="the first method shown (default: auto)")
    p.add_argument("--port", type=int, default=0, metavar="P", help="port (default: a free one)")
    p.add_argument("--host", default="127.0.0.1", metavar="ADDR",
                   help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--save-dir", default=".", metavar="DIR",
                   help="where the page's saved camera paths go, as <name>.json (default: the current directory)")
    add_common(p)
    return p


def _body(args: argparse.Namespace) -> int:
    from ibrtools.errors import BadValueError
    from ibrtools.formats import native
    from ibrtools.viewer import Viewer

    if not 0 <= args.port <= 65535:
        raise BadValueError(f"--port: expected 0..65535, got {args.port}")
    scene = native.load(args.scene)
    try:
        viewer = Viewer(scene, args.method, host=args.host, port=args.port, save_dir=args.save_dir)
    except OSError as e:
        raise BadValueError(f"--host {args.host} --port {args.port}: cannot listen there ({e.strerror or e})") from None
    print(f"{PROG}: {args.scene}: open {viewer.url}", flush=True)
    try:
        viewer.serve_forever()
    except KeyboardInterrupt:
        if not args.quiet:
            print(f"{PROG}: stopped", file=sys.stderr)
    finally:
        viewer.shutdown()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run_command(PROG, _body, build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
