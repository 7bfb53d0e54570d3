"""Co-location factors of the keyframe back-end: the links of a meeting, taken all along it.

An accepted attempt links two keyframes, one place of a meeting; between links each robot's
odometry drifts. Once the pose graph has placed two linked robots, their maps put the objects
both saw on top of each other all along the stretch they share. Those object pairs (mutual
nearest same-class neighbours within a radius, in the fleet frame) are cut into windows of
`window` metres of the first robot's travel; in each window with enough pairs the objects are
expressed in the frames of one keyframe of each robot (the middle keyframes that saw them),
the relative pose of the two keyframes is refitted on them (`refine.refit_link`, the
localizer's motion model) and becomes a link factor with the covariance of that fit. So the
graph is held where the robots actually met, not only where an attempt happened to align
them, as an oracle's loop closures would hold it. The factors only join robots the accepted
links already join (they never place a robot) and are derived again from the current
solution when the maps have grown (`OnlineConfig.refine_fleet_growth`); they leave the graph
whenever an accepted link does (a wrong link's consequences must not outlive it)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc import lie
from sgloc.estimation import MotionModel
from sgloc.online.keyframes.graph import COLOCATION, GraphFactor
from sgloc.online.keyframes.views import view_corrected, view_offset
from sgloc.online.refine import co_located, refit_link
from sgloc.online.robot_map import RobotMap

#: Fewest object pairs a window needs to become a factor (a rigid fit on fewer is weak).
MIN_PAIRS = 6


def object_keyframes(m: RobotMap, offset: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions (n,3) in the robot's odometry frame, labels (n,), keyframe (n,)) of `m`'s
    confirmed objects; an object's keyframe is the middle one of those that saw it (the
    rounded mean index). offset: metres, the viewpoint offset the positions are corrected for
    (`keyframes.views.view_corrected`; 0: the map's own positions)."""
    b = m.builder
    k, _, o = m.sightings()
    n = len(b.counts)
    seen = np.bincount(o, minlength=n).astype(np.float64)
    mean_k = np.bincount(o, weights=k, minlength=n) / np.maximum(seen, 1.0)
    keep = (b.counts >= m.min_observations) & (seen > 0)
    pos = view_corrected(m, offset) if offset else b.positions
    return pos[keep], b.labels[keep], np.rint(mean_k[keep]).astype(np.int64)


def _in_frame(X: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Points p (n,3) given in the frame X (4,4) lives in, expressed in X's own frame."""
    return (p - X[:3, 3]) @ X[:3, :3]


@dataclass(frozen=True)
class _Objects:
    """One placed robot's confirmed objects for the pairing: odometry-frame positions, labels,
    keyframes (`object_keyframes`), and the xy box of their fleet-frame positions."""

    positions: np.ndarray
    labels: np.ndarray
    keyframes: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def of(cls, m: RobotMap, T_fleet_odom: np.ndarray, offset: float = 0.0) -> _Objects:
        p, lab, k = object_keyframes(m, offset)
        xy = (p @ T_fleet_odom[:3, :3].T + T_fleet_odom[:3, 3])[:, :2]
        lo, hi = (xy.min(axis=0), xy.max(axis=0)) if len(p) else (np.zeros(2), -np.ones(2))
        return cls(p, lab, k, lo, hi)

    def near(self, other: _Objects, radius: float) -> bool:
        """Whether the two xy boxes, grown by `radius`, overlap."""
        return bool(np.all(self.lo - radius <= other.hi) and np.all(other.lo - radius <= self.hi))


def _pair_factors(
    a: int, b: int, maps: list[RobotMap], T_fleet_odom: dict[int, np.ndarray],
    objects: dict[int, _Objects], motion: MotionModel, radius: float, window: float,
) -> list[GraphFactor]:
    """The co-location factors between placed robots a and b (indices into `maps`; their
    odometry frames in the fleet frame `T_fleet_odom`, their `objects`); see the module doc."""
    A, B = objects[a], objects[b]
    if min(len(A.labels), len(B.labels)) < MIN_PAIRS or not A.near(B, radius):
        return []
    pa, la, ka, pb, lb, kb = A.positions, A.labels, A.keyframes, B.positions, B.labels, B.keyframes
    T_ab = lie.between(T_fleet_odom[a], T_fleet_odom[b])
    i, j = co_located(pb, lb, pa, la, T_ab, radius)  # b's object i on a's object j
    if len(i) < MIN_PAIRS:
        return []
    cell = np.floor(maps[a].travelled()[ka[j]] / window).astype(np.int64)
    Xa, Xb = maps[a].anchors(), maps[b].anchors()
    out = []
    for c in np.unique(cell):
        sel = cell == c
        if np.count_nonzero(sel) < MIN_PAIRS:
            continue
        ii, jj = i[sel], j[sel]
        k_a, k_b = int(np.median(ka[jj])), int(np.median(kb[ii]))
        T0 = lie.between(Xa[k_a], T_ab @ Xb[k_b])
        r = refit_link(_in_frame(Xb[k_b], pb[ii]), lb[ii], _in_frame(Xa[k_a], pa[jj]), la[jj],
                       T0, motion, radius)
        if r is not None and r.n_pairs >= MIN_PAIRS:
            out.append(GraphFactor(COLOCATION, a, k_a, b, k_b, r.T_a_b, r.covariance))
    return out


def colocation_factors(
    maps: list[RobotMap], T_fleet_odom: dict[int, np.ndarray], motion: MotionModel,
    radius: float, window: float, view_correction: bool = False,
) -> list[GraphFactor]:
    """Every co-location factor (kind COLOCATION) between the placed robots (`T_fleet_odom`:
    robot index -> (4,4) its odometry frame in the fleet frame), pairs in index order; robots
    whose objects lie apart are skipped at once. With `view_correction` the objects are
    corrected for the viewpoint offset measured on the placed robots' maps
    (`keyframes.views`), so robots that saw the same objects from opposite sides are not
    pulled apart along the way they looked."""
    placed = sorted(T_fleet_odom)
    offset = view_offset([maps[r] for r in placed]) if view_correction else 0.0
    objects = {r: _Objects.of(maps[r], T_fleet_odom[r], offset) for r in placed}
    return [f for n, a in enumerate(placed) for b in placed[n + 1:]
            for f in _pair_factors(a, b, maps, T_fleet_odom, objects, motion, radius, window)]
