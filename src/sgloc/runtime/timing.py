"""StageTimer: seconds per named stage of one run (the `timings` of a result)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from sgloc.kernels import thread_compile_seconds


def run_clock() -> float:
    """Wall seconds (`time.perf_counter`) that do not count the time the calling thread spends
    compiling sgloc's kernels on their first use: a stage timed by it takes as long on an
    install's first run as on later ones, which load the kernels from the cache. The time
    compiling is `sgloc.kernels.compile_seconds`."""
    return time.perf_counter() - thread_compile_seconds()


class StageTimer:
    """Times the stages of one run: `with timer("ransac"): ...` adds the seconds `clock` saw
    pass to timings["ransac"]; `timings` ends with "total", the sum of the stages. The default
    clock, `run_clock`, leaves out compiling the kernels. `names` reports stages under other
    names ({"estimation": "refine"})."""

    def __init__(
        self, clock: Callable[[], float] = run_clock, names: dict[str, str] | None = None
    ) -> None:
        self.clock = clock
        self.names = names or {}
        self._stages: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        start = self.clock()
        stage = self.names.get(stage, stage)
        try:
            yield
        finally:
            self._stages[stage] = self._stages.get(stage, 0.0) + self.clock() - start

    def add(self, seconds: dict[str, float]) -> None:
        """Add stages timed elsewhere (seconds by stage name)."""
        for stage, value in seconds.items():
            stage = self.names.get(stage, stage)
            self._stages[stage] = self._stages.get(stage, 0.0) + value

    @property
    def timings(self) -> dict[str, float]:
        """Seconds per stage in the order first run, then "total"."""
        return self._stages | {"total": sum(self._stages.values())}
