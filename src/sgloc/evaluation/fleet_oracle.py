"""The oracle of a drifting fleet: every robot's keyframes in one pose graph with the same
drifting odometry and PERFECT loop closures wherever the truth puts two keyframes within 10 m
(`fleet_metrics.closure_pairs`), solved with gtsam (Levenberg-Marquardt). What the odometry
itself allows: a fleet estimate cannot be expected to beat it. Needs gtsam (`oracle_fleet`
returns None without it)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sgloc.evaluation.fleet_metrics import CLOSURE_RADIUS, closure_pairs
from sgloc.geometry import invert
from sgloc.sim.drift import DriftModel

#: Floors of the odometry sigmas (rad, m) and the perfect closures' sigmas (rad, m).
FLOOR_RAD, FLOOR_M, CLOSURE_RAD, CLOSURE_M = 1e-5, 1e-3, 1e-5, 1e-3


def odometry_sigmas(step_m: float, level: float, model: DriftModel) -> np.ndarray:
    """(6,) sigmas [rx ry rz tx ty tz] (rad, m; gtsam Pose3 order) of one odometry step of
    `step_m` metres under the drift model at `level` (heading about the body z axis)."""
    bias = np.radians(level * model.bias_deg_per_m) * step_m
    walk = np.radians(level * model.walk_deg_per_sqrt_m) * np.sqrt(step_m)
    heading = max(float(np.hypot(bias, walk)), FLOOR_RAD)
    t = max(level * model.scale * step_m, FLOOR_M)
    return np.array([FLOOR_RAD, FLOOR_RAD, heading, t, t, t])


def connected_to_root(n: int, closures: np.ndarray, root: int) -> np.ndarray:
    """(n,) bool: the robots the closures connect to `root` (directly or through others)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    adj = coo_matrix((np.ones(len(closures)), (closures[:, 0], closures[:, 2])), shape=(n, n))
    _, comp = connected_components(adj, directed=False)
    return comp == comp[root]


def oracle_fleet(
    odometry: Sequence[np.ndarray], gt: Sequence[np.ndarray], root: int, level: float,
    model: DriftModel | None = None, radius: float = CLOSURE_RADIUS,
) -> list[np.ndarray | None] | None:
    """Per robot, (k,4,4) keyframe poses in the fleet frame (the root's odometry frame) of the
    oracle pose graph, or None for a robot the closures do not connect to the root; None when
    gtsam is not installed. odometry[r]: (k,4,4) drifting T_odom_sensor; gt[r]: (k,4,4) true
    poses in the ground-truth frame; level: the drift level the odometry's noise model uses."""
    from sgloc.online.robots.solve import gtsam_available

    if not gtsam_available():
        return None
    import gtsam

    model = model or DriftModel()
    closures = closure_pairs(gt, radius)
    used = connected_to_root(len(gt), closures, root)
    T_fleet_gt = odometry[root][0] @ invert(gt[root][0])
    first = np.concatenate([[0], np.cumsum([len(g) for g in gt])])
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(int(first[root]), gtsam.Pose3(odometry[root][0]),
                                     gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    for r in np.flatnonzero(used):
        odo = odometry[r]
        for k in range(len(odo)):
            values.insert(int(first[r] + k), gtsam.Pose3(T_fleet_gt @ gt[r][k]))
        for k in range(1, len(odo)):
            step = invert(odo[k - 1]) @ odo[k]
            sig = odometry_sigmas(float(np.linalg.norm(step[:3, 3])), level, model)
            graph.add(gtsam.BetweenFactorPose3(int(first[r] + k - 1), int(first[r] + k),
                                               gtsam.Pose3(step),
                                               gtsam.noiseModel.Diagonal.Sigmas(sig)))
    closure_noise = gtsam.noiseModel.Diagonal.Sigmas(
        np.array([CLOSURE_RAD] * 3 + [CLOSURE_M] * 3))
    for a, i, b, j in closures[used[closures[:, 0]]]:
        rel = invert(gt[a][i]) @ gt[b][j]
        graph.add(gtsam.BetweenFactorPose3(int(first[a] + i), int(first[b] + j),
                                           gtsam.Pose3(rel), closure_noise))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    return [np.stack([result.atPose3(int(first[r] + k)).matrix() for k in range(len(gt[r]))])
            if used[r] else None for r in range(len(gt))]
