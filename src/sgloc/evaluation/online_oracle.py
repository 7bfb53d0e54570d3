"""Ground truth for replays: when each robot could join at the earliest (an oracle that knows
every robot's true pose), and how far each placed robot is off at the end.

Oracle: each robot's sightings, put in the ground-truth frame, are merged into objects
(same class, chained within `merge_radius` m; an object exists from its first sighting). Robot
r shares an object with robot o at stamp t when both have seen a same-class object within
`radius` m of each other by t. The pair (r, o) overlaps from the stamp at which r shares
`min_shared` objects with o; the root is placed at its first keyframe, and a robot can be
placed once it overlaps a robot that can already be placed (earliest such stamp).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sgloc.geometry import apply, invert, rotation_angle_deg
from sgloc.io.keyframes import RobotLog


def world_objects(
    log: RobotLog, T_gt_odom: np.ndarray, merge_radius: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions (k,3) ground-truth frame, labels (k,), first stamp ns (k,)) of the robot's
    sightings merged into objects (same class, connected within `merge_radius` m)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    T = T_gt_odom @ log.poses[log.keyframe]
    p = np.einsum("nij,nj->ni", T[:, :3, :3], log.positions) + T[:, :3, 3]
    n = len(p)
    if n == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    pairs = cKDTree(p).query_pairs(merge_radius, output_type="ndarray")
    pairs = pairs[log.labels[pairs[:, 0]] == log.labels[pairs[:, 1]]]
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    k, comp = connected_components(adj, directed=False)
    counts = np.bincount(comp, minlength=k)[:, None]
    pos = np.zeros((k, 3))
    np.add.at(pos, comp, p)
    first = np.full(k, np.iinfo(np.int64).max)
    np.minimum.at(first, comp, log.stamps_ns[log.keyframe])
    lab = np.zeros(k, np.int64)
    lab[comp] = log.labels
    return pos / counts, lab, first


def pair_overlap_stamp(a: tuple, b: tuple, radius: float, min_shared: int) -> float:
    """The stamp (ns, as float; inf if never) from which robot a's objects share `min_shared`
    same-class objects within `radius` m with robot b's (both seen by then)."""
    from scipy.spatial import cKDTree

    (pa, la, fa), (pb, lb, fb) = a, b
    if len(pa) == 0 or len(pb) == 0:
        return np.inf
    m = cKDTree(pa).sparse_distance_matrix(cKDTree(pb), radius, output_type="ndarray")
    m = m[la[m["i"]] == lb[m["j"]]]
    if len(m) == 0:
        return np.inf
    when = np.maximum(fa[m["i"]], fb[m["j"]]).astype(np.float64)
    earliest = np.full(len(pa), np.inf)
    np.minimum.at(earliest, m["i"], when)
    earliest = np.sort(earliest[np.isfinite(earliest)])
    return float(earliest[min_shared - 1]) if len(earliest) >= min_shared else np.inf


def oracle_join_stamps(
    logs: Sequence[RobotLog],
    T_gt_odom: dict[str, np.ndarray],
    root: str,
    radius: float = 3.0,
    min_shared: int = 15,
) -> dict[str, float]:
    """{robot: earliest stamp (seconds; inf = never) at which it could be placed}."""
    objs = {g.name: world_objects(g, T_gt_odom[g.name]) for g in logs}
    names = [g.name for g in logs]
    over = {(r, o): pair_overlap_stamp(objs[r], objs[o], radius, min_shared)
            for r in names for o in names if r != o}
    first = {g.name: float(g.stamps_ns[0]) for g in logs}
    join = {r: (first[r] if r == root else np.inf) for r in names}
    for _ in names:  # Bellman-Ford: at most N rounds
        for r in names:
            for o in names:
                if o != r:
                    join[r] = min(join[r], max(over[(r, o)], join[o]))
    return {r: join[r] * 1e-9 for r in names}


def robot_error(
    T_fleet_robot: np.ndarray,
    T_gt_fleet: np.ndarray,
    T_gt_odom: np.ndarray,
    objects: np.ndarray,
) -> tuple[float, float]:
    """(metres at the centroid of the robot's objects (odometry frame), degrees) by which a
    robot's fleet frame is off, given the fleet frame's ground truth T_gt_fleet."""
    E = invert(T_gt_odom) @ T_gt_fleet @ T_fleet_robot
    c = objects.mean(axis=0) if len(objects) else np.zeros(3)
    return float(np.linalg.norm(apply(E, c[None])[0] - c)), rotation_angle_deg(E[:3, :3])


def oracle_refit(
    pos_b: np.ndarray, lab_b: np.ndarray, pos_a: np.ndarray, lab_a: np.ndarray,
    T_gt_a_b: np.ndarray, radius: float, motion,
) -> np.ndarray | None:
    """T_a_b fitted on the TRUE correspondences: the objects of robot b (pos_b (n,3), b's
    odometry frame) and of robot a that are mutual nearest same-class neighbours within
    `radius` metres once b's are moved by the ground truth T_gt_a_b, refitted by the motion
    model's robust fit. None with fewer than 3 such pairs. What the two maps themselves say
    about the link: its error against the ground truth is the part of a link's error that
    no estimator could remove (poses' own errors, object centres seen from other sides)."""
    from sgloc.errors import SglocError
    from sgloc.estimation import irls_refine
    from sgloc.online.refine import co_located

    i, j = co_located(pos_b, lab_b, pos_a, lab_a, T_gt_a_b, radius)
    if len(i) < 3:
        return None
    try:
        return irls_refine(pos_b[i], pos_a[j], T_gt_a_b, None, 15, motion.dof, motion.max_tilt)
    except SglocError:  # degenerate geometry (collinear pairs)
        return None


def link_of_odometry_frames(session, lk) -> tuple[np.ndarray, np.ndarray]:
    """(T_a_b, covariance) of the session's link `lk` between its robots' odometry frames: as
    it is for the back-end "robots"; a keyframe link through its two keyframes' odometry
    poses (`keyframes.graph.odometry_link`)."""
    from sgloc.online.keyframes.graph import odometry_link

    if lk.keyframe_a is None:
        return lk.T_a_b, lk.covariance
    return odometry_link(session.keyframes(lk.robot_a)[1][lk.keyframe_a], lk.T_a_b,
                         lk.covariance, session.keyframes(lk.robot_b)[1][lk.keyframe_b])


def oracle_link_frames(session, T_gt_odom: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """{robot: T_fleet_robot} of the session's fleet frame re-solved with every active link's
    transform replaced by its `oracle_refit` (same links, covariances, root and solver; a link
    without 3 true pairs is left out): the best the same links could give. Keyframe links
    (back-end "keyframes") enter as links of the two odometry frames, loop closures not: one
    rigid frame per robot."""
    from sgloc.online.robots.link_selection import Edge
    from sgloc.online.robots.posegraph import fleet_frame

    names, o, cfg = session.robots, session.online, session.config
    edges, covs = [], []
    for lk in session.links:
        if not lk.active or lk.robot_a == lk.robot_b:
            continue
        _, cov = link_of_odometry_frames(session, lk)
        a, b = session.map(lk.robot_a), session.map(lk.robot_b)
        T_gt = invert(T_gt_odom[lk.robot_a]) @ T_gt_odom[lk.robot_b]
        T = oracle_refit(b.positions, b.labels, a.positions, a.labels, T_gt,
                         cfg.ransac.threshold, cfg.motion)
        if T is not None:
            edges.append(Edge(names.index(lk.robot_a), names.index(lk.robot_b), T,
                              lk.confidence, lk.stamp))
            covs.append(cov)
    frame = fleet_frame(len(names), edges, covs, names.index(session.root),
                        lambda r: session.map(names[r]).positions, o.loop_translation,
                        o.loop_rotation, o.solver)
    return {names[r]: T for r, T in frame.T_fleet_robot.items()}
