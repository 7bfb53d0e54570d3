"""Local worker processes that end with the process that started them, on any signal.

A pool's workers are children of the main process; when it is killed (SIGTERM, SIGKILL) they
would live on, re-parented to PID 1. Each worker here watches its parent: when the parent is
gone (the worker's parent PID changes) it exits at once. When the main process stops early (an
error, Ctrl-C, SIGTERM), the pool's queued tasks are dropped and its workers ended, rather than
waited for. Workers ignore Ctrl-C (the main process handles it) and end on SIGTERM."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor

#: How often a worker looks for its parent, seconds.
WATCH_INTERVAL_S = 0.2


def _watch(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(WATCH_INTERVAL_S)
    os._exit(1)  # no cleanup to wait for: the results have nowhere to go


def _start_watching(niceness: int = 0) -> None:
    """Pool initializer: a daemon thread that ends this worker once its parent is gone; the
    signal handlers a forked worker inherited from the main process reset; `niceness` added to
    the worker's (lower priority: the main process first)."""
    if niceness:
        with contextlib.suppress(OSError):
            os.nice(niceness)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    threading.Thread(target=_watch, args=(os.getppid(),), daemon=True).start()


@contextlib.contextmanager
def process_pool(workers: int, niceness: int = 0) -> Iterator[ProcessPoolExecutor]:
    """A ProcessPoolExecutor of `workers` processes that exit when their parent does; when the
    block ends by an exception (Ctrl-C, SIGTERM, an error) its workers are ended at once.
    niceness: added to the workers' (background work that must not slow the main process)."""
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_start_watching,
                               initargs=(int(niceness),))
    try:
        yield pool
    except BaseException:
        procs = list((getattr(pool, "_processes", None) or {}).values())  # shutdown drops them
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            with contextlib.suppress(OSError, ValueError, AttributeError):
                proc.terminate()
        raise
    finally:
        pool.shutdown(wait=True)
