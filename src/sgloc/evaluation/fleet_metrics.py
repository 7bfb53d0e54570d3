"""What a fleet's keyframe poses are worth against the ground truth: the encounter error, the
fleet RMSE, and the oracle (what drifting odometry with perfect loop closures allows).

*Encounter error*: for every pair of keyframes of two different robots that the truth puts
within `radius` (20 m) of each other, the error of their relative position in the fleet frame,
|(t_b - t_a) - R (g_b - g_a)| with t the estimated and g the true positions and R the rotation
from the ground-truth frame into the fleet frame: what two robots at one place disagree about.
*Fleet RMSE*: the positions of every placed robot's keyframes against the truth after ONE rigid
alignment of the whole fleet. *Oracle*: a pose graph over every robot's keyframes with the same
(drifting) odometry and perfect loop closures wherever the truth puts two keyframes within
10 m (different robots, or one robot back where it was), solved with gtsam.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

#: Encounter radius (metres) and the oracle's loop-closure radius (metres).
ENCOUNTER_RADIUS, CLOSURE_RADIUS = 20.0, 10.0


def fleet_keyframe_poses(session: Any, robot: str) -> np.ndarray | None:
    """(k,4,4) T_fleet_sensor of `robot`'s keyframes as the session places them now (None while
    unplaced): `OnlineSession.trajectory`, the keyframe back-end's corrected poses or the
    robot's fleet frame applied to its odometry."""
    traj = session.trajectory(robot)
    return None if traj is None else traj[1]


def keyframe_pairs(positions: Sequence[np.ndarray], radius: float) -> tuple[np.ndarray, ...]:
    """(robot a, keyframe i, robot b, keyframe j) index arrays of every pair of keyframes of two
    different robots (a < b) whose `positions` (one (k,3) array per robot) are within `radius`."""
    from scipy.spatial import cKDTree

    robot = np.concatenate([np.full(len(p), r) for r, p in enumerate(positions)]).astype(np.int64)
    index = np.concatenate([np.arange(len(p)) for p in positions]).astype(np.int64)
    stacked = np.concatenate([np.reshape(p, (-1, 3)) for p in positions])
    pairs = cKDTree(stacked).query_pairs(radius, output_type="ndarray")
    u, v = pairs[:, 0], pairs[:, 1]
    keep = robot[u] != robot[v]
    u, v = u[keep], v[keep]
    swap = robot[u] > robot[v]
    u[swap], v[swap] = v[swap], u[swap].copy()
    order = np.lexsort((index[v], robot[v], index[u], robot[u]))
    u, v = u[order], v[order]
    return robot[u], index[u], robot[v], index[v]


def relative_errors(
    est_a: np.ndarray, gt_a: np.ndarray, est_b: np.ndarray, gt_b: np.ndarray, R_est_gt: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(metres, degrees) per pair of poses (n,4,4): the error of b's position relative to a's
    (est frame; the truth turned into it by R_est_gt) and of b's rotation relative to a's."""
    d_est = est_b[:, :3, 3] - est_a[:, :3, 3]
    d_gt = (gt_b[:, :3, 3] - gt_a[:, :3, 3]) @ R_est_gt.T
    Q_est = np.swapaxes(est_a[:, :3, :3], 1, 2) @ est_b[:, :3, :3]
    Q_gt = np.swapaxes(gt_a[:, :3, :3], 1, 2) @ gt_b[:, :3, :3]
    tr = np.einsum("nij,nij->n", Q_est, Q_gt)  # trace(Q_est^T Q_gt)
    deg = np.degrees(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)))
    return np.linalg.norm(d_est - d_gt, axis=1), deg


def encounter_errors(
    est: Sequence[np.ndarray | None], gt: Sequence[np.ndarray], T_fleet_gt: np.ndarray,
    radius: float = ENCOUNTER_RADIUS,
) -> np.ndarray:
    """(n,) encounter errors (metres) of every keyframe pair of two different robots within
    `radius` in the truth; est[r] (k,4,4) fleet frame (None: robot unplaced, left out), gt[r]
    (k,4,4) ground-truth frame; T_fleet_gt maps the ground-truth frame into the fleet frame."""
    a, i, b, j = keyframe_pairs([g[:, :3, 3] for g in gt], radius)
    placed = np.array([e is not None for e in est])
    keep = placed[a] & placed[b]
    a, i, b, j = a[keep], i[keep], b[keep], j[keep]
    if len(a) == 0:
        return np.zeros(0)
    E = _stacked(est, a, i)
    G_a, G_b = _stacked(gt, a, i), _stacked(gt, b, j)
    return relative_errors(E, G_a, _stacked(est, b, j), G_b, T_fleet_gt[:3, :3])[0]


def _stacked(poses: Sequence[np.ndarray | None], r: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(n,4,4) poses[r[n]][k[n]]."""
    out = np.empty((len(r), 4, 4))
    for robot in np.unique(r):
        sel = r == robot
        out[sel] = poses[robot][k[sel]]
    return out


def error_stats(errors: np.ndarray) -> dict[str, float | int | None]:
    """{median, p95, max (metres; None without pairs), n} of encounter errors."""
    if len(errors) == 0:
        return {"median": None, "p95": None, "max": None, "n": 0}
    return {"median": float(np.median(errors)), "p95": float(np.percentile(errors, 95)),
            "max": float(errors.max()), "n": int(len(errors))}


def placement_error(
    est_a: np.ndarray, gt_a: np.ndarray, est_b: np.ndarray, gt_b: np.ndarray,
    R_est_gt: np.ndarray, radius: float = ENCOUNTER_RADIUS,
) -> tuple[float, float] | None:
    """(median metres, median degrees) of `relative_errors` over the pairs of a keyframe of
    set a and one of set b (each (k,4,4): estimated, true) that the truth puts within
    `radius` (none: the single closest pair): how far a placement of a is off against b where
    they meet. None when a set is empty."""
    from scipy.spatial import cKDTree

    if len(est_a) == 0 or len(est_b) == 0:
        return None
    near = cKDTree(gt_b[:, :3, 3]).query_ball_point(gt_a[:, :3, 3], radius)
    i = np.repeat(np.arange(len(gt_a)), [len(n) for n in near])
    j = np.concatenate([np.asarray(n, dtype=np.int64) for n in near])
    if len(i) == 0:
        dist, jj = cKDTree(gt_b[:, :3, 3]).query(gt_a[:, :3, 3])
        i = np.array([int(np.argmin(dist))])
        j = np.array([int(jj[i[0]])])
    m, deg = relative_errors(est_a[i], gt_a[i], est_b[j], gt_b[j], R_est_gt)
    return float(np.median(m)), float(np.median(deg))


def rigid_rmse(est: Sequence[np.ndarray], gt: Sequence[np.ndarray]) -> float | None:
    """RMSE (metres) of estimated positions against true ones (one (k,3) array per robot, in
    pairs) after ONE rigid alignment of all of them; None with fewer than 3 positions."""
    from sgloc.estimation.fits import fit_rigid

    if not est:
        return None
    E, G = np.concatenate(est).reshape(-1, 3), np.concatenate(gt).reshape(-1, 3)
    if len(E) < 3:
        return None
    T = fit_rigid(E, G)
    moved = E @ T[:3, :3].T + T[:3, 3]
    return float(np.sqrt(np.mean(np.sum((moved - G) ** 2, axis=1))))


def closure_pairs(
    gt: Sequence[np.ndarray], radius: float = CLOSURE_RADIUS, revisit: float = 30.0
) -> np.ndarray:
    """(n,4) (robot a, keyframe i, robot b, keyframe j) loop closures: for every keyframe, the
    nearest keyframe of each other robot within `radius` in the truth, and of its own robot
    when that one is more than `revisit` metres of travel away (a return, not the next step)."""
    from scipy.spatial import cKDTree

    pos = [g[:, :3, 3] for g in gt]
    robot = np.concatenate([np.full(len(p), r) for r, p in enumerate(pos)]).astype(np.int64)
    index = np.concatenate([np.arange(len(p)) for p in pos]).astype(np.int64)
    travel = np.concatenate([_arc_length(p) for p in pos])
    stacked = np.concatenate(pos)
    pairs = cKDTree(stacked).query_pairs(radius, output_type="ndarray")
    u, v = np.concatenate([pairs[:, 0], pairs[:, 1]]), np.concatenate([pairs[:, 1], pairs[:, 0]])
    keep = (robot[u] != robot[v]) | (np.abs(travel[u] - travel[v]) > revisit)
    u, v = u[keep], v[keep]
    dist = np.linalg.norm(stacked[u] - stacked[v], axis=1)
    order = np.lexsort((v, dist, robot[v], u))
    u, v = u[order], v[order]
    first = np.ones(len(u), bool)
    first[1:] = (u[1:] != u[:-1]) | (robot[v[1:]] != robot[v[:-1]])
    u, v = u[first], v[first]
    lo, hi = np.unique(np.column_stack([np.minimum(u, v), np.maximum(u, v)]), axis=0).T
    return np.column_stack([robot[lo], index[lo], robot[hi], index[hi]])


def _arc_length(p: np.ndarray) -> np.ndarray:
    """(k,) metres travelled up to each position."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def odometry_bend(est: np.ndarray, odom: np.ndarray) -> np.ndarray:
    """(k,) metres each keyframe of one robot's corrected trajectory (est (k,4,4), fleet frame)
    lies off its odometry (odom (k,4,4)) after one rigid fit of the two: how far the fleet's
    solution bent the robot's odometry (0 for a robot the solution moved rigidly)."""
    from sgloc.estimation.fits import fit_rigid

    E, P = np.asarray(est)[:, :3, 3], np.asarray(odom)[:, :3, 3]
    if len(E) < 3:
        return np.zeros(len(E))
    T = fit_rigid(E, P)
    return np.linalg.norm(E @ T[:3, :3].T + T[:3, 3] - P, axis=1)


def outside_truth_group(est: Sequence[np.ndarray | None], gt: Sequence[np.ndarray],
                        tol: float = 3.0) -> list[int]:
    """Indices of the placed robots (est[k] not None: (k,4,4) fleet-frame poses; gt[k] the true
    ones) outside the largest group that one rigid alignment puts on the truth: each placed
    robot's own rigid fit (fleet -> truth) is a candidate alignment; a robot is in its group
    when the median error of its keyframe positions under it is within `tol` metres; the
    candidate holding the most robots (ties: the lowest index) is the alignment."""
    from sgloc.estimation.fits import fit_rigid

    placed = [k for k, e in enumerate(est) if e is not None and len(e) >= 3]
    if not placed:
        return []
    fits = [fit_rigid(est[k][:, :3, 3], gt[k][:, :3, 3]) for k in placed]
    best: list[int] = []
    for T in fits:
        group = [k for k in placed if float(np.median(np.linalg.norm(
            est[k][:, :3, 3] @ T[:3, :3].T + T[:3, 3] - gt[k][:, :3, 3], axis=1))) <= tol]
        if len(group) > len(best):
            best = group
    return [k for k in placed if k not in best]
