"""A batch of localization attempts planned by an `OnlineSession` (`plan_attempts`), run
anywhere (`run_batch`: this process, local processes, a Dask cluster) and applied back on the
session's own thread (`apply_attempts`). The batch holds plain data only (graphs, seeds and
what the session must note once the results are in), nothing referencing the session, so it
pickles and a server can run it off its ingest path."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from sgloc.online.attempts import run_attempts
from sgloc.online.records import Attempt
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.prepared import PreparedMap


@dataclass
class AttemptBatch:
    """The attempts one scheduling step chose, with what applying their results notes.

    tasks: (query graph, target graph or prepared map, seed) per attempt, in order.
    pairs: (i, j) robot indices, i <= j, this batch holds in flight (not planned again until
        applied); (i, i): a loop closure.
    stamp: the events' stamp (seconds). sizes: confirmed objects per robot at planning.
    versions: each robot's map version at planning (`RobotMap.version`).
    notes: what the back-end must note when the results are in (its own picklable record,
        e.g. which robot pair each task is).
    finishing: the robot name whose `finish` this batch is (None: a scheduling step).
    """

    stamp: float
    tasks: list[tuple] = field(default_factory=list)
    pairs: list[tuple[int, int]] = field(default_factory=list)
    sizes: list[int] = field(default_factory=list)
    versions: list[int] = field(default_factory=list)
    notes: Any = None
    finishing: str | None = None

    def __len__(self) -> int:
        return len(self.tasks)

    def __getstate__(self) -> dict:
        """Pickled with every prepared target as its graph (the same results; a prepared
        map is a cache of this process)."""
        state = dict(self.__dict__)
        state["tasks"] = [(q, t.graph if isinstance(t, PreparedMap) else t, s)
                          for q, t, s in self.tasks]
        return state


def run_batch(
    batch: AttemptBatch, config: LocalizerConfig, scheduler: Any = None, workers: int | None = 0
) -> list[Attempt]:
    """The attempts of `batch` localized with `config`, results in its order: in this process
    (workers 0 or 1), on `workers` local processes (None: CPU count) or on the Dask
    `scheduler` (`sgloc.online.attempts.run_attempts`). Pure: the batch is not changed."""
    return run_attempts(list(batch.tasks), config, scheduler, workers)
