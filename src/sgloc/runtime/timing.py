"""StageTimer: seconds per named stage of one run (the `timings` of a result)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager


class StageTimer:
    """Times the stages of one run: `with timer("ransac"): ...` adds the seconds `clock` saw
    pass to timings["ransac"]; `timings` ends with "total", the sum of the stages. `names`
    reports stages under other names ({"estimation": "refine"})."""

    def __init__(
        self, clock: Callable[[], float] = time.perf_counter, names: dict[str, str] | None = None
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
