"""What every command shares: thread/debug/quiet flags, the error policy and tables.

Exit codes: 0 success, 2 bad input or usage (one line on stderr,
no traceback unless --debug), 1 internal error.
"""
from __future__ import annotations

import argparse
import atexit
import contextlib
import json
import math
import os
import signal
import sys
from typing import Callable, Iterator, Sequence

from ibrtools.cache import ALL_METHODS, ORDER, STAGES, available_stages, default_methods
from ibrtools.errors import BadValueError, InputError, NotBuiltError, ParamError


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser whose usage errors are one line, like every other bad input: ``prog:
    error: <message>; see prog --help`` on stderr and exit status 2 (argparse prints the whole
    usage block first, a dozen lines for our commands, before the one line that matters)."""

    def error(self, message: str):  # noqa: D401 - argparse's hook
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}; see {self.prog} --help\n")


def add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-j", "--threads", type=int, default=0, metavar="N",
                        help="threads for the engine (default: all cores)")
    parser.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")


def set_threads(n: int) -> None:
    if n < 0:
        raise InputError(f"--threads: expected a non-negative number, got {n}")
    from ibrtools import _core

    _core.set_num_threads(n)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so that every ``finally`` and ``except
    BaseException`` on the way out runs: temporary files are removed and partial outputs undone
    (the default action of SIGTERM ends the process on the spot, leaving them behind)."""


_TERMINATED = False


def _on_sigterm(signum, frame):
    global _TERMINATED
    _TERMINATED = True  # remembered: an extension module being imported may turn the exception into its own
    raise Terminated()


def _terminated(prog: str, argv: Sequence[str] | None) -> int:
    """Exit status 143 after SIGTERM (our cleanups have run by now). As the console command
    (argv None), end the process right after the atexit stage: an extension whose import the
    signal cut short (open3d) can turn the exit status into 1 while the interpreter shuts down."""
    print(f"{prog}: terminated", file=sys.stderr)
    if argv is None:
        def _exit_now() -> None:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(143)

        atexit.register(_exit_now)
    return 143


def param_flag(name: str | None, args: argparse.Namespace) -> str:
    """The flag that sets method parameter ``name``: ``--param NAME`` (``--param`` for an unknown
    key); commands with flags of their own for some parameters pass their own function."""
    return "--param" if name is None else f"--param {name}"


ARG_FLAGS = {"options": "--opt", "stage_options": "--set", "params": "--param", "grid": "--sweep",
             "out_dir": "--output", "targets": "--target", "centre": "--center"}
"""The flags whose names are not the library's keywords (the rest: ``--`` and the keyword with ``-``
for ``_``: ``max_size`` is ``--max-size``)."""


def arg_flag(name: str) -> str:
    """The flag that sets the library's argument ``name``."""
    return ARG_FLAGS.get(name, "--" + name.replace("_", "-"))


def error_line(e: InputError | NotBuiltError, args: argparse.Namespace,
               flag_of: Callable[[str | None, argparse.Namespace], str] = param_flag) -> str:
    """The message of ``e`` as the command's user reads it: an error about an argument or a method
    parameter is named by the flag that sets it."""
    if isinstance(e, ParamError):
        return f"{flag_of(e.param, args)}: {e.detail}"
    if e.argument:
        shown = "" if e.value is None else f" {e.value}"
        return f"{'/'.join(arg_flag(a) for a in e.argument)}{shown}: {e.detail}"
    return str(e)


def run_command(prog: str, body: Callable[[argparse.Namespace], int],
                parser: argparse.ArgumentParser, argv: Sequence[str] | None,
                flag_of: Callable[[str | None, argparse.Namespace], str] = param_flag) -> int:
    """Run ``body(args)``: bad input is one ``PROG: error:`` line and exit 2 (a method parameter's
    error named by the flag ``flag_of`` gives), interrupts 130, anything else exit 1."""
    args = parser.parse_args(argv)
    try:
        old_term = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread (a command called from a library thread)
        old_term = None
    try:
        set_threads(args.threads)
        return body(args)
    except Terminated:
        return _terminated(prog, argv)
    except (InputError, NotBuiltError) as e:
        if args.debug:
            raise
        print(f"{prog}: error: {error_line(e, args, flag_of)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - the last line of defence: one line, exit 1
        if _TERMINATED:  # SIGTERM inside an extension's import (open3d reports "ImportError: initialization failed")
            return _terminated(prog, argv)
        if args.debug:
            raise
        print(f"{prog}: internal error: {type(e).__name__}: {e} (run with --debug for the traceback)",
              file=sys.stderr)
        return 1
    finally:
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)


def print_table(headers: list[str], rows: list[list[str]], title: str | None = None,
                quiet: bool = False, totals: list[str] | None = None) -> None:
    """A rich table on stdout; ``totals`` is a last row set apart by a rule (the summary)."""
    if quiet:
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title, title_justify="left")
    for h in headers:
        table.add_column(h)
    for i, r in enumerate(rows):
        table.add_row(*[str(c) for c in r], end_section=totals is not None and i == len(rows) - 1)
    if totals is not None:
        table.add_row(*[str(c) for c in totals], style="bold")
    Console(width=max(100, Console().width)).print(table)


def warn_stale(prog: str, scene, method: str, *, silent: bool) -> str | None:
    """Print (to stderr, before the run: it may take minutes) a warning when a preprocessing stage
    that ``--method`` reads is out of date in ``scene`` (ibrtools.pipeline.plan.stale_note), and
    return the note (None when current). ``silent`` (``-q``, ``--json``): not printed; the
    report and the JSON carry it as "stale_note"."""
    from ibrtools.pipeline.plan import stale_note
    from ibrtools.methods import resolve

    note = stale_note(scene, resolve(method, scene))
    if note and not silent:
        print(f"{prog}: warning: {note}", file=sys.stderr)
    return note


def print_json(doc) -> None:
    """``--json``: the document alone on stdout (NaN/inf are not JSON: written as null)."""
    import json

    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {str(k): clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if hasattr(v, "item") and callable(v.item):  # numpy scalars
            return clean(v.item())
        return v

    sys.stdout.write(json.dumps(clean(doc), indent=1, allow_nan=False) + "\n")
    sys.stdout.flush()


class _NoBar:
    """What :func:`progress_bar` gives when no bar is shown: every call does nothing."""

    shown = False

    def update(self, done: int, total: int | None = None, label: str = "") -> None:
        pass

    def advance(self, label: str = "") -> None:
        pass


class _Bar:
    shown = True

    def __init__(self, progress, task) -> None:
        self._p, self._t = progress, task

    def update(self, done: int, total: int | None = None, label: str = "") -> None:
        """``done`` of ``total`` steps finished; ``label`` names the step under way."""
        kw = {"total": total} if total is not None else {}
        self._p.update(self._t, completed=done, label=label, **kw)

    def advance(self, label: str = "") -> None:
        self._p.update(self._t, advance=1, label=label)


@contextlib.contextmanager
def progress_bar(prog: str, what: str, total: int | None = None, *, quiet: bool = False,
                 stream=None) -> Iterator[_Bar | _NoBar]:
    """THE progress bar of every command (rich, on stderr): shown only when ``stream`` (default
    stderr) is a terminal and not ``quiet``, so pipes, logs, --json and tests see nothing.
    Yields an object with ``update(done, total, label)`` and ``advance(label)``; ``total`` None
    shows a pulsing bar (unknown length) with the elapsed time."""
    stream = sys.stderr if stream is None else stream
    if quiet or not (hasattr(stream, "isatty") and stream.isatty()):
        yield _NoBar()
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, \
        TimeRemainingColumn

    console = Console(file=stream)
    with Progress(TextColumn(f"[bold]{prog}[/] {what}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), TextColumn("{task.fields[label]}"),
                  console=console, transient=False, redirect_stdout=False, redirect_stderr=False) as p:
        task = p.add_task(what, total=total, label="")
        yield _Bar(p, task)


def add_distributed(parser: argparse.ArgumentParser) -> None:
    """``--workers N`` / ``--scheduler ADDRESS``: run on Dask (docs/distributed.md); checked by
    ibrtools.pipeline.distributed.check_options (negative N, both at once: exit 2)."""
    g = parser.add_argument_group("distributed execution (Dask; docs/distributed.md)")
    g.add_argument("--workers", type=int, default=0, metavar="N",
                   help="start a local Dask cluster of N worker processes (one engine thread each unless -j)")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on an existing Dask cluster, e.g. tcp://HOST:8786 (the workers must see the "
                        "scene at the same path)")


def parse_methods(text: str | None) -> list[str]:
    if text is None or text == "auto":
        return default_methods()
    if text == "all":
        return list(ALL_METHODS)
    out = [t.strip() for t in text.split(",") if t.strip()]
    bad = [m for m in out if m not in ALL_METHODS]
    if bad or not out:
        raise BadValueError(f"--methods {text!r}: expected a comma-separated list of {', '.join(ALL_METHODS)} "
                            "(or 'auto', 'all')")
    return out


def parse_stages(text: str | None) -> list[str] | None:
    if text is None:
        return None
    out = [t.strip() for t in text.split(",") if t.strip()]
    known = list(ORDER)
    bad = [s for s in out if s not in known]
    if bad or not out:
        raise BadValueError(f"--stages {text!r}: expected a comma-separated list of {', '.join(known)}")
    absent = [s for s in out if s not in available_stages()]
    if absent:
        raise NotBuiltError(f"--stages: {', '.join(absent)} not built yet")
    return out


def parse_options(pairs: list[str] | None) -> dict:
    """``key=value`` strings (``--opt``) into a dict; numbers stay strings (importers convert)."""
    out: dict = {}
    for p in pairs or []:
        if "=" not in p or not p.split("=", 1)[0]:
            raise InputError(f"--opt {p!r}: expected key=value")
        k, v = p.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def parse_stage_options(pairs: list[str] | None) -> dict:
    """``STAGE.KEY=VALUE`` strings (``--set``) into {stage: {key: value}}; values are read as JSON
    when they parse (numbers, true/false), else kept as strings."""
    out: dict = {}
    for p in pairs or []:
        if "=" not in p or "." not in p.split("=", 1)[0]:
            raise InputError(f"--set {p!r}: expected STAGE.KEY=VALUE, e.g. pvm.max_block=8")
        k, v = p.split("=", 1)
        stage, key = k.strip().split(".", 1)
        if stage not in STAGES:
            raise InputError(f"--set {p!r}: unknown stage {stage!r} (expected one of {', '.join(STAGES)})")
        try:
            value = json.loads(v)
        except ValueError:
            value = v.strip()
        out.setdefault(stage, {})[key.strip()] = value
    if "texture" in out or "depth" in out:
        raise InputError("--set: texture and depth read their parameters from mesh.* (e.g. mesh.k_views=4)")
    return out
