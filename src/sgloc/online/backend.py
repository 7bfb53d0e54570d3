"""The fleet back-end interface. An `OnlineSession` keeps the robots' maps, schedules and runs
the localization attempts, keeps the attempts and events and saves itself; its back-end keeps
the links the attempts give and solves the fleet frame from them. The two share a
`SessionState`; a back-end is a class registered in `BACKENDS` under the name
`OnlineConfig.backend` takes, built with the state (`backend_for`).

    @BACKENDS.register("mine")
    class MyBackend:  # implements FleetBackend
        def __init__(self, state: SessionState) -> None: ...
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from sgloc.errors import SglocError
from sgloc.online.batch import AttemptBatch
from sgloc.online.records import Attempt, Event, Link
from sgloc.online.robot_map import RobotMap
from sgloc.online.schedule import PairSizes
from sgloc.pipeline.config import LocalizerConfig
from sgloc.registry import Registry
from sgloc.runtime.tasks import runs_here


class SessionState:
    """What a session and its back-end share: the settings, the robots' maps (in the order of
    their first keyframe), each pair's map sizes and attempt count at its last attempt, the
    attempts and events so far, and where each placed robot is (`placed`: robot ->
    T_fleet_odom, (4,4); the back-end sets it when it solves)."""

    def __init__(self, config: LocalizerConfig, online: Any, root: str | None) -> None:
        # online: the session's OnlineConfig (which names its back-end in BACKENDS)
        self.config, self.online = config, online
        self.root_name = root  # the root as given (None: the first robot)
        self.maps: dict[str, RobotMap] = {}
        self.last = PairSizes()  # pair -> the two maps' sizes at its last attempt
        self.tries: dict[tuple[int, int], int] = {}  # pair -> attempts so far
        self.attempts: list[Attempt] = []
        self.events: list[Event] = []
        self.placed: dict[str, np.ndarray] = {}

    @property
    def robots(self) -> list[str]:
        """Robot names in the order of their first keyframe."""
        return list(self.maps)

    @property
    def root(self) -> str | None:
        """The robot whose odometry frame is the fleet frame (None before any keyframe)."""
        return self.root_name if self.root_name is not None else next(iter(self.maps), None)

    def map_list(self) -> list[RobotMap]:
        """The robots' maps by robot index."""
        return list(self.maps.values())

    def now(self) -> float:
        """The newest keyframe stamp of any robot (0.0 before the first)."""
        return max((m.stamps[-1] for m in self.maps.values() if m.stamps), default=0.0)

    def index(self, robot: str) -> int:
        """`robot`'s index; SglocError naming the robots when it is unknown."""
        try:
            return self.robots.index(robot)
        except ValueError:
            raise SglocError(
                f"unknown robot {robot!r}; robots so far: {', '.join(self.robots) or 'none'}."
            ) from None

    def emit(self, emit: bool, stamp: float, kind: str, robots: tuple, detail: str) -> None:
        """Record an event (when `emit`)."""
        if emit:
            self.events.append(Event(stamp, kind, tuple(robots), detail))

    def seed(self, i: int, j: int, earlier: int = 0) -> list[int]:
        """The seed of the pair's next attempt after `earlier` more planned ones."""
        k = self.tries.get((i, j), 0) + earlier
        return [self.online.seed, i, j] if k == 0 else [self.online.seed, i, j, k]

    def target(self, i: int, uses: int):
        """Robot i's map as the target of one of `uses` attempts against it in a batch: its
        prepared map (`RobotMap.prepared`, kept until the map changes) when one is kept or
        several attempts use it; the graph otherwise (and on worker processes: `uses` 0)."""
        m = self.map_list()[i]
        return m.prepared(self.config, uses) if uses else m.graph()

    @staticmethod
    def uses(targets: list[int], workers, scheduler) -> dict[int, int]:
        """Attempts against each target robot in a batch when it runs in this process; 0 for
        every target when the batch goes to worker processes (they get arrays)."""
        if runs_here(len(targets), workers, scheduler):
            return Counter(targets)
        return dict.fromkeys(targets, 0)

    def groups(self, pairs: Iterable[tuple[int, int]]) -> np.ndarray:
        """Per robot index, a label of its group of robots joined by `pairs` (robot indices)."""
        from scipy import sparse
        from scipy.sparse.csgraph import connected_components

        n = len(self.maps)
        ij = np.array(list(pairs), np.int64).reshape(-1, 2)
        adj = sparse.coo_array((np.ones(len(ij)), (ij[:, 0], ij[:, 1])), shape=(n, n))
        return connected_components(adj, directed=False)[1]


class FleetBackend(Protocol):
    """What a session asks of its back-end. Robots are indices into `SessionState.robots`;
    stamps are seconds; transforms (4,4) `T_<to>_<from>`; covariances (6,6) as `Link`'s.
    `keyframe_vertices`: whether links join keyframes (`Link.keyframe_a` / `keyframe_b`) and
    `write_g2o` writes a vertex per keyframe (`keyframe_ids`) rather than one per robot."""

    keyframe_vertices: bool

    @property
    def links(self) -> list[Link]:
        """Every accepted link, active or not, in a stable order."""

    def active_pairs(self) -> list[tuple[int, int]]:
        """(i, j) robot indices of every active link."""

    def add_keyframe(self, robot: int) -> None:
        """`robot`'s map took a keyframe (its newest pose is `maps[robot].poses[-1]`)."""

    def plan(self, batch: AttemptBatch, due: list[tuple[int, int]], in_flight: set,
             budget: int | None, growth: tuple[float, int], robot: int | None, scheduler: Any,
             workers: int | None) -> None:
        """Fill `batch` (tasks, pairs, notes) with the attempts due now: `due` the pairs whose
        maps grew by `growth` (ratio, objects) since their last attempt, none of `in_flight`,
        at most `budget` (None: all), only those with `robot` when given."""

    def refits_due(self, batch: AttemptBatch) -> bool:
        """Whether applying `batch` would change a link even with no attempt in it."""

    def apply(self, batch: AttemptBatch, results: list[Attempt]) -> bool:
        """Note the batch's attempts (`SessionState.attempts`, `last`, `tries`) and keep the
        accepted ones as links; True when the links changed."""

    def refresh(self, stamp: float, emit: bool) -> None:
        """Select the consistent links, solve, set `SessionState.placed`, emit what changed."""

    def final_refinement_due(self) -> bool:
        """Once every robot finished: whether a last refinement on the final maps is due (it
        then runs at the next `refresh`)."""

    def trajectory(self, robot: int) -> np.ndarray:
        """(k,4,4) T_fleet_sensor of a placed robot's keyframes."""

    def keyframe_ids(self) -> list[tuple[int, str, int]]:
        """(vertex id in `write_g2o`'s file, robot, keyframe index) of every keyframe vertex."""

    def add_link(self, i: int, j: int, T_i_j: np.ndarray, covariance: np.ndarray,
                 confidence: float, stamp: float) -> None:
        """Keep a link found elsewhere between robots i < j's odometry frames."""

    def set_root(self, robot: int) -> None:
        """The root robot changed (the placements are cleared; a `refresh` follows)."""

    def state(self) -> tuple[dict, dict[str, np.ndarray]]:
        """(JSON-ready dict, arrays) holding the back-end (`load_state` reads them back)."""

    def load_state(self, meta: dict, arrays: dict[str, np.ndarray]) -> None:
        """Take the state `state` gave (the solution as it was, not re-solved)."""

    def write_g2o(self, path: str | Path) -> Path:
        """The pose graph as a g2o file."""


BACKENDS = Registry[type]("back-end")


def backend_for(state: SessionState) -> FleetBackend:
    """The back-end `state.online.backend` names, built on `state`."""
    return BACKENDS.lookup(state.online.backend)(state)
