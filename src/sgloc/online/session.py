"""OnlineSession: robots' maps grow keyframe by keyframe; the session localizes robot pairs
when their maps have grown enough and keeps one fleet frame over the consistent links."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

from sgloc.errors import SglocError
from sgloc.geometry import invert
from sgloc.io.keyframe_checks import check_keyframe, check_link, check_stamp
from sgloc.maps.graph import SemanticGraph
from sgloc.online.batch import AttemptBatch, run_batch
from sgloc.online.config import OnlineConfig
from sgloc.online.joint import largest_shift, refine_fleet
from sgloc.online.keyframe_fleet import KeyframeBackend, make_query, query_from
from sgloc.online.keyframe_graph import keyframe_link
from sgloc.online.link_selection import (
    Edge,
    LoopMemo,
    invert_with_covariance,
    loop_error,
    loop_tolerance,
)
from sgloc.online.posegraph import fleet_frame
from sgloc.online.precision import chain_covariance, predicted_error
from sgloc.online.records import (
    LINK_ACCEPTED,
    LINK_HELD,
    LINK_REVOKED,
    ROBOT_JOINED,
    Attempt,
    Event,
    Link,
)
from sgloc.online.refine import refit_link
from sgloc.online.robot_map import RobotMap
from sgloc.online.schedule import PairSizes, due_pairs
from sgloc.pipeline.config import LocalizerConfig
from sgloc.runtime.tasks import runs_here


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
        self._last = PairSizes()  # pair -> the two maps' sizes at its last attempt
        self._tries: dict[tuple[int, int], int] = {}
        self._refitted = PairSizes()  # pair -> the two maps' sizes at its last refit
        self._links: dict[tuple[int, int], Link] = {}
        self._T: dict[str, np.ndarray] = {}
        self.attempts: list[Attempt] = []
        self.events: list[Event] = []
        # backend "keyframes": the keyframe pose graph, its links, each robot's last loop try
        self._kf = KeyframeBackend(self.online) if self.online.backend == "keyframes" else None
        self._loop_last: dict[int, int] = {}
        # the joint refinement's last run: (its robots, their objects) and its corrections
        self._joint_at: tuple[list[str], int] | None = None
        self._joint_fix: dict[str, np.ndarray] = {}
        # pair -> the most matches of a link of it that was revoked: the evidence a link of
        # the pair must beat to come back
        self._revoked: dict[tuple[int, int], int] = {}
        self._finished: set[str] = set()  # robots whose `finish` came after their last keyframe
        self._loop_memo = LoopMemo()  # loop verdicts of unchanged links and maps (a cache)
        self._in_flight: set[tuple[int, int]] = set()  # pairs of planned, unapplied batches
        self._solve_stamp: float | None = None  # batches applied, not yet solved
        self._revision = 0  # `revision`

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
    def finished(self) -> set[str]:
        """Robots whose `finish` came after their last keyframe."""
        return set(self._finished)

    @property
    def links(self) -> list[Link]:
        """Every accepted link (one per robot pair, the newest), active or not; with backend
        "keyframes", every accepted keyframe link in the order found (revoked ones included)."""
        if self._kf is not None:
            return list(self._kf.links)
        return [self._links[k] for k in sorted(self._links)]

    def T_fleet_robot(self, robot: str) -> np.ndarray | None:
        """(4,4) mapping `robot`'s odometry frame into the fleet frame; None while unplaced.
        With backend "keyframes": at the robot's latest solved keyframe (map -> odom: the
        latest odometry pose to the corrected one)."""
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
        if self._kf is not None:  # the keyframes as the pose graph corrected them
            return stamps, self._kf.graph.poses(self._index(robot))
        return stamps, T @ poses

    def keyframe_ids(self) -> list[tuple[int, str, int]]:
        """(vertex id in `write_g2o`'s file, robot, keyframe index) of every keyframe it writes:
        those of the placed robots (backend "keyframes"; empty with backend "robots")."""
        if self._kf is None:
            return []
        names, placed = self.robots, set(self._kf.graph.placed)
        return [(key, names[r], k) for key, r, k in self._kf.graph.nodes() if r in placed]

    def _now(self) -> float:
        """The newest keyframe stamp of any robot (0.0 before the first)."""
        return max((m.stamps[-1] for m in self._maps.values() if m.stamps), default=0.0)

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
        # Everything is checked before anything is stored: a refused call changes nothing.
        m = self._maps.get(robot)
        stamp, T, pos, lab = check_keyframe(
            f"robot {robot!r}", stamp, m.stamps[-1] if m is not None and m.stamps else None,
            T_odom_sensor, positions, labels, None if m is None else m.builder.labels)
        n_events = len(self.events)
        if m is None:
            o = self.online
            m = RobotMap(robot, o.association_radius, o.min_observations, o.edge_radius)
        m.add(stamp, T, pos, lab)
        self._maps[robot] = m
        self._finished.discard(robot)
        if self._kf is not None:
            self._kf.graph.add_keyframe(self.robots.index(robot), m.poses[-1])
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
        r = self._index(robot)
        n_events = len(self.events)
        self._run(stamp, None, math.inf, 1, r, scheduler, workers, robot)
        return self.events[n_events:]

    def _finish_applied(self, robot: str, stamp: float) -> None:
        """`robot`'s finishing attempts are applied: it is finished; once every robot is, the
        joint refinement runs when due."""
        self._finished.add(robot)
        if self.online.refine_fleet and len(self._finished) == len(self._maps) \
                and self._final_refinement_due():
            self._refresh(stamp)

    def _final_refinement_due(self) -> bool:
        """Once every robot finished: whether the maps changed since the joint refinement
        (back-end "robots") or the co-location factors (back-end "keyframes") were last made;
        then they are made due now."""
        if self._kf is not None:
            maps = [self._maps[r] for r in self.robots]
            if not self._kf.colocation_due(maps, 0.0):
                return False
            self._kf.colocated_at = None
            return True
        if not self._joint_stale():
            return False
        self._joint_at = None
        return True

    def _joint_stale(self) -> bool:
        """Whether the placed robots or their maps changed since the joint refinement's last
        run."""
        if self._joint_at is None:
            return len(self._T) >= 2
        robots, total = self._joint_at
        return sorted(self._T) != robots or total != sum(self._maps[r].n_confirmed
                                                         for r in self._T)

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
            batch = self._plan(stamp, None, math.inf, 1, self._index(finishing), None, 0,
                               finishing)
        else:
            batch = self._plan(stamp, max_attempts, o.growth_ratio, o.growth_objects, None,
                               None, 0)
        if not batch.tasks and not batch.tried and finishing is None \
                and not self._refits_due(batch):
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
        return {r: self._T[r].copy() for r in self.robots if r in self._T}

    def _plan(self, stamp, max_attempts, growth_ratio, growth_objects, robot, scheduler,
              workers, finishing: str | None = None) -> AttemptBatch:
        """The batch `_run` runs: the due pairs (and loops) not in flight, in budget order."""
        stamp = check_stamp("the update", stamp) if stamp is not None else self._now()
        sizes = [self._maps[r].n_confirmed for r in self.robots]
        o = self.online
        due = due_pairs(sizes, self._last, o.min_objects, growth_ratio, growth_objects, robot)
        batch = AttemptBatch(stamp, o.backend, sizes=sizes, finishing=finishing,
                             versions=[self._maps[r].version for r in self.robots])
        if self._kf is not None:  # also every half submap of travel; loop closures too
            travelled = [self._maps[r].distance for r in self.robots]
            more = self._kf.due_by_travel(travelled, sizes, o.min_objects, robot)
            loops = self._due_loops(sizes, growth_ratio, growth_objects, robot)
            seen = set(due)
            due += [p for p in more if p[0] != p[1] and p not in seen]
            loops += [i for i, j in more if i == j and i not in loops]
            due = [p for p in due if p not in self._in_flight]
            loops = [r for r in loops if (r, r) not in self._in_flight]
            self._kf_plan(batch, due, loops, travelled, max_attempts, scheduler, workers, robot)
            return batch
        due = [p for p in due if p not in self._in_flight]
        if due:
            group = self._groups()
            due.sort(key=lambda p: group[p[0]] == group[p[1]])  # stable: growth order within
            due = due if max_attempts is None else due[:max_attempts]
            uses = self._uses([i for i, _ in due], workers, scheduler)
            batch.tasks = [self._pair(i, j, uses[i]) for i, j in due]
        batch.pairs = batch.targets = due
        batch.refit = (max_attempts, growth_ratio, growth_objects, robot)
        return batch

    def _refits_due(self, batch: AttemptBatch) -> bool:
        """Back-end "robots": whether applying `batch` would refit a link."""
        o = self.online
        if self._kf is not None or not o.refine_links or not self._links:
            return False
        _, ratio, objects, robot = batch.refit
        due = due_pairs(batch.sizes, self._refitted, o.min_objects, ratio, objects, robot)
        return any(p in self._links for p in due)

    def _apply(self, batch: AttemptBatch, results: list[Attempt], solve: bool = True
               ) -> list[Event]:
        """Note the batch's attempts and results, refit (back-end "robots"), re-solve (now,
        or at `solve_pending` when not `solve`)."""
        n_events, stamp = len(self.events), batch.stamp
        if self._kf is not None:
            changed = self._kf_apply(batch, results)
        else:
            changed = False
            for (i, j), r in zip(batch.targets, results, strict=True):
                changed |= self._record(i, j, batch.sizes, r, stamp)
            sizes = [self._maps[r].n_confirmed for r in self.robots]
            changed |= self._refit_due(sizes, *batch.refit)
        if changed and not solve:
            due = self._solve_stamp
            self._solve_stamp = stamp if due is None else max(stamp, due)
        elif changed or (solve and self._solve_stamp is not None):
            self._solve_stamp = None
            self._refresh(stamp)
        if batch.finishing is not None:
            self._finish_applied(batch.finishing, stamp)
        return self.events[n_events:]

    def _groups(self) -> np.ndarray:
        """Per robot index, a label of its group of robots joined by active links."""
        from scipy import sparse
        from scipy.sparse.csgraph import connected_components

        n, names = len(self._maps), self.robots
        if self._kf is not None:
            pairs = [(names.index(lk.robot_a), names.index(lk.robot_b)) for lk in self._kf.links
                     if lk.active]
        else:
            pairs = [k for k, lk in self._links.items() if lk.active]
        ij = np.array(pairs, np.int64).reshape(-1, 2)
        adj = sparse.coo_array((np.ones(len(ij)), (ij[:, 0], ij[:, 1])), shape=(n, n))
        return connected_components(adj, directed=False)[1]

    def _seed(self, i: int, j: int, earlier: int = 0) -> list[int]:
        """The seed of the pair's next attempt after `earlier` more planned ones."""
        k = self._tries.get((i, j), 0) + earlier
        return [self.online.seed, i, j] if k == 0 else [self.online.seed, i, j, k]

    def _pair(self, i: int, j: int, uses: int) -> tuple:
        """Robot j (query) in robot i's map (target, `_target`), with the pair's seed: the
        result is T_i_j."""
        return self._maps[self.robots[j]].graph(), self._target(i, uses), self._seed(i, j)

    def _target(self, i: int, uses: int):
        """Robot i's map as the target of one of `uses` attempts against it in this batch: its
        prepared map (`RobotMap.prepared`, kept until the map changes) when one is kept or
        several attempts use it; the graph otherwise (and on worker processes: `uses` 0)."""
        m = self._maps[self.robots[i]]
        return m.prepared(self.config, uses) if uses else m.graph()

    @staticmethod
    def _uses(targets: list[int], workers, scheduler) -> dict[int, int]:
        """Attempts against each target robot in a batch when it runs in this process; 0 for
        every target when the batch goes to worker processes (they get arrays)."""
        if runs_here(len(targets), workers, scheduler):
            return Counter(targets)
        return dict.fromkeys(targets, 0)

    def _due_loops(self, sizes, growth_ratio, growth_objects, robot) -> list[int]:
        """Robots (indices) due for a loop-closure attempt under the growth rule."""
        if not self.online.loop_closures:
            return []
        out = []
        for r, n in enumerate(sizes):
            prev = self._loop_last.get(r)
            if robot not in (None, r) or n < self.online.min_objects:
                continue
            if prev is None or n - prev >= growth_objects or (n - prev) / max(prev, 1) \
                    >= growth_ratio:
                out.append(r)
        return out

    def _kf_plan(self, batch: AttemptBatch, due, loops, travelled, budget, scheduler, workers,
                 finishing: int | None = None) -> None:
        """Backend "keyframes": plan the due pairs' attempts into `batch` (each robot of a pair
        that travelled half a submap since its last try is a query, its recent submap in the
        other's map: `KeyframeBackend.directions`; a `finishing` robot's last stretch in every
        other map) and loop closures, at most `budget` in all, in `KeyframeBackend.ordered`'s
        order. Nothing is noted until `_kf_apply`."""
        o = self.online
        maps = [self._maps[r] for r in self.robots]
        group = self._groups()
        pairs = self._kf.ordered(
            self._kf.directions([*due, *((r, r) for r in loops)], travelled, finishing),
            travelled, group)
        batch.tried = pairs if budget is None else pairs[:budget]
        batch.travelled = travelled
        batch.pairs = sorted({(min(t, q), max(t, q)) for t, q in batch.tried})
        planned: Counter = Counter()  # this batch's attempts of a pair, planned so far
        for t, q in batch.tried:
            key = (min(t, q), max(t, q))
            length, cap = self._kf_length(group[t] == group[q], self._tries.get(key, 0)
                                          + planned[key])
            planned[key] += 1
            qu = make_query(maps, t, q, length, cap)
            if cap is not None and len(qu.query_graph.positions) < o.min_objects:
                # a dense map: its last keyframe alone sees more than a small query holds
                qu = make_query(maps, t, q, math.inf)
            if min(len(qu.query_graph.positions), len(qu.target_graph.positions)) >= \
                    o.min_objects:
                batch.queries.append(qu)
        uses = self._uses([qu.target for qu in batch.queries if qu.target != qu.query],
                          workers, scheduler)
        tries: Counter = Counter()  # this batch's earlier attempts of a pair
        for qu in batch.queries:
            key = (min(qu.target, qu.query), max(qu.target, qu.query))
            # a loop closure's target is the robot's own older map, made for this attempt
            target = qu.target_graph if qu.target == qu.query else \
                self._target(qu.target, uses[qu.target])
            batch.tasks.append((qu.query_graph, target, self._seed(*key, tries[key])))
            tries[key] += 1

    def _kf_length(self, joined: bool, tries: int) -> tuple[float, int | None]:
        """(metres of the query robot's travel, at most this many objects or None) an attempt
        matches (`make_query`): a submap between robots already joined; between robots not
        yet joined the whole map (inf), as with back-end "robots" (a short submap of a
        repeating layout can fit another copy of it), and with `join_submaps` on every other
        try (`tries`: the pair's attempts before this one) the submap, cut to the objects seen
        last below the localizer's `small_query`, so that its whole geometry is verified
        against the map (`sgloc.acceptance.verification`): a sparse map fits another only
        where they overlap, and there its few objects give too few candidates for a fit. (A
        dense map, whose last keyframe alone sees more, is matched whole: `_kf_plan`.)"""
        o = self.online
        if joined:
            return o.submap_length, None
        if o.join_submaps and tries % 2 == 1:
            small = int(self.config.acceptance.evidence.small_query)
            return o.submap_length, (small - 1 if small > o.min_objects else None)
        return math.inf, None

    def _kf_apply(self, batch: AttemptBatch, results: list[Attempt]) -> bool:
        """Backend "keyframes": note the batch's tries; keep the accepted attempts as keyframe
        links (from the maps as planned when they changed since). True when a link was
        added."""
        names, sizes, stamp = self.robots, batch.sizes, batch.stamp
        maps = [self._maps[r] for r in names]
        for t, q in batch.tried:
            self._kf.tried(t, q, batch.travelled)
            if t == q:
                self._loop_last[q] = sizes[q]
            else:
                self._last[(min(t, q), max(t, q))] = (sizes[min(t, q)], sizes[max(t, q)])
        for qu in batch.queries:
            key = (min(qu.target, qu.query), max(qu.target, qu.query))
            self._tries[key] = self._tries.get(key, 0) + 1
        group = self._groups()
        changed = False
        tests = None  # attempts between groups: counted once, when a link needs them
        for qu, r in zip(batch.queries, results, strict=True):
            r = replace(r, query=names[qu.query], target=names[qu.target], stamp=stamp,
                        sizes=(len(qu.query_graph.positions), len(qu.target_graph.positions)))
            self.attempts.append(r)
            if r.accepted:
                # maps that changed since planning: the link from them as they stand, the
                # attempt's alignment the refit's start
                now = qu if all(maps[k].version == batch.versions[k] for k in
                                (qu.query, qu.target)) else query_from(maps, qu.target,
                                                                       qu.query, qu.first)
                lk = self._kf.link(maps, names, now, r, stamp, self.config.motion,
                                   self.config.ransac.threshold, self._agreement_radii())
                ga, gb = sorted((group[qu.target], group[qu.query]))
                pair = (min(qu.target, qu.query), max(qu.target, qu.query))
                if ga != gb and tests is None:
                    tests = self._tests_between(group)
                lk.tests = max(tests.get((ga, gb), 1) if ga != gb else
                               self._tries.get(pair, 1), 1)
                self._kf.links.append(lk)
                changed = True
        return changed

    def _tests_between(self, group: np.ndarray) -> dict[tuple[int, int], int]:
        """Attempts made so far between each two groups of robots (`group`: a label per robot
        index; keys: (lower label, higher label)), loop closures left out."""
        ij = np.array(list(self._tries), np.int64).reshape(-1, 2)
        n = np.fromiter(self._tries.values(), np.int64, len(self._tries))
        between = ij[:, 0] != ij[:, 1]
        g = np.sort(np.asarray(group)[ij[between]], axis=1)
        keys, inv = np.unique(g, axis=0, return_inverse=True)
        sums = np.bincount(inv.ravel(), weights=n[between], minlength=len(keys))
        return {(int(a), int(b)): int(c) for (a, b), c in zip(keys, sums, strict=True)}

    def _max_join_nfa(self) -> float | None:
        """The NFA a link joining two groups may have, its tests counted
        (`OnlineConfig.join_tests`): the localizer's, 1 / min_confidence - 1; None: no hold."""
        acc = self.config.acceptance
        if not self.online.join_tests or not acc.enabled or acc.min_confidence <= 0.0:
            return None
        return 1.0 / acc.min_confidence - 1.0

    def _record(self, i: int, j: int, sizes: list[int], r: Attempt, stamp: float) -> bool:
        """Store one attempt (robot j in robot i's map, named here); True when it added or
        replaced a link."""
        names = self.robots
        self._last[(i, j)] = (sizes[i], sizes[j])
        self._tries[(i, j)] = self._tries.get((i, j), 0) + 1
        r = replace(r, query=names[j], target=names[i], stamp=stamp, sizes=(sizes[j], sizes[i]))
        self.attempts.append(r)
        if not r.accepted:
            return False
        self._store_link(i, j, r.transform, r.covariance, r.confidence, stamp, r.n_matches, "")
        return True

    def _store_link(self, i, j, T, cov, confidence, stamp, n_matches, reason) -> None:
        """Make (T_i_j, cov) the pair's link. If the pair had a link that agrees with it within
        the loop tolerance (a loop of 2), the new one inherits its place in the consistent set
        and counts one more agreeing attempt (`Link.agreed`); a disagreeing active link is
        revoked (the newer attempt, on larger maps, is taken), the new one then re-checked."""
        names = self.robots
        old = self._links.get((i, j))
        new = Link(names[i], names[j], np.asarray(T, np.float64), np.asarray(cov, np.float64),
                   float(confidence), float(stamp), active=False, reason=reason,
                   n_matches=int(n_matches))
        self._links[(i, j)] = new
        self._refitted.pop((i, j), None)  # the new link is refitted at the next chance
        if old is None:
            return
        dt, dr = loop_error(invert(old.T_a_b) @ new.T_a_b, self._maps[names[j]].graph().positions)
        lim_m, lim_deg = loop_tolerance(self.online.loop_translation, self.online.loop_rotation, 2)
        if dt <= lim_m and dr <= lim_deg:
            new.active, new.agreed = old.active, old.agreed + 1
        elif old.active:
            self._revoke((i, j), old)
            self._emit(True, float(stamp), LINK_REVOKED, (names[i], names[j]),
                       f"a later attempt of this pair disagrees with it by {dt:.2f} m / "
                       f"{dr:.2f} deg")

    def _revoke(self, pair: tuple[int, int], lk: Link) -> None:
        """`lk`, the link of `pair`, leaves the consistent set: the pair's links come back only
        with clearly more matches than it had (hysteresis: no flip-flopping on the same
        evidence; `_eligible`)."""
        lk.revoked = True
        self._revoked[pair] = max(self._revoked.get(pair, 0), lk.n_matches)

    def _eligible(self, pair: tuple[int, int], lk: Link) -> bool:
        """Whether `lk` (of `pair`) may enter the consistent set: it is in it, or no link of
        the pair was revoked, or it rests on new evidence: more matches than any revoked one
        had (m) by growth_objects or growth_ratio * m, whichever is more (the attempts' growth
        rule). An inactive link held back says so in its reason."""
        bar = self._revoked.get(pair)
        if lk.active or bar is None:
            return True
        o = self.online
        need = bar + max(o.growth_objects, math.ceil(o.growth_ratio * bar))
        if lk.n_matches >= need and not lk.revoked:
            return True
        lk.reason = (f"revoked; held back until an attempt of this pair has {need} matches "
                     f"(a revoked link of it had {bar})")
        return False

    def _refit_due(self, sizes: list[int], budget: int | None, growth_ratio: float,
                   growth_objects: int, robot: int | None = None) -> bool:
        """Refit the links whose maps have grown (the attempts' growth rule; never-refitted
        links first), only those of robot index `robot` when given, at most `budget` (None:
        all). True when a link changed."""
        o = self.online
        if not o.refine_links or not self._links:
            return False
        due = [p for p in due_pairs(sizes, self._refitted, o.min_objects, growth_ratio,
                                    growth_objects, robot) if p in self._links]
        changed = False
        for i, j in due if budget is None else due[:budget]:
            self._refitted[(i, j)] = (sizes[i], sizes[j])
            changed |= self._refit_link(i, j)
        return changed

    def _refit_link(self, i: int, j: int) -> bool:
        """Refit the link (i, j) on every object pair it co-locates in the current maps; keep
        the refit when it rests on at least the link's matches and agrees with the link
        within the loop tolerance (a loop of 2)."""
        names, o = self.robots, self.online
        lk = self._links[(i, j)]
        a, b = self._maps[names[i]].graph(), self._maps[names[j]].graph()
        r = refit_link(b.positions, b.labels, a.positions, a.labels, lk.T_a_b,
                       self.config.motion, self.config.ransac.threshold)
        if r is None or r.n_pairs < lk.n_matches:
            return False
        dt, dr = loop_error(invert(lk.T_a_b) @ r.T_a_b, b.positions)
        lim_m, lim_deg = loop_tolerance(o.loop_translation, o.loop_rotation, 2)
        if dt > lim_m or dr > lim_deg:
            return False
        lk.T_a_b, lk.covariance, lk.refined_pairs = r.T_a_b, r.covariance, r.n_pairs
        return True

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
        i, j = self._index(robot_a), self._index(robot_b)
        if i == j:
            raise SglocError(f"a link needs two different robots, got {robot_a!r} twice.")
        T, cov, confidence, stamp = check_link(f"add_link({robot_a!r}, {robot_b!r})", T_a_b,
                                               covariance, confidence, stamp)
        if i > j:
            i, j = j, i
            T, cov = invert_with_covariance(T, cov)
        n_events = len(self.events)
        stamp = stamp if stamp is not None else self._now()
        if self._kf is not None:  # between the two robots' latest keyframes
            a, b = self._maps[self.robots[i]], self._maps[self.robots[j]]
            ka, kb = a.keyframes - 1, b.keyframes - 1
            T, cov = keyframe_link(a.anchors()[ka], T, cov, b.anchors()[kb])
            self._kf.links.append(Link(self.robots[i], self.robots[j], T, cov,
                                       float(confidence), stamp, active=False,
                                       reason="added link", keyframe_a=ka, keyframe_b=kb))
        else:
            self._store_link(i, j, T, cov, confidence, stamp, 0, "added link")
            self._revoked.pop((i, j), None)  # an added link is new evidence by itself
        self._refresh(stamp)
        return self.events[n_events:]

    def set_root(self, robot: str, stamp: float | None = None) -> list[Event]:
        """Make `robot`'s odometry frame the fleet frame (re-solves; returns the events,
        stamped `stamp`, default: the newest keyframe's)."""
        self._index(robot)
        stamp = check_stamp("set_root", stamp) if stamp is not None else self._now()
        n_events = len(self.events)
        self._root = robot
        self._T = {}
        self._joint_at, self._joint_fix = None, {}
        if self._kf is not None:
            self._kf.graph.set_root(self._index(robot))
        self._refresh(stamp)
        return self.events[n_events:]

    # -- the fleet frame -----------------------------------------------------------------------
    def _refresh(self, stamp: float, emit: bool = True) -> None:
        """Re-select the consistent links, re-solve the fleet frame, emit what changed; the
        revision moves on when the frame changed."""
        before = self._frame_now()
        if self._kf is not None:
            self._kf_refresh(stamp, emit)
        else:
            self._robots_refresh(stamp, emit)
        if not self._same_frame(before):
            self._revision += 1

    def _frame_now(self) -> tuple[dict[str, np.ndarray], list[bool]]:
        """The fleet frame as it stands: the corrections and the links' active flags."""
        return dict(self._T), [lk.active for lk in self.links]

    def _same_frame(self, before: tuple[dict[str, np.ndarray], list[bool]]) -> bool:
        T, active = before
        return active == [lk.active for lk in self.links] and T.keys() == self._T.keys() \
            and all(np.array_equal(T[r], self._T[r]) for r in T)

    def _robots_refresh(self, stamp: float, emit: bool) -> None:
        """Backend "robots": re-select the consistent links, re-solve the robots' frames, emit
        what changed."""
        names = self.robots
        o = self.online
        for lk in self._links.values():
            if lk.agreed < o.confirmations:
                lk.reason = f"awaiting confirmation: {lk.agreed} of {o.confirmations} attempts"
        keys = sorted(k for k, lk in self._links.items()
                      if lk.agreed >= o.confirmations and self._eligible(k, lk))
        links = [self._links[k] for k in keys]
        edges = [Edge(i, j, lk.T_a_b, lk.confidence, lk.stamp)
                 for (i, j), lk in zip(keys, links, strict=True)]
        root = self.root
        if root not in self._maps:
            self._T = {}
            return
        frame = fleet_frame(
            len(names), edges, [lk.covariance for lk in links], names.index(root),
            lambda r: self._maps[names[r]].graph().positions,
            o.loop_translation, o.loop_rotation, o.solver, self._loop_memo,
        )
        active = set(frame.active)
        T_new = {names[r]: T for r, T in frame.T_fleet_robot.items()}
        for r in self._held(frame, edges, [lk.covariance for lk in links]):
            T_new.pop(r, None)
        T_new = self._joint(T_new)
        lost = [r for r in names if r in self._T and r not in T_new]
        for k, lk in enumerate(links):
            was, now = lk.active, k in active
            if was and not now:
                lk.reason = frame.dropped.get(k, "")
                self._revoke(keys[k], lk)
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

    def _agreement_radii(self) -> tuple[float, float]:
        """(land, cover) metres of the links' overlap: the localizer's agreement radii."""
        acc = self.config.acceptance
        return acc.repetition_radii(acc.radius or self.config.ransac.threshold)

    def _link_agreement(self) -> tuple[float, int]:
        """(threshold, min_covered) of the links' map-agreement hold
        (`OnlineConfig.link_agreement`; None: the localizer's `min_agreement`)."""
        acc, own = self.config.acceptance, self.online.link_agreement
        return (acc.min_agreement if own is None else own), acc.min_covered

    def _kf_refresh(self, stamp: float, emit: bool) -> None:
        """Backend "keyframes": re-select the links, update and solve the keyframe graph,
        reanchor the maps, emit what changed."""
        names = self.robots
        if self.root not in self._maps:
            self._T = {}
            return
        root = names.index(self.root)
        if self._kf.graph.root != root:
            self._kf.graph.set_root(root)
        maps = [self._maps[r] for r in names]
        entered, left = self._kf.update(maps, names, self._max_join_nfa(),
                                        self._link_agreement())
        held = self._kf.newly_held
        if self.online.refine_fleet and self._kf.colocation_due(
                maps, self.online.refine_fleet_growth):
            self._kf.colocate(maps, self.config.motion,
                              self.online.refine_radius or self.config.ransac.threshold)
        g = self._kf.graph
        T_new = {names[r]: g.T_fleet_odom(r) for r in g.placed}
        lost = [r for r in names if r in self._T and r not in T_new]
        for lid in left:
            lk = self._kf.links[lid]
            note = f"; no longer placed: {', '.join(lost)}" if lost else ""
            self._emit(emit, stamp, LINK_REVOKED, (lk.robot_a, lk.robot_b), lk.reason + note)
        for lid in held:
            lk = self._kf.links[lid]
            self._emit(emit, stamp, LINK_HELD, (lk.robot_a, lk.robot_b),
                       f"{lk.reason}; keyframes {lk.keyframe_a} and {lk.keyframe_b}, "
                       f"{lk.n_matches} matches")
        for lid in entered:
            lk = self._kf.links[lid]
            self._emit(emit, stamp, LINK_ACCEPTED, (lk.robot_a, lk.robot_b),
                       f"confidence {lk.confidence:.6f}, {lk.n_matches} matches, keyframes "
                       f"{lk.keyframe_a} and {lk.keyframe_b}")
        for r in names:
            if r in T_new and r not in self._T:
                self._emit(emit, stamp, ROBOT_JOINED, (r,),
                           "the fleet frame's root" if r == self.root else
                           "placed in the fleet frame")
        self._T = T_new

    def _held(self, frame, edges: list[Edge], covariances: list[np.ndarray]) -> list[str]:
        """Robots the frame would newly place whose predicted error at their objects is beyond
        the limits (`OnlineConfig.join_sigmas`); none when the hold is off."""
        o, names = self.online, self.robots
        if o.join_sigmas is None:
            return []
        root = names.index(self.root)
        held = []
        for r, path in frame.paths.items():
            if r == root or names[r] in self._T:
                continue
            C = chain_covariance(edges, covariances, path, root)
            m, deg = predicted_error(C, self._maps[names[r]].graph().positions, o.join_sigmas)
            if m > o.loop_translation or deg > o.loop_rotation:
                held.append(names[r])
        return held

    def _joint(self, T: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The placed robots' frames refined together on every object pair their maps
        co-locate (`OnlineConfig.refine_fleet`); T unchanged when that is off or with fewer
        than two robots. The refinement reruns when it is due (`_joint_due`); in between, each
        robot keeps the correction the last run made to its pose-graph frame (T @ correction,
        in the robot's odometry frame), and robots placed since have none."""
        o, names = self.online, self.robots
        if not o.refine_fleet or len(T) < 2:
            return T
        if not self._joint_due(T):
            return {r: M @ self._joint_fix[r] if r in self._joint_fix else M
                    for r, M in T.items()}
        frames = {names.index(r): M for r, M in T.items()}
        graphs = {k: self._maps[names[k]].graph() for k in frames}
        objects = {k: (g.positions, g.labels) for k, g in graphs.items()}
        radius = o.refine_radius or self.config.ransac.threshold
        out, _ = refine_fleet(frames, objects, names.index(self.root), radius,
                              self.config.motion.dof)
        m, deg = largest_shift(frames, out, {k: g.positions for k, g in graphs.items()})
        self._joint_at = (sorted(T), sum(self._maps[r].n_confirmed for r in T))
        if m > o.loop_translation or deg > o.loop_rotation:
            self._joint_fix = {}
            return T
        refined = {names[k]: M for k, M in out.items()}
        self._joint_fix = {r: invert(T[r]) @ M for r, M in refined.items()}
        return refined

    def _joint_due(self, T: dict[str, np.ndarray]) -> bool:
        """The joint refinement is due for the placed robots T: never run, a robot of its last
        run is no longer placed, or their confirmed objects have grown by
        `OnlineConfig.refine_fleet_growth` (a fraction) since."""
        if self._joint_at is None:
            return True
        robots, total = self._joint_at
        if any(r not in T for r in robots):
            return True
        now = sum(self._maps[r].n_confirmed for r in T)
        return now - total >= self.online.refine_fleet_growth * total

    def _emit(self, emit: bool, stamp: float, kind: str, robots: tuple, detail: str) -> None:
        if emit:
            self.events.append(Event(stamp, kind, tuple(robots), detail))

    # -- state and files -----------------------------------------------------------------------
    def to_state(self) -> tuple[dict, dict[str, np.ndarray]]:
        """(JSON-ready dict, arrays) holding the whole session (`from_state` rebuilds it)."""
        meta = {
            "config": self.config.to_dict(),
            "online": self.online.to_dict(),
            "root": self._root,
            "robots": self.robots,
            "last": [[i, j, *v] for (i, j), v in sorted(self._last.items())],
            "tries": [[i, j, v] for (i, j), v in sorted(self._tries.items())],
            "refined": [[i, j, *v] for (i, j), v in sorted(self._refitted.items())],
            "links": [[i, j, lk.to_dict()] for (i, j), lk in sorted(self._links.items())],
            "attempts": [a.to_dict() for a in self.attempts],
            "events": [e.to_dict() for e in self.events],
            "placed": [k for k, r in enumerate(self.robots) if r in self._T],
            "loop_last": sorted([r, n] for r, n in self._loop_last.items()),
            "joint_at": None if self._joint_at is None else [self._joint_at[0],
                                                             self._joint_at[1]],
            "joint_fixed": sorted(self._joint_fix),
            "revoked": [[i, j, v] for (i, j), v in sorted(self._revoked.items())],
            "finished": sorted(self._finished),
        }
        arrays = {f"map{k}_{key}": arr for k, r in enumerate(self.robots)
                  for key, arr in self._maps[r].state().items()}
        # The fleet frames as they stand, not re-solved on load: the maps may have grown since
        # the last solve, and a resumed session must give exactly the saved frames.
        arrays.update({f"frame{k}": self._T[r] for k, r in enumerate(self.robots)
                       if r in self._T})
        arrays.update({f"joint_fix{k}": self._joint_fix[r] for k, r in enumerate(self.robots)
                       if r in self._joint_fix})
        if self._kf is not None:
            meta["keyframes"], kf_arrays = self._kf.state()
            arrays.update(kf_arrays)
        return meta, arrays

    @classmethod
    def from_state(cls, meta: dict, arrays: dict[str, np.ndarray]) -> OnlineSession:
        """The session `to_state` described (its fleet frame re-solved from the links)."""
        s = cls(LocalizerConfig.from_dict(meta["config"]), OnlineConfig.from_dict(meta["online"]),
                meta["root"])
        o = s.online
        for k, r in enumerate(meta["robots"]):
            m = RobotMap(r, o.association_radius, o.min_observations, o.edge_radius)
            prefix = f"map{k}_"
            m.set_state({key[len(prefix):]: v for key, v in arrays.items()
                         if key.startswith(prefix)})
            s._maps[r] = m
        s._last = PairSizes({(i, j): (a, b) for i, j, a, b in meta["last"]})
        s._tries = {(i, j): v for i, j, v in meta["tries"]}
        s._refitted = PairSizes({(i, j): (a, b) for i, j, a, b in meta.get("refined", [])})
        s._links = {(i, j): Link.from_dict(d) for i, j, d in meta["links"]}
        s.attempts = [Attempt.from_dict(d) for d in meta["attempts"]]
        s.events = [Event.from_dict(d) for d in meta["events"]]
        s._loop_last = {int(r): int(n) for r, n in meta.get("loop_last", [])}
        s._revoked = {(int(i), int(j)): int(v) for i, j, v in meta.get("revoked", [])}
        s._finished = set(meta.get("finished", []))
        if meta.get("joint_at") is not None:
            s._joint_at = (list(meta["joint_at"][0]), int(meta["joint_at"][1]))
        s._joint_fix = {r: np.array(arrays[f"joint_fix{s.robots.index(r)}"], np.float64)
                        for r in meta.get("joint_fixed", [])}
        if s._kf is not None:  # the saved solution as it was (not re-solved)
            s._kf = KeyframeBackend.from_state(o, meta["keyframes"], arrays)
            g = s._kf.graph
            s._T = {s.robots[r]: g.T_fleet_odom(r) for r in g.placed}
        elif "placed" in meta:
            s._T = {s.robots[k]: np.array(arrays[f"frame{k}"], np.float64)
                    for k in meta["placed"]}
        elif s.robots:  # a save from before the frames were stored
            s._refresh(0.0, emit=False)
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
        from sgloc.io.g2o import write_g2o

        if self._kf is not None:
            from sgloc.online.keyframe_graph import write_keyframe_g2o

            return write_keyframe_g2o(self._kf.graph, path)[0]

        names = self.robots
        vertices = {names.index(r): T for r, T in self._T.items()}
        edges = [(names.index(lk.robot_a), names.index(lk.robot_b), lk.T_a_b, lk.covariance)
                 for lk in self.links if lk.active]
        return write_g2o(path, vertices, edges)
