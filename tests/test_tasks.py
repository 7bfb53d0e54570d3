"""sgloc.runtime.tasks.run_all, the one task runner: results in task order, progress ticks, in this
process for 0 or 1 workers, on worker processes otherwise."""

from __future__ import annotations

import os

import pytest

from sgloc.errors import SglocError
from sgloc.runtime.tasks import run_all


def _square_and_pid(x: int) -> tuple[int, int]:
    return x * x, os.getpid()


def test_in_this_process_for_zero_or_one_worker():
    for workers in (0, 1):
        ticks: list[int] = []
        out = run_all([3, 1, 2], _square_and_pid, workers=workers, progress=ticks.append)
        assert [v for v, _ in out] == [9, 1, 4]
        assert {pid for _, pid in out} == {os.getpid()} and sum(ticks) == 3


def test_worker_processes_keep_the_task_order():
    ticks: list[int] = []
    out = run_all(list(range(8)), _square_and_pid, workers=2, progress=ticks.append)
    assert [v for v, _ in out] == [i * i for i in range(8)] and sum(ticks) == 8
    assert os.getpid() not in {pid for _, pid in out}


def test_unreachable_scheduler_is_one_clear_error():
    pytest.importorskip("distributed")
    with pytest.raises(SglocError, match="cannot reach the Dask scheduler"):
        run_all([1], _square_and_pid, scheduler="tcp://127.0.0.1:1")
