"""OnlineSession: robots' maps grow keyframe by keyframe; the session localizes robot pairs
when their maps have grown enough and keeps one fleet frame over the consistent links. It
schedules and runs the attempts, keeps the attempts and events and saves itself; its back-end
(`OnlineConfig.backend`, `sgloc.online.backend`) keeps the links and solves the fleet frame."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

# the back-ends register themselves in BACKENDS when imported
import sgloc.online.keyframes.backend  # noqa: F401
import sgloc.online.robots.backend  # noqa: F401
from sgloc.errors import SglocError
from sgloc.io.keyframe_checks import check_keyframe, check_link, check_stamp
from sgloc.maps.graph import SemanticGraph
from sgloc.online.backend import SessionState, backend_for
from sgloc.online.batch import AttemptBatch, run_batch
from sgloc.online.config import OnlineConfig
from sgloc.online.loops import invert_with_covariance
from sgloc.online.records import Attempt, Event, Link
from sgloc.online.robot_map import RobotMap
from sgloc.online.schedule import PairSizes, due_pairs
from sgloc.pipeline.config import LocalizerConfig


class OnlineSession:
    """A fleet's common frame, built while the robots explore.

    Args:
        config: the pairwise localizer's settings (LocalizerConfig; default: the library's).
        online: association, scheduling and consistency settings (OnlineConfig).
        root: the robot whose odometry frame is the fleet frame (default: the first robot to
            send a keyframe).
    """

    def __init__(
        self,
        config: LocalizerConfig | None = None,
        online: OnlineConfig | None = None,
        root: str | None = None,
    ) -> None:
        self.config = config or LocalizerConfig()
        self.online = online or OnlineConfig()
        self._state = SessionState(self.config, self.online, root)
        self._backend = backend_for(self._state)
        self._finished: set[str] = set()  # robots whose `finish` came after their last keyframe
        self._in_flight: set[tuple[int, int]] = set()  # pairs of planned, unapplied batches
        self._solve_stamp: float | None = None  # batches applied, not yet solved
        self._revision = 0  # `revision`

    # -- what the session knows ---------------------------------------------------------------
    @property
    def robots(self) -> list[str]:
        """Robot names in the order of their first keyframe."""
        return self._state.robots

    @property
    def root(self) -> str | None:
        """The robot whose odometry frame is the fleet frame (None before any keyframe)."""
        return self._state.root

    @property
    def attempts(self) -> list[Attempt]:
        """Every localization attempt so far, in the order applied."""
        return self._state.attempts

    @property
    def events(self) -> list[Event]:
        """Every event so far, in order."""
        return self._state.events

    @property
    def finished(self) -> set[str]:
        """Robots whose `finish` came after their last keyframe."""
        return set(self._finished)

    @property
    def links(self) -> list[Link]:
        """Every accepted link, active or not: with back-end "robots" one per robot pair (the
        newest); with "keyframes" every keyframe link in the order found (revoked ones
        included)."""
        return self._backend.links

    def T_fleet_robot(self, robot: str) -> np.ndarray | None:
        """(4,4) mapping `robot`'s odometry frame into the fleet frame; None while unplaced.
        With backend "keyframes": at the robot's latest solved keyframe (map -> odom: the
        latest odometry pose to the corrected one)."""
        self._state.index(robot)
        T = self._state.placed.get(robot)
        return None if T is None else T.copy()

    def map(self, robot: str) -> SemanticGraph:
        """`robot`'s confirmed objects in its odometry frame."""
        return self._state.maps[self.robots[self._state.index(robot)]].graph()

    def keyframes(self, robot: str) -> tuple[np.ndarray, np.ndarray]:
        """(stamps (k,) seconds, T_odom_sensor (k,4,4)) of `robot`'s keyframes so far."""
        return self._state.maps[self.robots[self._state.index(robot)]].trajectory()

    def trajectory(self, robot: str) -> tuple[np.ndarray, np.ndarray] | None:
        """(stamps (k,), T_fleet_sensor (k,4,4)): `robot`'s keyframe poses in the fleet frame
        as it stands now; None while the robot is unplaced."""
        if self.T_fleet_robot(robot) is None:
            return None
        k = self._state.index(robot)
        stamps = np.array(self._state.maps[robot].stamps, np.float64)
        return stamps, self._backend.trajectory(k)

    @property
    def keyframe_vertices(self) -> bool:
        """Whether links join keyframes and `write_g2o` writes a vertex per keyframe (back-end
        "keyframes") rather than one per robot ("robots")."""
        return self._backend.keyframe_vertices

    def keyframe_ids(self) -> list[tuple[int, str, int]]:
        """(vertex id in `write_g2o`'s file, robot, keyframe index) of every keyframe it writes:
        those of the placed robots (backend "keyframes"; empty with backend "robots")."""
        return self._backend.keyframe_ids()

    # -- updates -------------------------------------------------------------------------------
    def add_keyframe(
        self,
        robot: str,
        stamp: float,
        T_odom_sensor: np.ndarray,
        positions: np.ndarray,
        labels: np.ndarray,
    ) -> list[Event]:
        """Add what one keyframe of `robot` saw: positions (n,3) metres in the sensor frame,
        labels (n,) class ids, T_odom_sensor (4,4) the keyframe's pose in the robot's odometry
        frame; stamp in seconds. Runs at most `online.max_attempts` localization attempts.
        Returns the events this update caused."""
        if not isinstance(robot, str) or not robot:
            raise SglocError(f"robot must be a non-empty name, got {robot!r}.")
        # Everything is checked before anything is stored: a refused call changes nothing.
        maps = self._state.maps
        m = maps.get(robot)
        stamp, T, pos, lab = check_keyframe(
            f"robot {robot!r}", stamp, m.stamps[-1] if m is not None and m.stamps else None,
            T_odom_sensor, positions, labels, None if m is None else m.builder.labels)
        n_events = len(self.events)
        if m is None:
            o = self.online
            m = RobotMap(robot, o.association_radius, o.min_observations, o.edge_radius)
        m.add(stamp, T, pos, lab)
        maps[robot] = m
        self._finished.discard(robot)
        self._backend.add_keyframe(self.robots.index(robot))
        if robot == self.root and robot not in self._state.placed:
            self._refresh(stamp)
        if self.online.max_attempts != 0:
            self.run_pending(stamp, self.online.max_attempts)
        return self.events[n_events:]

    def run_pending(
        self,
        stamp: float | None = None,
        max_attempts: int | None = None,
        *,
        scheduler: str | None = None,
        workers: int | None = 0,
    ) -> list[Event]:
        """Attempt the due robot pairs (at most `max_attempts`; None: all), pairs that would
        join two separate groups first; on `workers` local processes or a Dask `scheduler`.
        stamp: the events' stamp (default: the newest keyframe's)."""
        o = self.online
        return self._run(stamp, max_attempts, o.growth_ratio, o.growth_objects, None,
                         scheduler, workers)

    def finish(
        self,
        robot: str,
        stamp: float | None = None,
        *,
        scheduler: str | None = None,
        workers: int | None = 0,
    ) -> list[Event]:
        """`robot` has sent its last keyframe: attempt once more every pair with it whose maps
        changed at all since the pair's last attempt, and refit its links likewise (no budget,
        no growth threshold), so that what it saw last is not left untried. More keyframes of
        the robot may still follow. stamp: the events' stamp (default: the newest keyframe's).
        Once every robot has finished, the joint refinement (`OnlineConfig.refine_fleet`; with
        back-end "keyframes" the co-location factors) runs on the final maps if they changed
        since its last run. Returns the events."""
        r = self._state.index(robot)
        n_events = len(self.events)
        self._run(stamp, None, math.inf, 1, r, scheduler, workers, robot)
        return self.events[n_events:]

    def _finish_applied(self, robot: str, stamp: float) -> None:
        """`robot`'s finishing attempts are applied: it is finished; once every robot is, the
        joint refinement (back-end "robots") or the co-location factors (back-end
        "keyframes") are made again when the maps changed since they were last made."""
        self._finished.add(robot)
        if self.online.refine_fleet and len(self._finished) == len(self._state.maps) \
                and self._backend.final_refinement_due():
            self._refresh(stamp)

    def _run(self, stamp, max_attempts, growth_ratio, growth_objects, robot, scheduler,
             workers, finishing: str | None = None) -> list[Event]:
        """Attempt the pairs due under the growth rule (growth_ratio, growth_objects), only
        those with robot index `robot` when given, then refit the links due under the same
        rule (at most `max_attempts` of each; None: all): plan, run, apply."""
        batch = self._plan(stamp, max_attempts, growth_ratio, growth_objects, robot, scheduler,
                           workers, finishing)
        return self._apply(batch, run_batch(batch, self.config, scheduler, workers))

    # -- attempts in batches: plan (here), run (anywhere), apply (here) ------------------------
    def plan_attempts(self, stamp: float | None = None, max_attempts: int | None = None,
                      finishing: str | None = None) -> AttemptBatch | None:
        """The attempts due now (at most `max_attempts`; None: all), as `run_pending` would
        run them, in a picklable batch for `run_batch` anywhere and `apply_attempts` here;
        None when there is nothing to do. With `finishing` (a robot name): the attempts
        `finish(robot)` would run, the robot marked finished when the batch is applied.
        Planning changes nothing the session saves; the batch's pairs are not planned again
        until it is applied. stamp: the events' stamp (default: the newest keyframe's)."""
        o = self.online
        if finishing is not None:
            batch = self._plan(stamp, None, math.inf, 1, self._state.index(finishing), None, 0,
                               finishing)
        else:
            batch = self._plan(stamp, max_attempts, o.growth_ratio, o.growth_objects, None,
                               None, 0)
        if not batch.tasks and not batch.pairs and finishing is None \
                and not self._backend.refits_due(batch):
            return None
        self._in_flight.update(batch.pairs)
        return batch

    def apply_attempts(self, batch: AttemptBatch, results: list[Attempt],
                       solve: bool = True) -> list[Event]:
        """Record the results of `batch` (`run_batch`'s, in its order): attempts, links, the
        fleet frame re-solved; returns the events. Call it on the session's own thread, once
        per planned batch. solve=False: the fleet frame is re-solved by the next
        `solve_pending` (one solve for several batches; a finishing batch solves at once)."""
        if len(results) != len(batch.tasks):
            raise SglocError(f"apply_attempts: {len(results)} results for a batch of "
                             f"{len(batch.tasks)} attempts; pass run_batch's results.")
        self._in_flight.difference_update(batch.pairs)
        return self._apply(batch, results, solve or batch.finishing is not None)

    @property
    def solve_due(self) -> bool:
        """Whether batches applied with solve=False wait for `solve_pending`."""
        return self._solve_stamp is not None

    def solve_pending(self) -> list[Event]:
        """Re-solve the fleet frame for the batches applied with solve=False; the events."""
        n_events, stamp = len(self.events), self._solve_stamp
        if stamp is not None:
            self._solve_stamp = None
            self._refresh(stamp)
        return self.events[n_events:]

    def release(self, batch: AttemptBatch) -> None:
        """Forget a planned batch that will not be applied (its run failed): its pairs may be
        planned again."""
        self._in_flight.difference_update(batch.pairs)

    @property
    def revision(self) -> int:
        """Increases whenever the fleet frame changes (corrections, active links, placed
        robots); equal revisions: the same corrections."""
        return self._revision

    def corrections(self) -> dict[str, np.ndarray]:
        """robot -> (4,4) T_fleet_odom (map -> odom, `T_fleet_robot`) of every placed robot,
        in the order of the robots."""
        placed = self._state.placed
        return {r: placed[r].copy() for r in self.robots if r in placed}

    def _plan(self, stamp, max_attempts, growth_ratio, growth_objects, robot, scheduler,
              workers, finishing: str | None = None) -> AttemptBatch:
        """The batch `_run` runs: the due pairs (and what else the back-end adds) not in
        flight, in budget order."""
        stamp = check_stamp("the update", stamp) if stamp is not None else self._state.now()
        maps, o = self._state.map_list(), self.online
        sizes = [m.n_confirmed for m in maps]
        due = due_pairs(sizes, self._state.last, o.min_objects, growth_ratio, growth_objects,
                        robot)
        batch = AttemptBatch(stamp, sizes=sizes, finishing=finishing,
                             versions=[m.version for m in maps])
        self._backend.plan(batch, due, self._in_flight, max_attempts,
                           (growth_ratio, growth_objects), robot, scheduler, workers)
        return batch

    def _apply(self, batch: AttemptBatch, results: list[Attempt], solve: bool = True
               ) -> list[Event]:
        """Note the batch's attempts and results (the back-end keeps the links), re-solve
        (now, or at `solve_pending` when not `solve`)."""
        n_events, stamp = len(self.events), batch.stamp
        changed = self._backend.apply(batch, results)
        if changed and not solve:
            due = self._solve_stamp
            self._solve_stamp = stamp if due is None else max(stamp, due)
        elif changed or (solve and self._solve_stamp is not None):
            self._solve_stamp = None
            self._refresh(stamp)
        if batch.finishing is not None:
            self._finish_applied(batch.finishing, stamp)
        return self.events[n_events:]

    def add_link(
        self,
        robot_a: str,
        robot_b: str,
        T_a_b: np.ndarray,
        covariance: np.ndarray,
        confidence: float = 1.0,
        stamp: float | None = None,
    ) -> list[Event]:
        """Add an inter-robot link found elsewhere (e.g. another place recognizer): T_a_b (4,4)
        maps b's odometry frame into a's, covariance (6,6) as `Link.covariance`. It replaces the
        pair's current link and goes through the same consistency check (as new evidence: a
        revoked link of the pair does not hold it back). Returns the events."""
        i, j = self._state.index(robot_a), self._state.index(robot_b)
        if i == j:
            raise SglocError(f"a link needs two different robots, got {robot_a!r} twice.")
        T, cov, confidence, stamp = check_link(f"add_link({robot_a!r}, {robot_b!r})", T_a_b,
                                               covariance, confidence, stamp)
        if i > j:
            i, j = j, i
            T, cov = invert_with_covariance(T, cov)
        n_events = len(self.events)
        stamp = stamp if stamp is not None else self._state.now()
        self._backend.add_link(i, j, T, cov, confidence, stamp)
        self._refresh(stamp)
        return self.events[n_events:]

    def set_root(self, robot: str, stamp: float | None = None) -> list[Event]:
        """Make `robot`'s odometry frame the fleet frame (re-solves; returns the events,
        stamped `stamp`, default: the newest keyframe's)."""
        k = self._state.index(robot)
        stamp = check_stamp("set_root", stamp) if stamp is not None else self._state.now()
        n_events = len(self.events)
        self._state.root_name = robot
        self._state.placed = {}
        self._backend.set_root(k)
        self._refresh(stamp)
        return self.events[n_events:]

    # -- the fleet frame -----------------------------------------------------------------------
    def _refresh(self, stamp: float, emit: bool = True) -> None:
        """Re-select the consistent links, re-solve the fleet frame, emit what changed; the
        revision moves on when the frame changed."""
        before = dict(self._state.placed), [lk.active for lk in self.links]
        self._backend.refresh(stamp, emit)
        if not self._same_frame(before):
            self._revision += 1

    def _same_frame(self, before: tuple[dict[str, np.ndarray], list[bool]]) -> bool:
        T, active = before
        now = self._state.placed
        return active == [lk.active for lk in self.links] and T.keys() == now.keys() \
            and all(np.array_equal(T[r], now[r]) for r in T)

    # -- state and files -----------------------------------------------------------------------
    def to_state(self) -> tuple[dict, dict[str, np.ndarray]]:
        """(JSON-ready dict, arrays) holding the whole session (`from_state` rebuilds it)."""
        st = self._state
        meta = {
            "config": self.config.to_dict(),
            "online": self.online.to_dict(),
            "root": st.root_name,
            "robots": self.robots,
            "last": [[i, j, *v] for (i, j), v in sorted(st.last.items())],
            "tries": [[i, j, v] for (i, j), v in sorted(st.tries.items())],
            "attempts": [a.to_dict() for a in st.attempts],
            "events": [e.to_dict() for e in st.events],
            "finished": sorted(self._finished),
        }
        arrays = {f"map{k}_{key}": arr for k, m in enumerate(st.map_list())
                  for key, arr in m.state().items()}
        more, more_arrays = self._backend.state()
        meta.update(more)
        arrays.update(more_arrays)
        return meta, arrays

    @classmethod
    def from_state(cls, meta: dict, arrays: dict[str, np.ndarray]) -> OnlineSession:
        """The session `to_state` described (the fleet frame as saved)."""
        s = cls(LocalizerConfig.from_dict(meta["config"]), OnlineConfig.from_dict(meta["online"]),
                meta["root"])
        o, st = s.online, s._state
        for k, r in enumerate(meta["robots"]):
            m = RobotMap(r, o.association_radius, o.min_observations, o.edge_radius)
            prefix = f"map{k}_"
            m.set_state({key[len(prefix):]: v for key, v in arrays.items()
                         if key.startswith(prefix)})
            st.maps[r] = m
        st.last = PairSizes({(i, j): (a, b) for i, j, a, b in meta["last"]})
        st.tries = {(i, j): v for i, j, v in meta["tries"]}
        st.attempts[:] = [Attempt.from_dict(d) for d in meta["attempts"]]
        st.events[:] = [Event.from_dict(d) for d in meta["events"]]
        s._finished = set(meta.get("finished", []))
        s._backend.load_state(meta, arrays)
        return s

    def save(self, path: str | Path) -> Path:
        """Write the whole session (maps, attempts, links, events, settings) to one .npz."""
        from sgloc.online.store import save_session

        return save_session(self, path)

    @classmethod
    def load(cls, path: str | Path) -> OnlineSession:
        """A session written by `save`, ready to take more keyframes."""
        from sgloc.online.store import load_session

        return load_session(cls, path)

    def write_g2o(self, path: str | Path) -> Path:
        """g2o file: VERTEX_SE3:QUAT per placed robot (its T_fleet_robot; id = robot index),
        EDGE_SE3:QUAT per active link with its information matrix (g2o order [t, r]). With
        backend "keyframes": the keyframe pose graph of the placed robots, a vertex per
        keyframe (`keyframe_ids` names them) and an edge per odometry and active link factor."""
        return self._backend.write_g2o(path)
