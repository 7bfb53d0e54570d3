"""The loop rules the back-ends share: how far a loop of links may disagree, measured at a
map's centroid, and a link seen from its other end."""

from __future__ import annotations

import numpy as np

from sgloc.geometry import apply, invert, rotation_angle_deg
from sgloc.lie import adjoint


def invert_with_covariance(T_a_b: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T_b_a, its covariance) from T_a_b and its covariance ([rx ry rz tx ty tz], right
    perturbation): T_a_b Exp(xi) inverted is T_b_a Exp(-Ad(T_a_b) xi) (`sgloc.lie.adjoint`)."""
    ad = adjoint(T_a_b)
    return invert(T_a_b), ad @ cov @ ad.T


def loop_error(T_loop: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """(displacement of the centroid of `points` by T_loop in metres, T_loop's rotation angle
    in degrees). At the centroid, not RMS over the points: over a map hundreds of metres long a
    rotation within the angle tolerance alone would move the far objects by metres."""
    return error_at(T_loop, centroid(points))


def centroid(points: np.ndarray) -> np.ndarray:
    """(1,3) the mean of `points` (n,3) (the origin when there are none), as `loop_error`
    takes it."""
    return np.asarray(points, np.float64).reshape(-1, 3).mean(axis=0, keepdims=True) if len(
        points) else np.zeros((1, 3))


def error_at(T_loop: np.ndarray, c: np.ndarray) -> tuple[float, float]:
    """`loop_error` at a given centroid c (1,3)."""
    return float(np.linalg.norm(apply(T_loop, c) - c)), rotation_angle_deg(T_loop[:3, :3])


def loop_tolerance(tol_m: float, tol_deg: float, n_links: int) -> tuple[float, float]:
    """What a loop of `n_links` links, each within tol_m / tol_deg of the truth, may disagree
    by: the links' independent errors add in quadrature, so tol * sqrt(n_links)."""
    f = float(np.sqrt(n_links))
    return tol_m * f, tol_deg * f
