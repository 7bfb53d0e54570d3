"""OnlineSession: robots' maps grow keyframe by keyframe; the session localizes robot pairs
when their maps have grown enough and keeps one fleet frame over the consistent links."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sgloc.config import LocalizerConfig
from sgloc.errors import SglocError
from sgloc.geometry import invert
from sgloc.graph import SemanticGraph
from sgloc.online.attempts import run_tasks
from sgloc.online.config import OnlineConfig
from sgloc.online.consistency import (
    Edge,
    invert_with_covariance,
    loop_error,
    loop_tolerance,
)
from sgloc.online.posegraph import fleet_frame
from sgloc.online.records import (
    LINK_ACCEPTED,
    LINK_REVOKED,
    ROBOT_JOINED,
    Attempt,
    Event,
    Link,
)
from sgloc.online.robot_map import RobotMap
from sgloc.online.schedule import due_pairs


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
        self._root = root
        self._maps: dict[str, RobotMap] = {}
        self._last: dict[tuple[int, int], tuple[int, int]] = {}
        self._tries: dict[tuple[int, int], int] = {}
        self._links: dict[tuple[int, int], Link] = {}
        self._T: dict[str, np.ndarray] = {}
        self.attempts: list[Attempt] = []
        self.events: list[Event] = []

    # -- what the session knows ---------------------------------------------------------------
    @property
    def robots(self) -> list[str]:
        """Robot names in the order of their first keyframe."""
        return list(self._maps)

    @property
    def root(self) -> str | None:
        """The robot whose odometry frame is the fleet frame (None before any keyframe)."""
        if self._root is not None:
            return self._root
        return next(iter(self._maps), None)

    @property
    def links(self) -> list[Link]:
        """Every accepted link (one per robot pair, the newest), active or not."""
        return [self._links[k] for k in sorted(self._links)]

    def T_fleet_robot(self, robot: str) -> np.ndarray | None:
        """(4,4) mapping `robot`'s odometry frame into the fleet frame; None while unplaced."""
        self._index(robot)
        T = self._T.get(robot)
        return None if T is None else T.copy()

    def map(self, robot: str) -> SemanticGraph:
        """`robot`'s confirmed objects in its odometry frame."""
        return self._maps[self.robots[self._index(robot)]].graph()

    def keyframes(self, robot: str) -> tuple[np.ndarray, np.ndarray]:
        """(stamps (k,) seconds, T_odom_sensor (k,4,4)) of `robot`'s keyframes so far."""
        return self._maps[self.robots[self._index(robot)]].trajectory()

    def trajectory(self, robot: str) -> tuple[np.ndarray, np.ndarray] | None:
        """(stamps (k,), T_fleet_sensor (k,4,4)): `robot`'s keyframe poses in the fleet frame
        as it stands now; None while the robot is unplaced."""
        T = self.T_fleet_robot(robot)
        if T is None:
            return None
        stamps, poses = self.keyframes(robot)
        return stamps, T @ poses

    def _index(self, robot: str) -> int:
        try:
            return self.robots.index(robot)
        except ValueError:
            raise SglocError(
                f"unknown robot {robot!r}; robots so far: {', '.join(self.robots) or 'none'}."
            ) from None

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
        if not math.isfinite(float(stamp)):
            raise SglocError(f"robot {robot!r}: the keyframe stamp must be finite, got {stamp}.")
        stamp = float(stamp)
        n_events = len(self.events)
        if robot not in self._maps:
            o = self.online
            self._maps[robot] = RobotMap(robot, o.association_radius, o.min_observations,
                                         o.edge_radius)
        self._maps[robot].add(stamp, T_odom_sensor, positions, labels)
        if robot == self.root and robot not in self._T:
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
        stamp: the events' stamp (default: the newest attempt's or 0.0)."""
        stamp = float(stamp) if stamp is not None else 0.0
        n_events = len(self.events)
        names = self.robots
        sizes = [self._maps[r].n_confirmed for r in names]
        o = self.online
        due = due_pairs(sizes, self._last, o.min_objects, o.growth_ratio, o.growth_objects)
        group = self._groups()
        due.sort(key=lambda p: group[p[0]] == group[p[1]])  # stable: growth order within
        due = due if max_attempts is None else due[:max_attempts]
        if not due:
            return []
        tasks = [self._task(i, j) for i, j in due]
        results = run_tasks(tasks, scheduler, workers)
        changed = False
        for (i, j), r in zip(due, results, strict=True):
            changed |= self._record(i, j, sizes, r, stamp)
        if changed:
            self._refresh(stamp)
        return self.events[n_events:]

    def _groups(self) -> list[int]:
        """Per robot index, a label of its group of robots joined by active links."""
        parent = list(range(len(self._maps)))

        def find(x: int) -> int:
            while parent[x] != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x

        for (i, j), lk in self._links.items():
            if lk.active:
                parent[find(i)] = find(j)
        return [find(x) for x in range(len(parent))]

    def _task(self, i: int, j: int) -> tuple:
        """Robot j (query) in robot i's map (target): the result is T_i_j."""
        names = self.robots
        q, t = self._maps[names[j]].graph(), self._maps[names[i]].graph()
        k = self._tries.get((i, j), 0)
        seed = [self.online.seed, i, j] if k == 0 else [self.online.seed, i, j, k]
        return ((i, j), q.positions, q.labels, q.edge_radius, t.positions, t.labels,
                t.edge_radius, self.config.to_dict(), seed)

    def _record(self, i: int, j: int, sizes: list[int], r: dict, stamp: float) -> bool:
        """Store one attempt; True when it added or replaced a link."""
        names = self.robots
        self._last[(i, j)] = (sizes[i], sizes[j])
        self._tries[(i, j)] = self._tries.get((i, j), 0) + 1
        self.attempts.append(Attempt(
            names[j], names[i], stamp, r["accepted"], r["transform"], r["confidence"],
            r["n_matches"], r["reason"], r["seconds"], (sizes[j], sizes[i]),
        ))
        if not r["accepted"]:
            return False
        self._store_link(i, j, r["transform"], r["covariance"], r["confidence"], stamp,
                         r["n_matches"], r.get("cov_source", ""))
        return True

    def _store_link(self, i, j, T, cov, confidence, stamp, n_matches, reason) -> None:
        """Make (T_i_j, cov) the pair's link. It stays in the consistent set if the pair's
        link was there and agrees with it within the loop tolerance; a disagreeing active link
        is revoked (the newer attempt, on larger maps, is taken), the new one then re-checked."""
        names = self.robots
        old = self._links.get((i, j))
        new = Link(names[i], names[j], np.asarray(T, np.float64), np.asarray(cov, np.float64),
                   float(confidence), float(stamp), active=False, reason=reason,
                   n_matches=int(n_matches))
        self._links[(i, j)] = new
        if old is None or not old.active:
            return
        dt, dr = loop_error(invert(old.T_a_b) @ new.T_a_b, self._maps[names[j]].graph().positions)
        lim_m, lim_deg = loop_tolerance(self.online.loop_translation, self.online.loop_rotation, 2)
        if dt <= lim_m and dr <= lim_deg:
            new.active = True  # an update of an active link
            return
        self._emit(True, float(stamp), LINK_REVOKED, (names[i], names[j]),
                   f"a later attempt of this pair disagrees with it by {dt:.2f} m / {dr:.2f} deg")

    def add_link(
        self,
        robot_a: str,
        robot_b: str,
        T_a_b: np.ndarray,
        covariance: np.ndarray,
        confidence: float = 1.0,
        stamp: float = 0.0,
    ) -> list[Event]:
        """Add an inter-robot link found elsewhere (e.g. another place recognizer): T_a_b (4,4)
        maps b's odometry frame into a's, covariance (6,6) as `Link.covariance`. It replaces the
        pair's current link and goes through the same consistency check. Returns the events."""
        i, j = self._index(robot_a), self._index(robot_b)
        if i == j:
            raise SglocError(f"a link needs two different robots, got {robot_a!r} twice.")
        T = np.asarray(T_a_b, np.float64)
        cov = np.asarray(covariance, np.float64)
        if T.shape != (4, 4) or cov.shape != (6, 6) or not (np.isfinite(T).all()
                                                           and np.isfinite(cov).all()):
            raise SglocError("add_link: T_a_b must be a finite (4,4) and covariance a finite "
                             f"(6,6) array, got {T.shape} and {cov.shape}.")
        if i > j:
            i, j = j, i
            T, cov = invert_with_covariance(T, cov)
        n_events = len(self.events)
        self._store_link(i, j, T, cov, confidence, stamp, 0, "added link")
        self._refresh(float(stamp))
        return self.events[n_events:]

    def set_root(self, robot: str, stamp: float = 0.0) -> list[Event]:
        """Make `robot`'s odometry frame the fleet frame (re-solves; returns the events)."""
        self._index(robot)
        n_events = len(self.events)
        self._root = robot
        self._T = {}
        self._refresh(stamp)
        return self.events[n_events:]

    # -- the fleet frame -----------------------------------------------------------------------
    def _refresh(self, stamp: float, emit: bool = True) -> None:
        """Re-select the consistent links, re-solve the fleet frame, emit what changed."""
        names = self.robots
        keys = sorted(self._links)
        links = [self._links[k] for k in keys]
        edges = [Edge(i, j, lk.T_a_b, lk.confidence, lk.stamp)
                 for (i, j), lk in zip(keys, links, strict=True)]
        root = self.root
        if root not in self._maps:
            self._T = {}
            return
        o = self.online
        frame = fleet_frame(
            len(names), edges, [lk.covariance for lk in links], names.index(root),
            lambda r: self._maps[names[r]].graph().positions,
            o.loop_translation, o.loop_rotation, o.solver,
        )
        active = set(frame.active)
        T_new = {names[r]: T for r, T in frame.T_fleet_robot.items()}
        lost = [r for r in names if r in self._T and r not in T_new]
        for k, lk in enumerate(links):
            was, now = lk.active, k in active
            if was and not now:
                lk.reason = frame.dropped.get(k, "")
                note = f"; no longer placed: {', '.join(lost)}" if lost else ""
                self._emit(emit, stamp, LINK_REVOKED, (lk.robot_a, lk.robot_b), lk.reason + note)
            elif now and not was:
                lk.reason = ""
                self._emit(emit, stamp, LINK_ACCEPTED, (lk.robot_a, lk.robot_b),
                           f"confidence {lk.confidence:.6f}, {lk.n_matches} matches")
            elif not now:
                lk.reason = frame.dropped.get(k, lk.reason)
            lk.active = now
        for r in names:
            if r in T_new and r not in self._T:
                self._emit(emit, stamp, ROBOT_JOINED, (r,),
                           "the fleet frame's root" if r == root else "placed in the fleet frame")
        self._T = T_new

    def _emit(self, emit: bool, stamp: float, kind: str, robots: tuple, detail: str) -> None:
        if emit:
            self.events.append(Event(stamp, kind, tuple(robots), detail))

    # -- files ---------------------------------------------------------------------------------
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
        EDGE_SE3:QUAT per active link with its information matrix (g2o order [t, r])."""
        from sgloc.io.g2o import write_g2o

        names = self.robots
        vertices = {names.index(r): T for r, T in self._T.items()}
        edges = [(names.index(lk.robot_a), names.index(lk.robot_b), lk.T_a_b, lk.covariance)
                 for lk in self.links if lk.active]
        return write_g2o(path, vertices, edges)
