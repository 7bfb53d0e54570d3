"""Rigid transforms as 4x4 float64 arrays `T_to_from` (p_to = R @ p_from + t)."""

from __future__ import annotations

import numpy as np


def make_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Build a 4x4 transform from a 3x3 rotation and a 3-vector translation (metres)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform."""
    R, t = T[:3, :3], T[:3, 3]
    return make_transform(R.T, -R.T @ t)


def apply(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map (n,3) points by T."""
    return np.asarray(points) @ T[:3, :3].T + T[:3, 3]


def random_rigid_transform(
    rng: np.random.Generator,
    max_translation: float = 200.0,
    max_roll_pitch_deg: float = 5.0,
) -> np.ndarray:
    """A random rigid transform: any yaw, roll and pitch up to `max_roll_pitch_deg` degrees,
    translation uniform in a ball of radius `max_translation` metres (z axis is up)."""
    yaw = rng.uniform(-np.pi, np.pi)
    roll, pitch = np.deg2rad(rng.uniform(-max_roll_pitch_deg, max_roll_pitch_deg, 2))
    from scipy.spatial.transform import Rotation  # deferred: scipy.spatial loads in ~0.2 s

    R = Rotation.from_euler("zyx", [yaw, pitch, roll]).as_matrix()
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    t = direction * max_translation * rng.uniform() ** (1 / 3)
    return make_transform(R, t)


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation matrix, degrees in [0, 180]."""
    # atan2(sin, cos) keeps full precision near 0 and 180 degrees, unlike arccos of the trace.
    s = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    c = 0.5 * (np.trace(R) - 1.0)
    return float(np.degrees(np.arctan2(s, c)))


def transform_error(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    """(translation error m, rotation error deg) of `T_err = T_est @ inv(T_gt)`.

    Both transforms map the same source frame into the same target frame; the error is
    therefore expressed in the target frame, as the paper measures it.
    """
    E = T_est @ invert(T_gt)
    return float(np.linalg.norm(E[:3, 3])), rotation_angle_deg(E[:3, :3])


def regularized_covariance(cov: np.ndarray, floor: float = 1e-12) -> np.ndarray:
    """A covariance made symmetric with eigenvalues >= `floor`, so that it can be inverted
    (an information matrix) or factorised whatever its source."""
    c = np.asarray(cov, dtype=np.float64)
    c = 0.5 * (c + c.T)
    w, v = np.linalg.eigh(c)
    return (v * np.maximum(w, floor)) @ v.T


def translation_error_at(T_est: np.ndarray, T_gt: np.ndarray, point: np.ndarray) -> float:
    """How far apart (metres) T_est and T_gt put `point` (3,) of their common source frame:
    the translation error where the maps overlap when `point` is the query objects' centroid
    (`transform_error` measures at the target frame's origin instead)."""
    p = np.append(np.asarray(point, dtype=np.float64).reshape(3), 1.0)
    return float(np.linalg.norm((T_est @ p - T_gt @ p)[:3]))
