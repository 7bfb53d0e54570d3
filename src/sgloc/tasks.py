"""The one task runner: a picklable function over a list of picklable tasks, run in this
process, on local worker processes or on a Dask cluster, results in the order of the tasks.
Trials (`sgloc.evaluation.trials`) and a fleet's pairwise localizations run through it."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import as_completed
from typing import Any, TypeVar

from sgloc.errors import SglocError
from sgloc.workers import process_pool

Task = TypeVar("Task")
#: Called with the number of tasks just finished (for a progress bar).
Progress = Callable[[int], None]
#: Seconds to wait for a Dask scheduler to answer.
SCHEDULER_TIMEOUT_S = 15


def run_all(
    tasks: Sequence[Task],
    fn: Callable[[Task], Any],
    workers: int | None = None,
    scheduler: Any = None,
    progress: Progress | None = None,
) -> list[Any]:
    """`fn` of each task (both picklable), in the order of `tasks`.

    workers: local processes (None: the number of CPUs; 0 or 1: in this process).
    scheduler: a Dask scheduler address ("tcp://host:8786") or a `distributed.Client`; when
        given, the tasks run on that cluster instead (its workers must see the same data paths).
    progress: called with the number of tasks just finished.
    """
    tasks = list(tasks)
    tick = progress or (lambda n: None)
    if scheduler is not None:
        return _run_dask(tasks, scheduler, tick, fn)
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers <= 1 or len(tasks) <= 1:
        rows = []
        for t in tasks:
            rows.append(fn(t))
            tick(1)
        return rows
    with process_pool(min(workers, len(tasks))) as pool:
        return _collect([pool.submit(fn, t) for t in tasks], as_completed, tick)


def _collect(futures: list[Any], completed: Callable, tick: Progress) -> list[Any]:
    """The futures' results in their order, calling tick(1) as each completes (any order)."""
    index = {getattr(f, "key", f): i for i, f in enumerate(futures)}  # Dask futures by key
    rows: list[Any] = [None] * len(futures)
    for fut in completed(futures):
        rows[index[getattr(fut, "key", fut)]] = fut.result()
        tick(1)
    return rows


def _run_dask(tasks: list[Any], scheduler: Any, tick: Progress, fn: Callable) -> list[Any]:
    from sgloc.optional import require

    require("distributed", "dask", "--scheduler (running tasks on a Dask cluster)")
    from dask.distributed import Client
    from dask.distributed import as_completed as dask_completed

    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s") if own else scheduler
    except (OSError, TimeoutError, ValueError, TypeError) as e:  # unreachable or malformed
        raise SglocError(
            f"cannot reach the Dask scheduler at {scheduler!r} ({e}); start one (e.g. "
            "`dask scheduler` and `dask worker ADDRESS`) or drop --scheduler to run locally."
        ) from None
    try:
        return _collect(client.map(fn, tasks, pure=False), dask_completed, tick)
    finally:
        if own:
            client.close()
