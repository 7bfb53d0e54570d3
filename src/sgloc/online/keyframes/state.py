"""The online session's keyframe back-end (`OnlineConfig.backend = "keyframes"`): attempts
match a robot's recent local submap against another robot's map (or its own older map: a loop
closure); an accepted attempt becomes a link between two keyframes; the links the evidence
supports (`keyframes.links.select_links`) enter the keyframe pose graph (`keyframes.graph`) with
every robot's odometry; the robots' maps follow their corrected keyframes (`RobotMap.reanchor`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc import lie
from sgloc.errors import SglocError
from sgloc.estimation import MotionModel
from sgloc.maps.graph import SemanticGraph
from sgloc.online.config import OnlineConfig
from sgloc.online.keyframes.agreement import disagreement_reason, disagrees, overlap
from sgloc.online.keyframes.colocation import colocation_factors
from sgloc.online.keyframes.consistency import Chains, check_links
from sgloc.online.keyframes.graph import KeyframeGraph, keyframe_link
from sgloc.online.keyframes.links import select_links
from sgloc.online.keyframes.noise import fit_scale, heading_loops
from sgloc.online.keyframes.views import view_corrected, view_offset
from sgloc.online.loops import loop_error, loop_tolerance
from sgloc.online.records import Attempt, Link
from sgloc.online.refine import refit_link
from sgloc.online.robot_map import RobotMap


@dataclass(frozen=True)
class Query:
    """One attempt: robot `query`'s recent submap (its objects seen since keyframe `first`)
    localized in robot `target`'s map (for a loop closure, target == query and the map is the
    robot's objects not seen since `first`)."""

    target: int
    query: int
    first: int
    query_graph: SemanticGraph
    target_graph: SemanticGraph
    query_objects: np.ndarray | None = None  # (n,) bool over the query's association objects
    target_objects: np.ndarray | None = None  # likewise over the target's (None: all)


def recent_start(m: RobotMap, length: float, max_objects: int | None = None) -> int:
    """The first keyframe of `m`'s last `length` metres of travel; with `max_objects`, later
    when that stretch holds more confirmed objects: the first keyframe from which at most
    `max_objects` of them were seen (those seen last)."""
    d = m.travelled()
    first = int(np.searchsorted(d, d[-1] - length, side="left"))
    if max_objects is None:
        return first
    k, _, o = m.sightings()
    last = np.full(len(m.builder.counts), -1, np.int64)
    np.maximum.at(last, o, k)
    last = np.sort(last[m.builder.counts >= m.min_observations])[::-1]
    if len(last) > max_objects:
        first = max(first, int(last[max_objects]) + 1)
    return first


def seen_per_keyframe(m: RobotMap, first: int) -> np.ndarray:
    """(n,) how many confirmed objects each keyframe of `m` from `first` on saw (n: the
    keyframes from `first` to the last)."""
    k, _, o = m.sightings()
    n_objects = len(m.builder.counts)
    keep = (k >= first) & (m.builder.counts >= m.min_observations)[o]
    seen = np.unique(k[keep] * n_objects + o[keep])  # each (keyframe, object) once
    return np.bincount(seen // n_objects - first, minlength=max(m.keyframes - first, 0))


def make_query(maps: list[RobotMap], target: int, query: int, length: float,
               max_objects: int | None = None) -> Query:
    """The attempt of `query`'s recent submap (last `length` metres, at most `max_objects`
    objects: `recent_start`) in `target`'s map."""
    return query_from(maps, target, query, recent_start(maps[query], length, max_objects))


def query_from(maps: list[RobotMap], target: int, query: int, first: int) -> Query:
    """The attempt of `query`'s objects seen since keyframe `first` in `target`'s map, from
    the maps as they stand."""
    q = maps[query]
    recent = q.seen_since(first)
    tgt = q.subgraph(~recent) if target == query else maps[target].graph()
    return Query(target, query, first, q.subgraph(recent), tgt, recent,
                 ~recent if target == query else None)


def query_positions(maps: list[RobotMap], task: Query, offset: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(query submap positions, target map positions) of `task`, in the order of its graphs,
    corrected for the viewpoint offset `offset` (metres; `keyframes.views.view_corrected`)."""
    out = []
    for r, sel, g in ((task.query, task.query_objects, task.query_graph),
                      (task.target, task.target_objects, task.target_graph)):
        m = maps[r]
        keep = m.builder.counts >= m.min_observations
        if sel is not None:
            keep &= sel
        pos = view_corrected(m, offset)[keep]
        if len(pos) != len(g.positions):  # a Query made without its object masks
            raise SglocError(f"robot {m.name!r}: the attempt's objects are not the map's.")
        out.append(pos)
    return out[0], out[1]


def refit(task: Query, result: Attempt, motion: MotionModel, radius: float, tol_m: float,
          tol_deg: float, maps: list[RobotMap] | None = None
          ) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The accepted attempt's T_target_query refitted on every object pair it co-locates
    between the query submap and the target map (`refine.refit_link`), with the covariance
    of that fit: (T, covariance, pairs), or None when the refit rests on fewer pairs than the
    attempt's matches or moves the query submap by more than the loop tolerance (as a loop
    of 2) from the attempt's alignment. With `maps` (the session's robot maps), the objects
    are corrected for the viewpoint offset measured on the two robots' maps
    (`keyframes.views`)."""
    q, t = task.query_graph, task.target_graph
    T = np.asarray(result.transform, np.float64)
    pq, pt = q.positions, t.positions
    if maps is not None:
        both = [maps[task.query]] if task.query == task.target else [maps[task.query],
                                                                     maps[task.target]]
        pq, pt = query_positions(maps, task, view_offset(both))
    r = refit_link(pq, q.labels, pt, t.labels, T, motion, radius)
    if r is None or r.n_pairs < int(result.n_matches):
        return None
    dt, dr = loop_error(lie.between(T, r.T_a_b), q.positions)
    lim_m, lim_deg = loop_tolerance(tol_m, tol_deg, 2)
    return None if dt > lim_m or dr > lim_deg else (r.T_a_b, r.covariance, r.n_pairs)


def link_of(maps: list[RobotMap], names: list[str], task: Query, result: Attempt,
            stamp: float, refitted: tuple | None = None) -> Link:
    """The keyframe link of an accepted attempt, between the two keyframes nearest the place
    the attempt aligned (the query submap's centroid): the query keyframe of the submap's
    stretch nearest it, and the target keyframe nearest it moved into the target map (for a
    loop closure, among the keyframes before the submap's stretch). Both ends lie where the
    two maps overlap, so the link does not carry the query's drift along the rest of its
    submap. T and covariance from the localization's T_target_query (T: `refitted`'s when
    given, the (T, covariance, pairs) of `refit`) through the two keyframes' current poses in
    their maps. The localizer's covariance is kept: calibrated on real data, it holds the
    offset two maps share, which more pairs do not remove."""
    qm, tm = maps[task.query], maps[task.target]
    at, aq = tm.anchors(), qm.anchors()
    T, C = np.asarray(result.transform, np.float64), result.covariance
    if refitted is not None:
        T = refitted[0]
    c = task.query_graph.positions.mean(axis=0)
    c_t = T[:3, :3] @ c + T[:3, 3]
    anchors_t = at
    if task.target == task.query:
        anchors_t = anchors_t[:max(task.first, 1)]
    ka = int(np.argmin(np.linalg.norm(anchors_t[:, :3, 3] - c_t, axis=1)))
    anchors_q = aq[task.first:]
    kb = task.first + int(np.argmin(np.linalg.norm(anchors_q[:, :3, 3] - c, axis=1)))
    T_kk, cov = keyframe_link(at[ka], T, C, aq[kb])
    return Link(names[task.target], names[task.query], T_kk, cov, float(result.confidence),
                float(stamp), active=False, n_matches=int(result.n_matches),
                refined_pairs=0 if refitted is None else int(refitted[2]),
                keyframe_a=ka, keyframe_b=kb)


#: The odometry factors are re-scaled when the fitted scale moves by more than this factor
#: (each change restarts the solver).
RESCALE_STEP = 1.5


class KeyframeState:
    """The keyframe back-end's state for an `OnlineSession`: the keyframe pose graph, its links
    and what each robot pair was last tried at."""

    def __init__(self, online: OnlineConfig, root: int = 0) -> None:
        self.online = online
        self.graph = KeyframeGraph(online.odometry, online.solver, root)
        self.links: list[Link] = []
        self.fid: dict[int, int] = {}  # link id -> factor id while in the graph
        # (i, j) robot indices (i <= j; i == j: loop closures) -> metres each had travelled
        # at the pair's last attempt
        self.travel_last: dict[tuple[int, int], tuple[float, float]] = {}
        # (target, query) -> metres the query had travelled at its last attempt in that target
        self.query_last: dict[tuple[int, int], float] = {}
        self.colocated: list[int] = []  # factor ids of the co-location factors in the graph
        # (placed robots, their confirmed objects) when the co-location factors were derived
        self.colocated_at: tuple[list[int], int] | None = None
        self.held: set[int] = set()  # link ids the checks hold out (never in the graph)
        self.newly_held: list[int] = []  # those the last `update` newly held
        self.odometry_scale = 1.0  # the odometry factors' variance scale (`keyframes.noise`)

    def link(self, maps: list[RobotMap], names: list[str], task: Query, result: Attempt,
             stamp: float, motion: MotionModel, radius: float,
             radii: tuple[float, float]) -> Link:
        """The keyframe link of an accepted attempt (`link_of`), its alignment refitted on
        the co-located objects (`refit`) when `OnlineConfig.refine_links` is on, its overlap
        measured (`keyframes.agreement.overlap`); motion: the localizer's motion model, radius:
        the pairing radius, radii: the (land, cover) radii of the overlap (metres)."""
        o = self.online
        r = (refit(task, result, motion, radius, o.loop_translation, o.loop_rotation,
                   maps if o.view_correction else None) if o.refine_links else None)
        lk = link_of(maps, names, task, result, stamp, r)
        lk.landed, lk.covered = overlap(maps[task.target], maps[task.query], lk,
                                        o.submap_length, radii)
        return lk

    def due_by_travel(self, travelled: list[float], sizes: list[int], min_objects: int,
                      robot: int | None) -> list[tuple[int, int]]:
        """Pairs (i, j), i <= j (i == j: a loop closure; only with `loop_closures`), both maps
        with >= min_objects, of which a robot travelled half a submap (submap_length / 2)
        since its last try as the pair's query; those never attempted first, then most
        travelled."""
        n = len(sizes)
        moved = self._moved_matrix(travelled, 0.0)
        moved = np.maximum(moved, moved.T)
        i, j = np.triu_indices(n, 0 if self.online.loop_closures else 1)
        big = np.asarray(sizes) >= min_objects
        keep = big[i] & big[j] & (moved[i, j] >= self.online.submap_length / 2)
        if robot is not None:
            keep &= (i == robot) | (j == robot)
        i, j = i[keep], j[keep]
        tried = np.zeros((n, n), bool)
        for a, c in self.travel_last:
            tried[a, c] = True
        order = np.lexsort((j, i, -moved[i, j], tried[i, j]))
        return [(int(i[k]), int(j[k])) for k in order]

    def _moved_matrix(self, travelled: list[float], never: float) -> np.ndarray:
        """(n, n) `moved(t, q, travelled, never)` for every target t and query q."""
        trav = np.asarray(travelled, np.float64)
        last = self._last_matrix(len(travelled))
        for (t, q), v in self.query_last.items():
            last[t, q] = v
        moved = trav[None, :] - last
        if np.isfinite(never):
            return np.where(np.isnan(moved), trav[None, :] - never, moved)
        return np.where(np.isnan(moved), never, moved)

    def _last_matrix(self, n: int) -> np.ndarray:
        """(n, n): where the pair was tried, each query q's travel at the pair's last
        attempt (target t = row); NaN elsewhere."""
        last = np.full((n, n), np.nan)
        for (i, j), (ti, tj) in self.travel_last.items():
            last[i, j], last[j, i] = tj, ti
        return last

    def _since_matrix(self, travelled: list[float], never: float) -> np.ndarray:
        """(n, n) metres each query q travelled since the pair's last attempt (target t =
        row); `never` where the pair was never tried."""
        since = np.asarray(travelled, np.float64)[None, :] - self._last_matrix(len(travelled))
        return np.where(np.isnan(since), never, since)

    def directions(self, pairs: list[tuple[int, int]], travelled: list[float],
                   finishing: int | None = None) -> list[tuple[int, int]]:
        """(target, query) attempts for the due `pairs` (i, j): each robot of a pair whose
        recent submap has not been tried in the other's map since it travelled half a submap
        (or never) is a query, so that where one robot now is a place the other passed long
        ago, the meeting is tried from the side that holds it as its recent stretch; when
        neither is (the pair is due by map growth), the robot that travelled more since the
        pair's last attempt. A `finishing` robot (`OnlineSession.finish`) is a query whenever
        it travelled at all since its last try in the other's map: what it saw last is tried.
        A loop closure (i, i) is (i, i)."""
        if not pairs:
            return []
        step = self.online.submap_length / 2
        moved = self._moved_matrix(travelled, np.inf)
        since = np.asarray(travelled)[None, :] - np.nan_to_num(
            self._last_matrix(len(travelled)), nan=0.0)
        i, j = np.asarray(pairs).T
        fin = -1 if finishing is None else finishing
        fwd = (moved[i, j] >= step) | ((j == fin) & (moved[i, j] > 0))  # j the query
        back = (moved[j, i] >= step) | ((i == fin) & (moved[j, i] > 0))
        neither = ~fwd & ~back
        fwd |= neither & (since[i, j] >= since[j, i])
        back |= neither & ~(since[i, j] >= since[j, i])
        back &= i != j  # a loop closure once
        take = np.stack([fwd, back], axis=1).ravel()
        t = np.stack([i, j], axis=1).ravel()[take]
        q = np.stack([j, i], axis=1).ravel()[take]
        return [(int(a), int(b)) for a, b in zip(t, q, strict=True)]

    def ordered(self, attempts: list[tuple[int, int]], travelled: list[float],
                group: np.ndarray) -> list[tuple[int, int]]:
        """(target, query) `attempts` in the order the budget takes them: those that would
        join two separate groups (`group`: a label per robot) first, then one side of every
        pair before the other side of any (first the side whose query travelled more since
        the pair's last attempt; ties: the higher robot index as query), then the pairs never
        tried, then those whose robots travelled most since the pair's last attempt."""
        if not attempts:
            return []
        t, q = np.asarray(attempts).T
        since = self._since_matrix(travelled, np.inf)
        fwd, back = since[t, q], since[q, t]
        first = (t == q) | (fwd > back) | ((fwd == back) & (q > t))
        group = np.asarray(group)
        keys = np.lexsort((np.arange(len(t)), -np.maximum(fwd, back), ~first,
                           group[t] == group[q]))
        return [attempts[k] for k in keys]

    def moved(self, target: int, query: int, travelled: list[float],
              never: float = np.inf) -> float:
        """Metres `query` travelled since its last try in `target`'s map (since the pair's
        last attempt when it was never the query; `never` when the pair was never tried)."""
        if (target, query) in self.query_last:
            return travelled[query] - self.query_last[(target, query)]
        i, j = min(target, query), max(target, query)
        if (i, j) not in self.travel_last:
            return travelled[query] - never if np.isfinite(never) else never
        return travelled[query] - self.travel_last[(i, j)][0 if query == i else 1]

    def tried(self, target: int, query: int, travelled: list[float]) -> None:
        """Note an attempt of `query`'s recent submap in `target`'s map (travel so far)."""
        i, j = min(target, query), max(target, query)
        self.travel_last[(i, j)] = (travelled[i], travelled[j])
        self.query_last[(target, query)] = travelled[query]

    def update(self, maps: list[RobotMap], names: list[str], max_nfa: float | None = None,
               agreement: tuple[float, int] = (0.0, 1)) -> tuple[list[int], list[int]]:
        """Check and select the links (those whose maps disagree held first,
        `keyframes.agreement.disagrees` with agreement = (threshold, min_covered); then
        `keyframes.consistency.check_links` around `keyframes.links.select_links`, max_nfa
        its), move the graph to the selection (links
        leave it by factor id), solve, reanchor the placed robots' maps. Returns (link ids
        that entered, link ids that left, now revoked); `newly_held` then lists the link ids
        the checks newly hold out that were never in the graph."""
        index = {n: i for i, n in enumerate(names)}
        odom = {i: m.trajectory()[1] for i, m in enumerate(maps)}
        travelled = {i: m.travelled() for i, m in enumerate(maps)}
        o = self.online
        chains = Chains(index, odom, travelled, o.odometry)
        before = set(self.fid)
        candidates = [i for i, lk in enumerate(self.links) if not lk.revoked]
        apart = {i: disagreement_reason(self.links[i], agreement[0]) for i in candidates
                 if disagrees(self.links[i], *agreement)}
        candidates = [i for i in candidates if i not in apart]

        def select(ids: list[int]) -> tuple[list[int], dict[int, str]]:
            return select_links(self.links, ids, index, odom, travelled, o.odometry,
                                o.loop_translation, o.loop_rotation, max_nfa)

        if o.odometry_scale:
            self.rescale(chains)
        checked = check_links(self.links, candidates, chains, select,
                              lambda ids: self._move(ids, index), enabled=o.link_checks)
        checked.held.update(apart)
        taken = set(checked.taken)
        left = sorted(before - taken)
        for lid in left:
            lk = self.links[lid]
            lk.active, lk.revoked = False, True
            lk.reason = checked.held.get(lid, checked.dropped.get(lid, ""))
        entered = sorted(taken - before)
        for lid in entered:
            self.links[lid].active, self.links[lid].reason = True, ""
        for lid, why in checked.dropped.items():
            if not self.links[lid].revoked:
                self.links[lid].reason = why
        held = []
        for lid, why in sorted(checked.held.items()):
            lk = self.links[lid]
            lk.reason = why
            lk.revoked = lk.revoked or lid in checked.bent  # a bending link does not come back
            if lid not in before and lid not in self.held:
                held.append(lid)
        self.held = {lid for lid in checked.held if lid not in before}
        self.newly_held = held
        self.reanchor(maps)
        return entered, left

    def rescale(self, chains: Chains) -> None:
        """Fit the odometry's variance scale to the loops of the links in the graph
        (`keyframes.noise`) and give the graph's odometry factors the scaled model when the
        scale moved by more than RESCALE_STEP times since it was last set."""
        s = fit_scale(*heading_loops(self.links, sorted(self.fid), chains))
        if abs(np.log(s / self.odometry_scale)) > np.log(RESCALE_STEP):
            self.odometry_scale = s
            self.graph.set_noise(self.online.odometry.scaled(s))

    def _move(self, ids: list[int], index: dict[str, int]) -> KeyframeGraph:
        """The graph holding exactly the links `ids` (co-location factors dropped when a link
        leaves: they were derived from a solution it held), solved."""
        gone = sorted(set(self.fid) - set(ids))
        for lid in gone:
            self.graph.remove(self.fid.pop(lid))
        if gone:
            self.drop_colocated()
        for lid in ids:
            if lid not in self.fid:
                lk = self.links[lid]
                self.fid[lid] = self.graph.add_link(index[lk.robot_a], lk.keyframe_a,
                                                    index[lk.robot_b], lk.keyframe_b,
                                                    lk.T_a_b, lk.covariance)
        self.graph.solve()
        return self.graph

    def drop_colocated(self) -> None:
        """Remove the co-location factors from the graph (derived again when next due)."""
        for fid in self.colocated:
            self.graph.remove(fid)
        self.colocated, self.colocated_at = [], None

    def colocation_due(self, maps: list[RobotMap], growth: float) -> bool:
        """Whether the co-location factors are due: never derived, the placed robots changed,
        or their confirmed objects grew by the fraction `growth` since (and at all)."""
        if self.colocated_at is None:
            return len(self.graph.placed) >= 2
        robots, before = self.colocated_at
        total = sum(maps[r].n_confirmed for r in self.graph.placed)
        return robots != self.graph.placed or (total != before
                                                and total - before >= growth * before)

    def colocate(self, maps: list[RobotMap], motion: MotionModel, radius: float) -> None:
        """Derive the co-location factors (`keyframes.colocation`) of the placed robots again
        from the current solution, solve and reanchor. motion: the localizer's motion model;
        radius: the pairing radius (metres)."""
        g = self.graph
        placed = g.placed
        self.drop_colocated()
        T = {r: g.T_fleet_odom(r) for r in placed}
        for f in colocation_factors(maps, T, motion, radius, self.online.submap_length / 4,
                                    self.online.view_correction):
            self.colocated.append(g.add_link(f.robot_a, f.k_a, f.robot_b, f.k_b, f.T_a_b,
                                             f.covariance, f.kind))
        self.colocated_at = (placed, sum(maps[r].n_confirmed for r in placed))
        g.solve()
        self.reanchor(maps)

    def reanchor(self, maps: list[RobotMap]) -> None:
        """Each placed robot's map re-placed on its corrected keyframes, expressed in its
        odometry frame as it stands at its latest keyframe (inv(T_fleet_odom) @ X_k)."""
        for r in self.graph.placed:
            X = self.graph.poses(r)
            T = self.graph.T_fleet_odom(r)
            maps[r].reanchor(lie.between(T, np.eye(4)) @ X)

    def state(self) -> tuple[dict, dict[str, np.ndarray]]:
        """(JSON-ready dict, arrays): the graph (`KeyframeGraph.state`), links, factor ids and
        the pairs' travel at their last attempts; `from_state` restores them exactly."""
        meta, arrays = self.graph.state()
        meta["links"] = [lk.to_dict() for lk in self.links]
        meta["fid"] = sorted([lid, f] for lid, f in self.fid.items())
        meta["travel_last"] = [[i, j, a, b] for (i, j), (a, b) in sorted(self.travel_last.items())]
        meta["query_last"] = [[t, q, d] for (t, q), d in sorted(self.query_last.items())]
        meta["colocated"] = list(self.colocated)
        meta["colocated_at"] = self.colocated_at
        meta["held"] = sorted(self.held)
        meta["odometry_scale"] = self.odometry_scale
        return meta, arrays

    @classmethod
    def from_state(cls, online: OnlineConfig, meta: dict, arrays: dict) -> KeyframeState:
        """The back-end `state` described, its graph holding the saved solution."""
        f = cls(online)
        f.graph = KeyframeGraph.from_state(online.odometry, meta, arrays)
        f.links = [Link.from_dict(d) for d in meta["links"]]
        f.fid = {int(lid): int(fid) for lid, fid in meta["fid"]}
        f.travel_last = {(int(i), int(j)): (float(a), float(b))
                         for i, j, a, b in meta.get("travel_last", [])}
        f.query_last = {(int(t), int(q)): float(d) for t, q, d in meta.get("query_last", [])}
        f.colocated = [int(x) for x in meta.get("colocated", [])]
        at = meta.get("colocated_at")
        f.colocated_at = None if at is None else ([int(r) for r in at[0]], int(at[1]))
        f.held = {int(x) for x in meta.get("held", [])}
        f.odometry_scale = float(meta.get("odometry_scale", 1.0))
        f.graph.noise = online.odometry.scaled(f.odometry_scale)  # the saved factors keep theirs
        return f
