"""Least-squares fleet frame: robots' odometry frames as Pose3 nodes, links as between factors
weighted by their covariance; gtsam when installed, else scipy.optimize.least_squares."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sgloc.errors import SglocError
from sgloc.geometry import invert, regularized_covariance
from sgloc.lie import product_exp, product_log
from sgloc.online.robots.link_selection import Edge


def gtsam_available() -> bool:
    try:
        import gtsam  # noqa: F401
    except ImportError:
        return False
    return True


def solve_pose_graph(
    initial: dict[int, np.ndarray],
    edges: Sequence[Edge],
    covariances: Sequence[np.ndarray],
    root: int,
    solver: str = "auto",
) -> dict[int, np.ndarray]:
    """T_fleet_robot for the nodes of `initial` (root fixed at its initial pose).

    edges: links among those nodes (T_a_b ~ inv(X_a) @ X_b); covariances: (6,6) each, in
    [rx ry rz tx ty tz] order, right perturbation (GTSAM Pose3's convention).
    """
    if len(edges) < len(initial):  # a tree: the initial poses already satisfy every link
        return dict(initial)
    use_gtsam = solver == "gtsam" or (solver == "auto" and gtsam_available())
    if solver == "gtsam" and not gtsam_available():
        raise SglocError("solver 'gtsam' needs gtsam: pip install 'sgloc[gtsam]' (or use 'scipy').")
    return (_solve_gtsam if use_gtsam else _solve_scipy)(initial, edges, covariances, root)


def _solve_gtsam(initial, edges, covariances, root):
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k, T in initial.items():
        values.insert(k, gtsam.Pose3(T))
    graph.add(gtsam.NonlinearEqualityPose3(root, gtsam.Pose3(initial[root])))
    for e, cov in zip(edges, covariances, strict=True):
        noise = gtsam.noiseModel.Gaussian.Covariance(regularized_covariance(cov))
        graph.add(gtsam.BetweenFactorPose3(e.a, e.b, gtsam.Pose3(e.T_a_b), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    return {k: result.atPose3(k).matrix() for k in initial}


def _solve_scipy(initial, edges, covariances, root):
    from scipy.optimize import least_squares

    free = [k for k in sorted(initial) if k != root]
    slot = {k: i for i, k in enumerate(free)}
    # Whitening: r_w = U @ r with U.T @ U = inverse covariance.
    whiten = [np.linalg.cholesky(np.linalg.inv(regularized_covariance(c))).T for c in covariances]
    inv_meas = [invert(e.T_a_b) for e in edges]

    def poses(x):
        return {k: initial[k] if k == root
                else initial[k] @ product_exp(x[6 * slot[k]: 6 * slot[k] + 6]) for k in initial}

    def residuals(x):
        X = poses(x)
        return np.concatenate([
            U @ product_log(Mi @ invert(X[e.a]) @ X[e.b])
            for e, Mi, U in zip(edges, inv_meas, whiten, strict=True)
        ])

    sol = least_squares(residuals, np.zeros(6 * len(free)), method="trf", xtol=1e-12,
                        ftol=1e-12, gtol=1e-12)
    return poses(sol.x)
