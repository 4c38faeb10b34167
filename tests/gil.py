"""Structural check that a kernel releases the GIL (all kernels do): run it in a second Python
thread while the main thread records time stamps. A kernel that holds the GIL leaves no stamps
inside its run (negative control, run by hand: `sum(range(3 * 10**7))` as the work gives 0)."""
from __future__ import annotations

import threading
import time
from typing import Callable


def stamps_during(work: Callable[[], object]) -> tuple[float, float, list[float]]:
    """(start, end) of ``work()`` run in another thread, and the main thread's time stamps."""
    span: dict[str, float] = {}

    def run() -> None:
        span["t0"] = time.perf_counter()
        work()
        span["t1"] = time.perf_counter()

    stamps: list[float] = []
    th = threading.Thread(target=run)
    th.start()
    while th.is_alive():
        stamps.append(time.perf_counter())
    th.join()
    return span["t0"], span["t1"], stamps


def stamps_in_middle(t0: float, t1: float, stamps: list[float]) -> int:
    """How many stamps fall in the middle half of [t0, t1] (away from thread start/stop)."""
    lo, hi = t0 + 0.25 * (t1 - t0), t1 - 0.25 * (t1 - t0)
    return sum(lo < s < hi for s in stamps)


def runs_python_during(work: Callable[[], object], tries: int = 3, min_span: float = 0.02) -> bool:
    """Whether this thread ran Python in the middle of ``work()`` (run in another thread), in any
    of ``tries`` attempts that lasted at least ``min_span`` s. Retrying keeps the check's power (a
    kernel that holds the GIL leaves no stamp in any attempt) while a heavily loaded machine that
    did not schedule this thread during one short attempt does not fail it."""
    for _ in range(tries):
        t0, t1, stamps = stamps_during(work)
        if t1 - t0 >= min_span and stamps_in_middle(t0, t1, stamps) > 0:
            return True
    return False
