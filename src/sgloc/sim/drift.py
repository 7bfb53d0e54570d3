"""A seeded odometry drift model: what a good LiDAR odometry does to a robot's keyframe poses.

Level 1 (a good LiDAR odometry): a scale error of 0.5 % on every step's translation, a heading
bias of 0.002 deg per metre travelled and a heading random walk of 0.002 deg per sqrt(metre);
level L multiplies all three by L (level 0: no drift, the poses unchanged bit for bit). The
signs of the scale error and of the bias are drawn once per robot. The heading error turns
about the odometry frame's up axis (`DriftModel.up`); the first keyframe keeps its pose, so the
odometry frame stays where it was. Only the keyframe poses drift: what each keyframe saw stays
in its sensor frame. """

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sgloc.errors import SglocError
from sgloc.io.keyframes import RobotLog
from sgloc.lie import axis_rotation


@dataclass(frozen=True)
class DriftModel:
    """Drift at level 1: scale (fraction of each step's length), bias_deg_per_m (heading
    degrees per metre travelled), walk_deg_per_sqrt_m (heading random walk, degrees per
    sqrt(metre)); up: the unit axis of the odometry frame the heading turns about."""

    scale: float = 0.005
    bias_deg_per_m: float = 0.002
    walk_deg_per_sqrt_m: float = 0.002
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)


def heading_and_positions(
    xyz: np.ndarray, level: float, rng: np.random.Generator, model: DriftModel | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(heading error (k,) radians, drifted positions (k,3) metres) of true keyframe positions
    `xyz` (k,3, odometry frame) at drift `level`. Step k's translation is scaled by (1 + s) and
    turned by the heading error reached at keyframe k; the first keyframe keeps its place."""
    model = model or DriftModel()
    if not (np.isfinite(level) and level >= 0):
        raise SglocError(f"drift level {level!r}: give a level >= 0 (0 = no drift).")
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    sign_scale, sign_bias = rng.choice([-1.0, 1.0], size=2)
    step = np.diff(xyz, axis=0)
    d = np.linalg.norm(step, axis=1)
    walk = rng.standard_normal(len(d)) * np.radians(level * model.walk_deg_per_sqrt_m) * np.sqrt(d)
    bias = sign_bias * np.radians(level * model.bias_deg_per_m) * d
    psi = np.concatenate([[0.0], np.cumsum(bias + walk)])
    R = axis_rotation(np.asarray(model.up, dtype=np.float64), psi[1:])
    moved = (1.0 + sign_scale * level * model.scale) * np.einsum("kij,kj->ki", R, step)
    # drifted = true + accumulated error, so that level 0 leaves every position bit-identical
    error = np.concatenate([np.zeros((1, 3)), np.cumsum(moved - step, axis=0)])
    return psi, xyz + error


def drift_poses(
    poses: np.ndarray, level: float, rng: np.random.Generator, model: DriftModel | None = None
) -> np.ndarray:
    """(k,4,4) drifting odometry poses T_odom_sensor from the true ones (k,4,4), at `level`."""
    model = model or DriftModel()
    poses = np.asarray(poses, dtype=np.float64)
    psi, xyz = heading_and_positions(poses[:, :3, 3], level, rng, model)
    out = poses.copy()
    out[:, :3, :3] = axis_rotation(np.asarray(model.up, dtype=np.float64), psi) @ poses[:, :3, :3]
    out[:, :3, 3] = xyz
    return out


def drift_log(
    log: RobotLog, level: float, rng: np.random.Generator, model: DriftModel | None = None
) -> RobotLog:
    """`log` with its keyframe poses drifting at `level` (sightings, stamps and name kept).
    Quaternions are turned by quaternion product, so level 0 returns identical values."""
    model = model or DriftModel()
    psi, xyz = heading_and_positions(log.xyz, level, rng, model)
    u = np.asarray(model.up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    h = np.column_stack([np.outer(np.sin(psi / 2), u), np.cos(psi / 2)])  # (x, y, z, w)
    return dataclasses.replace(log, xyz=xyz, quat=quaternion_product(h, log.quat))


def quaternion_product(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(k,4) Hamilton products p * q of (x, y, z, w) quaternions (rotation q, then p)."""
    pv, pw, qv, qw = p[:, :3], p[:, 3:], q[:, :3], q[:, 3:]
    v = pw * qv + qw * pv + np.cross(pv, qv)
    w = pw * qw - np.sum(pv * qv, axis=1, keepdims=True)
    return np.column_stack([v, w])
