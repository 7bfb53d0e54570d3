"""Local worker processes that end with the process that started them, on any signal.

A pool's workers are children of the main process; when it is killed (SIGTERM, SIGKILL) they
would live on, re-parented to PID 1. Each worker here watches its parent: when the parent is
gone (the worker's parent PID changes) it exits at once."""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor

#: How often a worker looks for its parent, seconds.
WATCH_INTERVAL_S = 0.2


def _watch(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(WATCH_INTERVAL_S)
    os._exit(1)  # no cleanup to wait for: the results have nowhere to go


def _start_watching() -> None:
    """Pool initializer: a daemon thread that ends this worker once its parent is gone."""
    threading.Thread(target=_watch, args=(os.getppid(),), daemon=True).start()


def process_pool(workers: int) -> ProcessPoolExecutor:
    """A ProcessPoolExecutor of `workers` processes that exit when their parent does."""
    return ProcessPoolExecutor(max_workers=workers, initializer=_start_watching)
