"""Starting the commands as subprocesses that a test can interrupt.

A process started with SIGINT ignored keeps it ignored across exec, and Python then installs no
KeyboardInterrupt handler: that is what a shell does to a background job (`make test &`,
`( pytest ... & )`, `nohup ... &`: SIGINT and SIGQUIT set to SIG_IGN), and pytest's workers pass
it on. A command started from there, correctly, ignores SIGINT and runs to its end: the flaky
failures of the SIGINT tests (exit 0, or a timeout). Tests that send SIGINT therefore start the
command through :func:`interruptible`, an exec with SIGINT at its default action, whatever the
test process inherited.
"""
from __future__ import annotations

import sys

_SIGINT_DEFAULT = [sys.executable, "-c", "import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
                   "os.execv(sys.argv[1], sys.argv[1:])"]


def interruptible(argv: list[str]) -> list[str]:
    """``argv`` run with SIGINT at its default action (the same process: exec, not a child)."""
    return _SIGINT_DEFAULT + list(argv)
