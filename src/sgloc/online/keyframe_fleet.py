"""The online session's keyframe back-end (`OnlineConfig.backend = "keyframes"`): attempts
match a robot's recent local submap against another robot's map (or its own older map: a loop
closure); an accepted attempt becomes a link between two keyframes; the links the evidence
supports (`keyframe_links.select_links`) enter the keyframe pose graph (`keyframe_graph`) with
every robot's odometry; the robots' maps follow their corrected keyframes (`RobotMap.reanchor`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc import lie
from sgloc.maps.graph import SemanticGraph
from sgloc.online.config import OnlineConfig
from sgloc.online.keyframe_graph import KeyframeGraph, keyframe_link
from sgloc.online.keyframe_links import select_links
from sgloc.online.records import Link
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


def recent_start(m: RobotMap, length: float) -> int:
    """The first keyframe of `m`'s last `length` metres of travel."""
    d = m.travelled()
    return int(np.searchsorted(d, d[-1] - length, side="left"))


def make_query(maps: list[RobotMap], target: int, query: int, length: float) -> Query:
    """The attempt of `query`'s recent submap (last `length` metres) in `target`'s map."""
    q = maps[query]
    first = recent_start(q, length)
    recent = q.seen_since(first)
    tgt = q.subgraph(~recent) if target == query else maps[target].graph()
    return Query(target, query, first, q.subgraph(recent), tgt)


def link_of(maps: list[RobotMap], names: list[str], task: Query, result: dict,
            stamp: float) -> Link:
    """The keyframe link of an accepted attempt: the query robot's latest keyframe and the
    target keyframe nearest the query submap's centroid moved into the target map (for a loop
    closure, among the keyframes before the submap's stretch); T and covariance from the
    localization's T_target_query through the two keyframes' current poses in their maps."""
    qm, tm = maps[task.query], maps[task.target]
    T = np.asarray(result["transform"], np.float64)
    c = task.query_graph.positions.mean(axis=0)
    c_t = T[:3, :3] @ c + T[:3, 3]
    anchors_t = tm.anchors()
    if task.target == task.query:
        anchors_t = anchors_t[:max(task.first, 1)]
    ka = int(np.argmin(np.linalg.norm(anchors_t[:, :3, 3] - c_t, axis=1)))
    kb = qm.keyframes - 1
    T_kk, cov = keyframe_link(tm.anchors()[ka], T, result["covariance"], qm.anchors()[kb])
    return Link(names[task.target], names[task.query], T_kk, cov, float(result["confidence"]),
                float(stamp), active=False, n_matches=int(result["n_matches"]),
                keyframe_a=ka, keyframe_b=kb)


class KeyframeFleet:
    """The keyframe pose graph and its links, for an `OnlineSession`."""

    def __init__(self, online: OnlineConfig, root: int = 0) -> None:
        self.online = online
        self.graph = KeyframeGraph(online.odometry, online.solver, root)
        self.links: list[Link] = []
        self.fid: dict[int, int] = {}  # link id -> factor id while in the graph
        # (i, j) robot indices (i <= j; i == j: loop closures) -> metres each had travelled
        # at the pair's last attempt
        self.travel_last: dict[tuple[int, int], tuple[float, float]] = {}

    def due_by_travel(self, travelled: list[float], sizes: list[int], min_objects: int,
                      robot: int | None) -> list[tuple[int, int]]:
        """Pairs (i, j), i <= j (i == j: a loop closure; only with `loop_closures`), both maps
        with >= min_objects, of which a robot travelled half a submap (submap_length / 2)
        since the pair's last attempt; those never attempted first, then most travelled."""
        step = self.online.submap_length / 2
        scored = []
        for j in range(len(sizes)):
            for i in range(j + 1):
                if sizes[i] < min_objects or sizes[j] < min_objects or robot not in (None, i, j):
                    continue
                if i == j and not self.online.loop_closures:
                    continue
                prev = self.travel_last.get((i, j), (0.0, 0.0))
                moved = max(travelled[i] - prev[0], travelled[j] - prev[1])
                if moved >= step:
                    scored.append(((i, j) not in self.travel_last, moved, i, j))
        scored.sort(key=lambda x: (not x[0], -x[1], x[2], x[3]))
        return [(i, j) for _, _, i, j in scored]

    def select(self, maps: list[RobotMap], names: list[str]) -> tuple[list[int], dict]:
        """The link ids the evidence supports now, and why the others are not taken."""
        index = {n: i for i, n in enumerate(names)}
        odom = {i: m.trajectory()[1] for i, m in enumerate(maps)}
        travelled = {i: m.travelled() for i, m in enumerate(maps)}
        candidates = [i for i, lk in enumerate(self.links) if not lk.revoked]
        o = self.online
        return select_links(self.links, candidates, index, odom, travelled, o.odometry,
                            o.loop_translation, o.loop_rotation)

    def update(self, maps: list[RobotMap], names: list[str]) -> tuple[list[int], list[int]]:
        """Re-select the links, move the graph to the selection (links leave it by factor id),
        solve, reanchor the placed robots' maps. Returns (link ids that entered, link ids
        that left, now revoked)."""
        taken, dropped = self.select(maps, names)
        entered, left = [], []
        for lid in sorted(set(self.fid) - set(taken)):
            self.graph.remove(self.fid.pop(lid))
            lk = self.links[lid]
            lk.active, lk.revoked, lk.reason = False, True, dropped.get(lid, "")
            left.append(lid)
        index = {n: i for i, n in enumerate(names)}
        for lid in taken:
            if lid not in self.fid:
                lk = self.links[lid]
                self.fid[lid] = self.graph.add_link(index[lk.robot_a], lk.keyframe_a,
                                                    index[lk.robot_b], lk.keyframe_b,
                                                    lk.T_a_b, lk.covariance)
                lk.active, lk.reason = True, ""
                entered.append(lid)
        for lid, why in dropped.items():
            if not self.links[lid].revoked:
                self.links[lid].reason = why
        self.graph.solve()
        self.reanchor(maps)
        return entered, left

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
        return meta, arrays

    @classmethod
    def from_state(cls, online: OnlineConfig, meta: dict, arrays: dict) -> KeyframeFleet:
        """The back-end `state` described, its graph holding the saved solution."""
        f = cls(online)
        f.graph = KeyframeGraph.from_state(online.odometry, meta, arrays)
        f.links = [Link.from_dict(d) for d in meta["links"]]
        f.fid = {int(lid): int(fid) for lid, fid in meta["fid"]}
        f.travel_last = {(int(i), int(j)): (float(a), float(b))
                         for i, j, a, b in meta.get("travel_last", [])}
        return f
