"""Back-end "keyframes" (the default): a robust pose graph over every robot's keyframes. An
attempt matches a robot's recent submap against another robot's map (or its own older map: a
loop closure); an accepted attempt is a link between two keyframes (`state.KeyframeState`
holds the graph, the links and what each pair was last tried at)."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from sgloc.online.backend import BACKENDS, SessionState
from sgloc.online.batch import AttemptBatch
from sgloc.online.keyframes.graph import keyframe_link, write_keyframe_g2o
from sgloc.online.keyframes.state import (
    KeyframeState,
    Query,
    make_query,
    query_from,
    recent_start,
    seen_per_keyframe,
)
from sgloc.online.records import LINK_ACCEPTED, LINK_HELD, LINK_REVOKED, ROBOT_JOINED, Attempt, Link
from sgloc.online.robot_map import RobotMap


@dataclass
class KeyframePlan:
    """A batch's notes: `queries` (`state.Query`) per task, `tried` every (target, query) the
    budget took, `travelled` metres per robot at planning."""

    queries: list[Query] = field(default_factory=list)
    tried: list[tuple[int, int]] = field(default_factory=list)
    travelled: list[float] = field(default_factory=list)


@BACKENDS.register("keyframes")
class KeyframeBackend:
    """Links between keyframes in one pose graph with every robot's odometry
    (`FleetBackend`)."""

    keyframe_vertices = True

    def __init__(self, state: SessionState) -> None:
        self.s = state
        self.kf = KeyframeState(state.online)
        self.loop_last: dict[int, int] = {}  # robot -> its map's size at its last loop try

    # -- what it holds -------------------------------------------------------------------------
    @property
    def links(self) -> list[Link]:
        """Every accepted keyframe link in the order found (revoked ones included)."""
        return list(self.kf.links)

    def active_pairs(self) -> list[tuple[int, int]]:
        names = self.s.robots
        return [(names.index(lk.robot_a), names.index(lk.robot_b)) for lk in self.kf.links
                if lk.active]

    def add_keyframe(self, robot: int) -> None:
        self.kf.graph.add_keyframe(robot, self.s.map_list()[robot].poses[-1])

    def trajectory(self, robot: int) -> np.ndarray:
        return self.kf.graph.poses(robot)  # the keyframes as the pose graph corrected them

    def keyframe_ids(self) -> list[tuple[int, str, int]]:
        names, placed = self.s.robots, set(self.kf.graph.placed)
        return [(key, names[r], k) for key, r, k in self.kf.graph.nodes() if r in placed]

    # -- attempts ------------------------------------------------------------------------------
    def plan(self, batch: AttemptBatch, due, in_flight, budget, growth, robot, scheduler,
             workers) -> None:
        """The due pairs and those whose robots travelled half a submap since, loop closures
        too; each robot of a pair that travelled is a query, its recent submap in the other's
        map (`KeyframeState.directions`; a finishing robot's last stretch in every other map),
        at most `budget` in all, in `KeyframeState.ordered`'s order. Nothing is noted until
        `apply`."""
        o, maps = self.s.online, self.s.map_list()
        travelled = [m.distance for m in maps]
        more = self.kf.due_by_travel(travelled, batch.sizes, o.min_objects, robot)
        loops = self._due_loops(batch.sizes, growth, robot)
        seen = set(due)
        due = due + [p for p in more if p[0] != p[1] and p not in seen]
        loops += [i for i, j in more if i == j and i not in loops]
        due = [p for p in due if p not in in_flight]
        loops = [r for r in loops if (r, r) not in in_flight]
        group = self.s.groups(self.active_pairs())
        pairs = self.kf.ordered(  # `robot` is given only when it is finishing
            self.kf.directions([*due, *((r, r) for r in loops)], travelled, robot),
            travelled, group)
        notes = KeyframePlan(tried=pairs if budget is None else pairs[:budget],
                             travelled=travelled)
        batch.notes = notes
        batch.pairs = sorted({(min(t, q), max(t, q)) for t, q in notes.tried})
        notes.queries = self._queries(maps, notes.tried, group)
        self._tasks(batch, scheduler, workers)

    def _queries(self, maps, tried, group) -> list[Query]:
        """The query of each (target, query) tried with enough objects on both sides."""
        o, queries = self.s.online, []
        planned: Counter = Counter()  # this batch's attempts of a pair, planned so far
        for t, q in tried:
            key = (min(t, q), max(t, q))
            length, cap = self._length(group[t] == group[q], self.s.tries.get(key, 0)
                                       + planned[key])
            planned[key] += 1
            if cap is not None and _dense(maps[q], length, cap):
                length, cap = math.inf, None
            qu = make_query(maps, t, q, length, cap)
            if cap is not None and len(qu.query_graph.positions) < o.min_objects:
                # too little left after the cut: its last keyframe alone saw more
                qu = make_query(maps, t, q, math.inf)
            if min(len(qu.query_graph.positions), len(qu.target_graph.positions)) >= \
                    o.min_objects:
                queries.append(qu)
        return queries

    def _tasks(self, batch: AttemptBatch, scheduler, workers) -> None:
        """The batch's tasks from its queries, each with its pair's seed."""
        queries = batch.notes.queries
        uses = self.s.uses([qu.target for qu in queries if qu.target != qu.query],
                           workers, scheduler)
        tries: Counter = Counter()  # this batch's earlier attempts of a pair
        for qu in queries:
            key = (min(qu.target, qu.query), max(qu.target, qu.query))
            # a loop closure's target is the robot's own older map, made for this attempt
            target = qu.target_graph if qu.target == qu.query else \
                self.s.target(qu.target, uses[qu.target])
            batch.tasks.append((qu.query_graph, target, self.s.seed(*key, tries[key])))
            tries[key] += 1

    def _due_loops(self, sizes, growth, robot) -> list[int]:
        """Robots (indices) due for a loop-closure attempt under the growth rule."""
        o = self.s.online
        if not o.loop_closures:
            return []
        growth_ratio, growth_objects = growth
        out = []
        for r, n in enumerate(sizes):
            prev = self.loop_last.get(r)
            if robot not in (None, r) or n < o.min_objects:
                continue
            if prev is None or n - prev >= growth_objects or (n - prev) / max(prev, 1) \
                    >= growth_ratio:
                out.append(r)
        return out

    def _length(self, joined: bool, tries: int) -> tuple[float, int | None]:
        """(metres of the query robot's travel, at most this many objects or None) an attempt
        matches (`make_query`): a submap between robots already joined; between robots not
        yet joined the whole map (inf), as with back-end "robots" (a short submap of a
        repeating layout can fit another copy of it), and with `join_submaps` on every other
        try (`tries`: the pair's attempts before this one) the submap, cut to the objects seen
        last below the localizer's `small_query`, so that its whole geometry is verified
        against the map (`sgloc.acceptance.verification`): a sparse map fits another only
        where they overlap, and there its few objects give too few candidates for a fit. (A
        dense map, whose keyframes typically each see more, is matched whole: `_queries`.)"""
        o = self.s.online
        if joined:
            return o.submap_length, None
        if o.join_submaps and tries % 2 == 1:
            small = int(self.s.config.acceptance.evidence.small_query)
            return o.submap_length, (small - 1 if small > o.min_objects else None)
        return math.inf, None

    def refits_due(self, batch: AttemptBatch) -> bool:
        return False  # links are refitted when made

    def apply(self, batch: AttemptBatch, results: list[Attempt]) -> bool:
        """Note the batch's tries; keep the accepted attempts as keyframe links (from the maps
        as planned when they changed since). True when a link was added."""
        s, notes = self.s, batch.notes
        names, sizes, stamp, maps = s.robots, batch.sizes, batch.stamp, s.map_list()
        for t, q in notes.tried:
            self.kf.tried(t, q, notes.travelled)
            if t == q:
                self.loop_last[q] = sizes[q]
            else:
                s.last[(min(t, q), max(t, q))] = (sizes[min(t, q)], sizes[max(t, q)])
        for qu in notes.queries:
            key = (min(qu.target, qu.query), max(qu.target, qu.query))
            s.tries[key] = s.tries.get(key, 0) + 1
        group = s.groups(self.active_pairs())
        changed = False
        tests = None  # attempts between groups: counted once, when a link needs them
        for qu, r in zip(notes.queries, results, strict=True):
            r = replace(r, query=names[qu.query], target=names[qu.target], stamp=stamp,
                        sizes=(len(qu.query_graph.positions), len(qu.target_graph.positions)))
            s.attempts.append(r)
            if not r.accepted:
                continue
            # maps that changed since planning: the link from them as they stand, the
            # attempt's alignment the refit's start
            now = qu if all(maps[k].version == batch.versions[k] for k in
                            (qu.query, qu.target)) else query_from(maps, qu.target, qu.query,
                                                                   qu.first)
            lk = self.kf.link(maps, names, now, r, stamp, s.config.motion,
                              s.config.ransac.threshold, self._agreement_radii())
            ga, gb = sorted((group[qu.target], group[qu.query]))
            pair = (min(qu.target, qu.query), max(qu.target, qu.query))
            if ga != gb and tests is None:
                tests = self._tests_between(group)
            lk.tests = max(tests.get((ga, gb), 1) if ga != gb else s.tries.get(pair, 1), 1)
            self.kf.links.append(lk)
            changed = True
        return changed

    def _tests_between(self, group: np.ndarray) -> dict[tuple[int, int], int]:
        """Attempts made so far between each two groups of robots (`group`: a label per robot
        index; keys: (lower label, higher label)), loop closures left out."""
        tries = self.s.tries
        ij = np.array(list(tries), np.int64).reshape(-1, 2)
        n = np.fromiter(tries.values(), np.int64, len(tries))
        between = ij[:, 0] != ij[:, 1]
        g = np.sort(np.asarray(group)[ij[between]], axis=1)
        keys, inv = np.unique(g, axis=0, return_inverse=True)
        sums = np.bincount(inv.ravel(), weights=n[between], minlength=len(keys))
        return {(int(a), int(b)): int(c) for (a, b), c in zip(keys, sums, strict=True)}

    def add_link(self, i, j, T_i_j, covariance, confidence, stamp) -> None:
        """The link between the two robots' latest keyframes."""
        maps = self.s.map_list()
        a, b = maps[i], maps[j]
        ka, kb = a.keyframes - 1, b.keyframes - 1
        T, cov = keyframe_link(a.anchors()[ka], T_i_j, covariance, b.anchors()[kb])
        names = self.s.robots
        self.kf.links.append(Link(names[i], names[j], T, cov, float(confidence), stamp,
                                  active=False, reason="added link", keyframe_a=ka,
                                  keyframe_b=kb))

    # -- the fleet frame -----------------------------------------------------------------------
    def set_root(self, robot: int) -> None:
        self.kf.graph.set_root(robot)

    def final_refinement_due(self) -> bool:
        if not self.kf.colocation_due(self.s.map_list(), 0.0):
            return False
        self.kf.colocated_at = None
        return True

    def _max_join_nfa(self) -> float | None:
        """The NFA a link joining two groups may have, its tests counted
        (`OnlineConfig.join_tests`): the localizer's, 1 / min_confidence - 1; None: no hold."""
        acc = self.s.config.acceptance
        if not self.s.online.join_tests or not acc.enabled or acc.min_confidence <= 0.0:
            return None
        return 1.0 / acc.min_confidence - 1.0

    def _agreement_radii(self) -> tuple[float, float]:
        """(land, cover) metres of the links' overlap: the localizer's agreement radii."""
        acc = self.s.config.acceptance
        return acc.repetition_radii(acc.radius or self.s.config.ransac.threshold)

    def link_agreement(self) -> tuple[float, int]:
        """(threshold, min_covered) of the links' map-agreement hold
        (`OnlineConfig.link_agreement`; None: the localizer's `min_agreement`)."""
        acc, own = self.s.config.acceptance, self.s.online.link_agreement
        return (acc.min_agreement if own is None else own), acc.min_covered

    def refresh(self, stamp: float, emit: bool) -> None:
        """Re-select the links, update and solve the keyframe graph, reanchor the maps, emit
        what changed."""
        s, o, names = self.s, self.s.online, self.s.robots
        if s.root not in s.maps:
            s.placed = {}
            return
        root = names.index(s.root)
        if self.kf.graph.root != root:
            self.kf.graph.set_root(root)
        maps = s.map_list()
        entered, left = self.kf.update(maps, names, self._max_join_nfa(), self.link_agreement())
        held = self.kf.newly_held
        if o.refine_fleet and self.kf.colocation_due(maps, o.refine_fleet_growth):
            self.kf.colocate(maps, s.config.motion, o.refine_radius or s.config.ransac.threshold)
        g = self.kf.graph
        T_new = {names[r]: g.T_fleet_odom(r) for r in g.placed}
        self._emit_links(entered, left, held, T_new, stamp, emit)
        for r in names:
            if r in T_new and r not in s.placed:
                s.emit(emit, stamp, ROBOT_JOINED, (r,),
                       "the fleet frame's root" if r == s.root else "placed in the fleet frame")
        s.placed = T_new

    def _emit_links(self, entered, left, held, T_new, stamp, emit) -> None:
        """The events of the links that left, were held and entered the graph."""
        s, links = self.s, self.kf.links
        lost = [r for r in s.robots if r in s.placed and r not in T_new]
        for lid in left:
            lk = links[lid]
            note = f"; no longer placed: {', '.join(lost)}" if lost else ""
            s.emit(emit, stamp, LINK_REVOKED, (lk.robot_a, lk.robot_b), lk.reason + note)
        for lid in held:
            lk = links[lid]
            s.emit(emit, stamp, LINK_HELD, (lk.robot_a, lk.robot_b),
                   f"{lk.reason}; keyframes {lk.keyframe_a} and {lk.keyframe_b}, "
                   f"{lk.n_matches} matches")
        for lid in entered:
            lk = links[lid]
            s.emit(emit, stamp, LINK_ACCEPTED, (lk.robot_a, lk.robot_b),
                   f"confidence {lk.confidence:.6f}, {lk.n_matches} matches, keyframes "
                   f"{lk.keyframe_a} and {lk.keyframe_b}")

    # -- state and files -----------------------------------------------------------------------
    def state(self) -> tuple[dict, dict[str, np.ndarray]]:
        meta, arrays = self.kf.state()
        return {"keyframes": meta,
                "loop_last": sorted([r, n] for r, n in self.loop_last.items())}, arrays

    def load_state(self, meta: dict, arrays: dict[str, np.ndarray]) -> None:
        """The saved solution as it was (not re-solved)."""
        self.kf = KeyframeState.from_state(self.s.online, meta["keyframes"], arrays)
        self.loop_last = {int(r): int(n) for r, n in meta.get("loop_last", [])}
        g, names = self.kf.graph, self.s.robots
        self.s.placed = {names[r]: g.T_fleet_odom(r) for r in g.placed}

    def write_g2o(self, path: str | Path) -> Path:
        """The keyframe pose graph of the placed robots: a vertex per keyframe
        (`keyframe_ids` names them), an edge per odometry and active link factor."""
        return write_keyframe_g2o(self.kf.graph, path)[0]


def _dense(m: RobotMap, length: float, cap: int) -> bool:
    """Whether `m`'s keyframes over its last `length` metres typically (the median) each saw
    more than `cap` confirmed objects: no stretch of such a map is a small query, and a few of
    its keyframes that saw less (a gap in the view) are not a place to join on."""
    seen = seen_per_keyframe(m, recent_start(m, length))
    return bool(len(seen)) and float(np.median(seen)) > cap
