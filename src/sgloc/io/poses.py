"""Pose files: KITTI (12 values a row, row-major 3x4) and TUM (`t x y z qx qy qz qw`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.io.text import read_numbers


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """(N,4,4) poses from a KITTI pose file (each row: a row-major 3x4 [R | t])."""
    vals = read_numbers(Path(path), "KITTI pose file (12 values a row)", per_row=12)
    T = np.tile(np.eye(4), (len(vals), 1, 1))
    T[:, :3, :] = vals.reshape(-1, 3, 4)
    return T


def write_kitti_poses(path: str | Path, poses: np.ndarray) -> Path:
    """Write (N,4,4) poses as KITTI rows (12 values, row-major 3x4)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(p, np.asarray(poses)[:, :3, :].reshape(-1, 12), fmt="%.9e")
    return p


def read_tum_poses(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps (N,), poses (N,4,4)) from a TUM file (`t x y z qx qy qz qw` rows)."""
    vals = read_numbers(Path(path), "TUM pose file (t x y z qx qy qz qw)", per_row=8)
    T = np.tile(np.eye(4), (len(vals), 1, 1))
    q = vals[:, 4:8]
    from scipy.spatial.transform import Rotation  # deferred: scipy.spatial loads in ~0.2 s

    T[:, :3, :3] = Rotation.from_quat(q / np.linalg.norm(q, axis=1, keepdims=True)).as_matrix()
    T[:, :3, 3] = vals[:, 1:4]
    return vals[:, 0], T


def write_tum_poses(path: str | Path, timestamps: np.ndarray, poses: np.ndarray) -> Path:
    """Write TUM rows `t x y z qx qy qz qw`."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    poses = np.asarray(poses)
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
    rows = np.column_stack([np.asarray(timestamps, float), poses[:, :3, 3], q])
    np.savetxt(p, rows, fmt="%.9f")
    return p
