"""How precisely a robot is placed: the covariance of its fleet frame composed along its path of
links from the root, and the error it predicts where the robot's objects are."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sgloc.estimation.covariance import point_covariance
from sgloc.geometry import invert
from sgloc.lie import adjoint
from sgloc.online.loops import invert_with_covariance
from sgloc.online.robots.link_selection import Edge


def chain_covariance(
    edges: Sequence[Edge], covariances: Sequence[np.ndarray], path: Sequence[int], root: int
) -> np.ndarray:
    """(6,6) covariance of T_root_robot composed along `path` (edge ids, from the root), right
    perturbation in the robot's frame ([rx ry rz tx ty tz], rad and m), the links independent:
    T_0p Exp(a) T_pr Exp(b) = T_0p T_pr Exp(Ad(T_pr^-1) a + b) to first order. Loops that also
    constrain the robot are not counted, so it is an upper bound of the pose graph's."""
    x, C = root, np.zeros((6, 6))
    for k in path:
        e = edges[k]
        if e.a == x:
            T, Ck, x = e.T_a_b, covariances[k], e.b
        else:
            (T, Ck), x = invert_with_covariance(e.T_a_b, covariances[k]), e.a
        Ad = adjoint(invert(T))
        C = Ad @ C @ Ad.T + Ck
    return 0.5 * (C + C.T)


def predicted_error(
    covariance: np.ndarray, points: np.ndarray, sigmas: float
) -> tuple[float, float]:
    """(metres, degrees): `sigmas` standard deviations of the error a pose covariance predicts,
    along its worst direction, at the centroid of `points` (n,3) (the pose's own frame), and of
    its rotation."""
    c = np.asarray(points, np.float64).reshape(-1, 3).mean(axis=0) if len(points) else np.zeros(3)
    P = point_covariance(covariance, c)
    s_t = float(np.sqrt(max(np.linalg.eigvalsh(P)[-1], 0.0)))
    s_r = float(np.sqrt(max(np.linalg.eigvalsh(covariance[:3, :3])[-1], 0.0)))
    return sigmas * s_t, float(np.degrees(sigmas * s_r))
