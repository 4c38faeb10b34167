"""Distributed execution on Dask (docs/distributed.md).

``ibr-render`` / ``ibr-preprocess`` with ``--workers N`` start a :class:`distributed.LocalCluster`
(N worker processes on loopback, one Dask thread each, no dashboard, quiet logs); with
``--scheduler ADDRESS`` they connect a :class:`distributed.Client` to an existing cluster.

What travels: the scene is shared by PATH (every worker loads it itself with
:func:`ibrtools.formats.native.load`; all machines must see the same file system), never
scattered. A render task carries a small spec (scene path, ``plan()``'s keyword arguments,
method, parameters, post-processing options: a few hundred bytes) and a chunk of frame indices;
it sends back each frame's report entry and its output files already encoded (PNG/EXR bytes,
made by the same writer a local run uses, so the files are bit-identical). A worker prepares
the method once per (scene, plan, method, parameters) and reuses it for every frame it is given
(``ibrtools.pipeline.job``: the worker side, a per-process cache of one prepared method).

Failures: a frame whose render raises comes back as a failure record (the job goes on); a task
that dies with its worker is rescheduled by the scheduler (and ``retries`` covers errors around
the frame function), so no frame is lost.
"""
from __future__ import annotations

import contextlib
import logging
import os
from pathlib import Path
from typing import Callable, Iterator

from ibrtools.errors import BadValueError, InputError

# Seconds to wait for an existing scheduler before saying it cannot be reached.
CONNECT_TIMEOUT = 5.0
# Retries of a task that raised outside the per-frame error handling (a worker lost mid-task
# is rescheduled by the scheduler whatever this says: distributed.scheduler.allowed-failures).
RETRIES = 2
HINT = "install the distributed extra: pip install 'ibrtools[distributed]' (dask[distributed])"


class MissingDaskError(InputError):
    """Workers or a scheduler asked for but dask.distributed is not installed."""


def check_options(scheduler: str | None, workers: int) -> None:
    """Usage errors before any work: a negative worker count, both options at once."""
    if isinstance(workers, bool) or not isinstance(workers, int):
        raise BadValueError.about("workers", f"expected a whole number, got {workers!r}")
    if workers < 0:
        raise BadValueError.about("workers", f"expected a number of worker processes >= 0, got {workers}")
    if scheduler is not None and workers:
        raise BadValueError.about(("workers", "scheduler"), "give one: a number of workers starts a local "
                                                             "cluster, a scheduler's address uses an existing one")
    if scheduler is not None and (not isinstance(scheduler, str) or not scheduler.strip()):
        raise BadValueError.about("scheduler", f"expected an address such as tcp://host:8786, got {scheduler!r}")


def wanted(scheduler: str | None, workers: int) -> bool:
    return scheduler is not None or workers > 0


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise MissingDaskError.about(("workers", "scheduler"),
                                     f"distributed execution needs dask.distributed; {HINT}") from None
    return distributed


@contextlib.contextmanager
def open_client(scheduler: str | None = None, workers: int = 0, *, threads_per_worker: int = 1) -> Iterator:
    """A connected :class:`distributed.Client`: to ``scheduler`` (an existing cluster; a clear
    error within :data:`CONNECT_TIMEOUT` s when it cannot be reached), or to a LocalCluster of
    ``workers`` processes started here (and closed on the way out)."""
    check_options(scheduler, workers)
    if not wanted(scheduler, workers):
        raise BadValueError("open_client: give scheduler=ADDRESS or workers=N")
    distributed = _import_distributed()
    interrupted = [False]
    if scheduler is not None:
        try:
            client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as e:
            raise BadValueError.about("scheduler", f"cannot connect ({e})", scheduler) from None
        try:
            with _note_interrupt(interrupted):
                yield client
        finally:
            with _quiet(interrupted[0]):
                client.close()
        return
    import dask

    # Dask starts its worker processes with MALLOC_TRIM_THRESHOLD_=65536 (to hand freed memory
    # back to the OS). Setting it turns off glibc's dynamic mmap threshold: every large array
    # (a 1080p frame buffer) is then a fresh mmap, page-faulted anew for every frame, which a
    # plain process does not pay (docs/distributed.md: the effect's size was not established on
    # the loaded development machine). The nanny reads this environment when it is made (also
    # for the replacement of a worker that died).
    environ = {k: v for k, v in (dask.config.get("distributed.nanny.pre-spawn-environ", None) or {}).items()
               if k != "MALLOC_TRIM_THRESHOLD_"}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker,
                                           processes=True, host="127.0.0.1", dashboard_address=None,
                                           silence_logs=logging.ERROR,
                                           # no dashboard; the scheduler's HTTP endpoint on loopback too
                                           scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    try:
        client = distributed.Client(cluster, set_as_default=False)
        try:
            # Ctrl-C reaches the whole process group: the command handles it (all or nothing,
            # then stops the cluster), so its workers ignore it (new ones too: a plugin).
            client.register_plugin(_ignore_sigint_plugin(), name="ibrtools-ignore-sigint")
            with _note_interrupt(interrupted):
                yield client
        finally:
            with _quiet(interrupted[0]):
                client.close()
    finally:
        with _quiet(interrupted[0]):
            cluster.close()


@contextlib.contextmanager
def _note_interrupt(flag: list) -> Iterator[None]:
    """Marks ``flag`` when the block is interrupted; meanwhile the client's event loop does not
    print the traceback of dask's own Ctrl-C bug (:func:`_drop_cancel_before_start`)."""
    tornado_log = logging.getLogger("tornado.application")
    tornado_log.addFilter(_drop_cancel_before_start)
    try:
        yield
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM through the commands' handler
        flag[0] = True
        raise
    finally:
        tornado_log.removeFilter(_drop_cancel_before_start)


def _drop_cancel_before_start(record: logging.LogRecord) -> bool:
    """Logging filter of the client's event loop: an interrupt that reaches ``distributed.utils.sync``
    before its call has started schedules a ``cancel`` callback that reads the not-yet-assigned
    future and raises NameError on the loop thread (dask 2026.8), which tornado logs with a
    traceback, racing the command's own shutdown. Harmless (there is nothing to cancel); dropped.
    Every other record passes."""
    exc = record.exc_info[1] if record.exc_info else None
    if not isinstance(exc, NameError) or exc.__traceback__ is None:
        return True
    tb = exc.__traceback__
    while tb.tb_next is not None:
        tb = tb.tb_next
    code = tb.tb_frame.f_code
    return not (code.co_name == "cancel" and code.co_filename.replace(os.sep, "/").endswith("distributed/utils.py"))


@contextlib.contextmanager
def _quiet(on: bool) -> Iterator[None]:
    """After an interrupt, the cluster's shutdown logs tracebacks of the callbacks it cancels
    (tornado, distributed): not the user's concern, so those loggers are silenced meanwhile."""
    names = ("distributed", "tornado", "asyncio")
    old = {n: logging.getLogger(n).level for n in names}
    if on:
        for n in names:
            logging.getLogger(n).setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        if on:
            for n, lvl in old.items():
                logging.getLogger(n).setLevel(lvl)


HEARTBEAT_LOST = "Failed to communicate with scheduler during heartbeat."


def _drop_lost_heartbeat(record: logging.LogRecord) -> bool:
    """Logging filter of a local cluster's workers: a heartbeat that finds the scheduler's
    connection closed. The scheduler lives in the command's own process, so this only happens
    while the command shuts the cluster down (Ctrl-C, SIGTERM, the end of a run): the worker's
    traceback of it is not the user's concern. Every other record passes."""
    return record.msg != HEARTBEAT_LOST


def _ignore_sigint_plugin():
    """A worker plugin of the local cluster: the worker process ignores SIGINT (the command
    handles it and stops the cluster) and does not print the traceback of the heartbeat that
    the cluster's shutdown cuts off (:func:`_drop_lost_heartbeat`). Defined here, not at module
    level, so that importing this module does not import dask."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class IgnoreSigint(WorkerPlugin):
        def setup(self, worker) -> None:
            import signal
            import threading

            logging.getLogger("distributed.worker").addFilter(_drop_lost_heartbeat)
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)

    return IgnoreSigint()


def describe(client, scheduler: str | None) -> dict:
    """The cluster for the report: scheduler ("local" for --workers), worker count, threads."""
    ws = _workers(client)
    return {"scheduler": scheduler or "local", "workers": len(ws),
            "threads_per_worker": sorted({int(w.get("nthreads", 1)) for w in ws.values()})}


def _workers(client) -> dict:
    """Every worker's info (recent versions of scheduler_info() list the first 5 unless told)."""
    import inspect

    try:
        every = "n_workers" in inspect.signature(client.scheduler_info).parameters
    except (TypeError, ValueError):
        every = False
    return (client.scheduler_info(n_workers=-1) if every else client.scheduler_info()).get("workers", {})


# ---------------------------------------------------------------------------------------------
# Worker side: what a task does. Module-level functions, so that workers import them by name.


def engine_threads(threads: int) -> int:
    """Engine threads of a task: ``threads`` when given (-j), else 1. Dask's own model: a
    worker's threads are the cores it may use, one task per thread, so a task gets one core
    (``dask worker --nthreads`` = cores uses a machine; a worker that does not know its siblings
    on the same machine must not take every core, or two of them oversubscribe it)."""
    return threads if threads > 0 else 1


def scene_stamp(root: str | os.PathLike) -> list:
    """What identifies a scene's version on disk: scene.json's size and modification time (any
    stage or re-import rewrites it), so a long-lived worker never reuses a stale preparation."""
    st = (Path(root) / "scene.json").stat()
    return [st.st_size, st.st_mtime_ns]


# --- preprocessing: per-view work of the stages that are per view ------------------------------

def _chunks(items: list, n_workers: int, per_worker: int = 4) -> list[list]:
    """Small chunks of ``items`` (about ``per_worker`` per worker, order kept)."""
    k = max(1, min(len(items), n_workers * per_worker))
    size = -(-len(items) // k)
    return [items[i:i + size] for i in range(0, len(items), size)]


def map_views(client, fn: Callable, root: str | os.PathLike, names: list[str], *args) -> dict:
    """``fn(root, names_chunk, *args) -> {name: value}`` over chunks of ``names`` on the
    cluster; the merged dict in the order of ``names``."""
    n_workers = max(1, len(_workers(client)))
    futures = [client.submit(fn, str(root), c, *args, retries=RETRIES, pure=False)
               for c in _chunks(list(names), n_workers)]
    try:
        parts = client.gather(futures)
    finally:
        client.cancel([f for f in futures if not f.done()])
    merged: dict = {}
    for p in parts:
        merged.update(p)
    return {n: merged[n] for n in names}


def set_task_threads(threads: int) -> None:
    """At the start of a task: the engine's threads (see :func:`engine_threads`)."""
    from ibrtools import _core

    _core.set_num_threads(engine_threads(threads))


class LazyClient:
    """The cluster of a preprocessing run, started (or connected) on first use only, so that a
    run whose per-view stages are up to date or skipped starts none. A context manager."""

    def __init__(self, scheduler: str | None = None, workers: int = 0, threads: int = 0):
        check_options(scheduler, workers)
        self.scheduler, self.workers = scheduler, workers
        self.task_threads = int(threads)  # engine threads per task: -j, else 1 (engine_threads)
        self._stack = contextlib.ExitStack()
        self._client = None

    def __enter__(self) -> "LazyClient":
        return self

    def __exit__(self, *exc) -> None:
        self._client = None
        self._stack.close()

    @property
    def client(self):
        if self._client is None:
            self._client = self._stack.enter_context(open_client(self.scheduler, self.workers))
        return self._client

    def map_views(self, fn: Callable, root: str | os.PathLike, names: list[str], *args) -> dict:
        """:func:`map_views` on this cluster; ``fn`` also receives the engine threads per task."""
        return map_views(self.client, fn, root, names, *args, self.task_threads)
