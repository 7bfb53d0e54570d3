"""Back-end "robots": one rigid frame per robot, solved from the links `link_selection` keeps
(a pose graph over the robots' odometry frames, `posegraph`), then refined together on the
objects the placed robots' maps co-locate (`sgloc.online.joint`). What `localize_fleet` uses."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sgloc.geometry import invert
from sgloc.online.backend import BACKENDS, SessionState
from sgloc.online.batch import AttemptBatch
from sgloc.online.joint import largest_shift, refine_fleet
from sgloc.online.loops import loop_error, loop_tolerance
from sgloc.online.records import LINK_ACCEPTED, LINK_REVOKED, ROBOT_JOINED, Attempt, Link
from sgloc.online.refine import refit_link
from sgloc.online.robots.link_selection import Edge, LoopMemo
from sgloc.online.robots.posegraph import fleet_frame
from sgloc.online.robots.precision import chain_covariance, predicted_error
from sgloc.online.schedule import PairSizes, due_pairs


@dataclass
class RobotsPlan:
    """A batch's notes: (i, j) per task (robot j in robot i's map) and the (budget,
    growth_ratio, growth_objects, robot) of the link refits that follow its results."""

    targets: list[tuple[int, int]]
    refit: tuple


@BACKENDS.register("robots")
class RobotsBackend:
    """One link per robot pair (the newest), a rigid frame per robot (`FleetBackend`)."""

    keyframe_vertices = False

    def __init__(self, state: SessionState) -> None:
        self.s = state
        self.pair_links: dict[tuple[int, int], Link] = {}
        self.refitted = PairSizes()  # pair -> the two maps' sizes at its last refit
        # pair -> the most matches of a link of it that was revoked: the evidence a link of
        # the pair must beat to come back
        self.revoked: dict[tuple[int, int], int] = {}
        self.loop_memo = LoopMemo()  # loop verdicts of unchanged links and maps (a cache)
        # the joint refinement's last run: (its robots, their objects) and its corrections
        self.joint_at: tuple[list[str], int] | None = None
        self.joint_fix: dict[str, np.ndarray] = {}

    # -- what it holds -------------------------------------------------------------------------
    @property
    def links(self) -> list[Link]:
        """Every accepted link (one per robot pair, the newest), active or not."""
        return [self.pair_links[k] for k in sorted(self.pair_links)]

    def active_pairs(self) -> list[tuple[int, int]]:
        return [k for k, lk in self.pair_links.items() if lk.active]

    def add_keyframe(self, robot: int) -> None:
        pass  # a robot's frame is its odometry frame: nothing to add per keyframe

    def trajectory(self, robot: int) -> np.ndarray:
        name = self.s.robots[robot]
        return self.s.placed[name] @ self.s.maps[name].trajectory()[1]

    def keyframe_ids(self) -> list[tuple[int, str, int]]:
        return []  # the g2o file has a vertex per robot, not per keyframe

    # -- attempts ------------------------------------------------------------------------------
    def plan(self, batch: AttemptBatch, due, in_flight, budget, growth, robot, scheduler,
             workers) -> None:
        """The due pairs, those that would join two groups first (growth order within)."""
        due = [p for p in due if p not in in_flight]
        if due:
            group = self.s.groups(self.active_pairs())
            due.sort(key=lambda p: group[p[0]] == group[p[1]])
            due = due if budget is None else due[:budget]
            uses = self.s.uses([i for i, _ in due], workers, scheduler)
            maps = self.s.map_list()
            batch.tasks = [(maps[j].graph(), self.s.target(i, uses[i]), self.s.seed(i, j))
                           for i, j in due]
        batch.pairs = due
        batch.notes = RobotsPlan(due, (budget, *growth, robot))

    def refits_due(self, batch: AttemptBatch) -> bool:
        o = self.s.online
        if not o.refine_links or not self.pair_links:
            return False
        _, ratio, objects, robot = batch.notes.refit
        due = due_pairs(batch.sizes, self.refitted, o.min_objects, ratio, objects, robot)
        return any(p in self.pair_links for p in due)

    def apply(self, batch: AttemptBatch, results: list[Attempt]) -> bool:
        changed = False
        for (i, j), r in zip(batch.notes.targets, results, strict=True):
            changed |= self.record(i, j, batch.sizes, r, batch.stamp)
        sizes = [m.n_confirmed for m in self.s.map_list()]
        return self._refit_due(sizes, *batch.notes.refit) or changed

    def record(self, i: int, j: int, sizes: list[int], r: Attempt, stamp: float) -> bool:
        """Store one attempt (robot j in robot i's map); True when it added or replaced a
        link."""
        names = self.s.robots
        self.s.last[(i, j)] = (sizes[i], sizes[j])
        self.s.tries[(i, j)] = self.s.tries.get((i, j), 0) + 1
        r = replace(r, query=names[j], target=names[i], stamp=stamp, sizes=(sizes[j], sizes[i]))
        self.s.attempts.append(r)
        if not r.accepted:
            return False
        self._store_link(i, j, r.transform, r.covariance, r.confidence, stamp, r.n_matches, "")
        return True

    def add_link(self, i, j, T_i_j, covariance, confidence, stamp) -> None:
        self._store_link(i, j, T_i_j, covariance, confidence, stamp, 0, "added link")
        self.revoked.pop((i, j), None)  # an added link is new evidence by itself

    def _store_link(self, i, j, T, cov, confidence, stamp, n_matches, reason) -> None:
        """Make (T_i_j, cov) the pair's link. If the pair had a link that agrees with it within
        the loop tolerance (a loop of 2), the new one inherits its place in the consistent set
        and counts one more agreeing attempt (`Link.agreed`); a disagreeing active link is
        revoked (the newer attempt, on larger maps, is taken), the new one then re-checked."""
        names, o = self.s.robots, self.s.online
        old = self.pair_links.get((i, j))
        new = Link(names[i], names[j], np.asarray(T, np.float64), np.asarray(cov, np.float64),
                   float(confidence), float(stamp), active=False, reason=reason,
                   n_matches=int(n_matches))
        self.pair_links[(i, j)] = new
        self.refitted.pop((i, j), None)  # the new link is refitted at the next chance
        if old is None:
            return
        dt, dr = loop_error(invert(old.T_a_b) @ new.T_a_b, self.s.maps[names[j]].graph().positions)
        lim_m, lim_deg = loop_tolerance(o.loop_translation, o.loop_rotation, 2)
        if dt <= lim_m and dr <= lim_deg:
            new.active, new.agreed = old.active, old.agreed + 1
        elif old.active:
            self._revoke((i, j), old)
            self.s.emit(True, float(stamp), LINK_REVOKED, (names[i], names[j]),
                        f"a later attempt of this pair disagrees with it by {dt:.2f} m / "
                        f"{dr:.2f} deg")

    def _revoke(self, pair: tuple[int, int], lk: Link) -> None:
        """`lk`, the link of `pair`, leaves the consistent set: the pair's links come back only
        with clearly more matches than it had (hysteresis: no flip-flopping on the same
        evidence; `_eligible`)."""
        lk.revoked = True
        self.revoked[pair] = max(self.revoked.get(pair, 0), lk.n_matches)

    def _eligible(self, pair: tuple[int, int], lk: Link) -> bool:
        """Whether `lk` (of `pair`) may enter the consistent set: it is in it, or no link of
        the pair was revoked, or it rests on new evidence: more matches than any revoked one
        had (m) by growth_objects or growth_ratio * m, whichever is more (the attempts' growth
        rule). An inactive link held back says so in its reason."""
        bar = self.revoked.get(pair)
        if lk.active or bar is None:
            return True
        o = self.s.online
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
        o = self.s.online
        if not o.refine_links or not self.pair_links:
            return False
        due = [p for p in due_pairs(sizes, self.refitted, o.min_objects, growth_ratio,
                                    growth_objects, robot) if p in self.pair_links]
        changed = False
        for i, j in due if budget is None else due[:budget]:
            self.refitted[(i, j)] = (sizes[i], sizes[j])
            changed |= self._refit_link(i, j)
        return changed

    def _refit_link(self, i: int, j: int) -> bool:
        """Refit the link (i, j) on every object pair it co-locates in the current maps; keep
        the refit when it rests on at least the link's matches and agrees with the link
        within the loop tolerance (a loop of 2)."""
        names, o, cfg = self.s.robots, self.s.online, self.s.config
        lk = self.pair_links[(i, j)]
        a, b = self.s.maps[names[i]].graph(), self.s.maps[names[j]].graph()
        r = refit_link(b.positions, b.labels, a.positions, a.labels, lk.T_a_b, cfg.motion,
                       cfg.ransac.threshold)
        if r is None or r.n_pairs < lk.n_matches:
            return False
        dt, dr = loop_error(invert(lk.T_a_b) @ r.T_a_b, b.positions)
        lim_m, lim_deg = loop_tolerance(o.loop_translation, o.loop_rotation, 2)
        if dt > lim_m or dr > lim_deg:
            return False
        lk.T_a_b, lk.covariance, lk.refined_pairs = r.T_a_b, r.covariance, r.n_pairs
        return True

    # -- the fleet frame -----------------------------------------------------------------------
    def set_root(self, robot: int) -> None:
        self.joint_at, self.joint_fix = None, {}

    def final_refinement_due(self) -> bool:
        if not self._joint_stale():
            return False
        self.joint_at = None
        return True

    def _joint_stale(self) -> bool:
        """Whether the placed robots or their maps changed since the joint refinement's last
        run."""
        placed = self.s.placed
        if self.joint_at is None:
            return len(placed) >= 2
        robots, total = self.joint_at
        return sorted(placed) != robots or total != sum(self.s.maps[r].n_confirmed
                                                        for r in placed)

    def refresh(self, stamp: float, emit: bool) -> None:
        """Re-select the consistent links, re-solve the robots' frames, emit what changed."""
        s, o = self.s, self.s.online
        names = s.robots
        for lk in self.pair_links.values():
            if lk.agreed < o.confirmations:
                lk.reason = f"awaiting confirmation: {lk.agreed} of {o.confirmations} attempts"
        keys = sorted(k for k, lk in self.pair_links.items()
                      if lk.agreed >= o.confirmations and self._eligible(k, lk))
        links = [self.pair_links[k] for k in keys]
        edges = [Edge(i, j, lk.T_a_b, lk.confidence, lk.stamp)
                 for (i, j), lk in zip(keys, links, strict=True)]
        root = s.root
        if root not in s.maps:
            s.placed = {}
            return
        frame = fleet_frame(
            len(names), edges, [lk.covariance for lk in links], names.index(root),
            lambda r: s.maps[names[r]].graph().positions,
            o.loop_translation, o.loop_rotation, o.solver, self.loop_memo,
        )
        T_new = {names[r]: T for r, T in frame.T_fleet_robot.items()}
        for r in self._held(frame, edges, [lk.covariance for lk in links]):
            T_new.pop(r, None)
        T_new = self._joint(T_new)
        self._note_links(keys, links, set(frame.active), frame.dropped, T_new, stamp, emit)
        for r in names:
            if r in T_new and r not in s.placed:
                s.emit(emit, stamp, ROBOT_JOINED, (r,),
                       "the fleet frame's root" if r == root else "placed in the fleet frame")
        s.placed = T_new

    def _note_links(self, keys, links, active, dropped, T_new, stamp, emit) -> None:
        """Mark the links the frame took or dropped; emit the changes."""
        lost = [r for r in self.s.robots if r in self.s.placed and r not in T_new]
        for k, lk in enumerate(links):
            was, now = lk.active, k in active
            if was and not now:
                lk.reason = dropped.get(k, "")
                self._revoke(keys[k], lk)
                note = f"; no longer placed: {', '.join(lost)}" if lost else ""
                self.s.emit(emit, stamp, LINK_REVOKED, (lk.robot_a, lk.robot_b),
                            lk.reason + note)
            elif now and not was:
                lk.reason = ""
                self.s.emit(emit, stamp, LINK_ACCEPTED, (lk.robot_a, lk.robot_b),
                            f"confidence {lk.confidence:.6f}, {lk.n_matches} matches")
            elif not now:
                lk.reason = dropped.get(k, lk.reason)
            lk.active = now

    def _held(self, frame, edges: list[Edge], covariances: list[np.ndarray]) -> list[str]:
        """Robots the frame would newly place whose predicted error at their objects is beyond
        the limits (`OnlineConfig.join_sigmas`); none when the hold is off."""
        o, names = self.s.online, self.s.robots
        if o.join_sigmas is None:
            return []
        root = names.index(self.s.root)
        held = []
        for r, path in frame.paths.items():
            if r == root or names[r] in self.s.placed:
                continue
            C = chain_covariance(edges, covariances, path, root)
            m, deg = predicted_error(C, self.s.maps[names[r]].graph().positions, o.join_sigmas)
            if m > o.loop_translation or deg > o.loop_rotation:
                held.append(names[r])
        return held

    def _joint(self, T: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The placed robots' frames refined together on every object pair their maps
        co-locate (`OnlineConfig.refine_fleet`); T unchanged when that is off or with fewer
        than two robots. The refinement reruns when it is due (`_joint_due`); in between, each
        robot keeps the correction the last run made to its pose-graph frame (T @ correction,
        in the robot's odometry frame), and robots placed since have none."""
        s, o = self.s, self.s.online
        names = s.robots
        if not o.refine_fleet or len(T) < 2:
            return T
        if not self._joint_due(T):
            return {r: M @ self.joint_fix[r] if r in self.joint_fix else M
                    for r, M in T.items()}
        frames = {names.index(r): M for r, M in T.items()}
        graphs = {k: s.maps[names[k]].graph() for k in frames}
        objects = {k: (g.positions, g.labels) for k, g in graphs.items()}
        radius = o.refine_radius or s.config.ransac.threshold
        out, _ = refine_fleet(frames, objects, names.index(s.root), radius,
                              s.config.motion.dof)
        m, deg = largest_shift(frames, out, {k: g.positions for k, g in graphs.items()})
        self.joint_at = (sorted(T), sum(s.maps[r].n_confirmed for r in T))
        if m > o.loop_translation or deg > o.loop_rotation:
            self.joint_fix = {}
            return T
        refined = {names[k]: M for k, M in out.items()}
        self.joint_fix = {r: invert(T[r]) @ M for r, M in refined.items()}
        return refined

    def _joint_due(self, T: dict[str, np.ndarray]) -> bool:
        """The joint refinement is due for the placed robots T: never run, a robot of its last
        run is no longer placed, or their confirmed objects have grown by
        `OnlineConfig.refine_fleet_growth` (a fraction) since."""
        if self.joint_at is None:
            return True
        robots, total = self.joint_at
        if any(r not in T for r in robots):
            return True
        now = sum(self.s.maps[r].n_confirmed for r in T)
        return now - total >= self.s.online.refine_fleet_growth * total

    # -- state and files -----------------------------------------------------------------------
    def state(self) -> tuple[dict, dict[str, np.ndarray]]:
        names, placed = self.s.robots, self.s.placed
        meta = {
            "refined": [[i, j, *v] for (i, j), v in sorted(self.refitted.items())],
            "links": [[i, j, lk.to_dict()] for (i, j), lk in sorted(self.pair_links.items())],
            "placed": [k for k, r in enumerate(names) if r in placed],
            "joint_at": None if self.joint_at is None else [self.joint_at[0],
                                                            self.joint_at[1]],
            "joint_fixed": sorted(self.joint_fix),
            "revoked": [[i, j, v] for (i, j), v in sorted(self.revoked.items())],
        }
        # The frames as they stand, not re-solved on load: the maps may have grown since the
        # last solve, and a resumed session must give exactly the saved frames.
        arrays = {f"frame{k}": placed[r] for k, r in enumerate(names) if r in placed}
        arrays.update({f"joint_fix{k}": self.joint_fix[r] for k, r in enumerate(names)
                       if r in self.joint_fix})
        return meta, arrays

    def load_state(self, meta: dict, arrays: dict[str, np.ndarray]) -> None:
        names = self.s.robots
        self.refitted = PairSizes({(i, j): (a, b) for i, j, a, b in meta.get("refined", [])})
        self.pair_links = {(i, j): Link.from_dict(d) for i, j, d in meta["links"]}
        self.revoked = {(int(i), int(j)): int(v) for i, j, v in meta.get("revoked", [])}
        if meta.get("joint_at") is not None:
            self.joint_at = (list(meta["joint_at"][0]), int(meta["joint_at"][1]))
        self.joint_fix = {r: np.array(arrays[f"joint_fix{names.index(r)}"], np.float64)
                          for r in meta.get("joint_fixed", [])}
        if "placed" in meta:
            self.s.placed = {names[k]: np.array(arrays[f"frame{k}"], np.float64)
                             for k in meta["placed"]}
        elif names:  # a save from before the frames were stored
            self.refresh(0.0, emit=False)

    def write_g2o(self, path: str | Path) -> Path:
        """VERTEX_SE3:QUAT per placed robot (its T_fleet_robot; id = robot index),
        EDGE_SE3:QUAT per active link with its information matrix (g2o order [t, r])."""
        from sgloc.io.g2o import write_g2o

        names = self.s.robots
        vertices = {names.index(r): T for r, T in self.s.placed.items()}
        edges = [(names.index(lk.robot_a), names.index(lk.robot_b), lk.T_a_b, lk.covariance)
                 for lk in self.links if lk.active]
        return write_g2o(path, vertices, edges)
