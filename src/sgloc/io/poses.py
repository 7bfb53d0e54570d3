"""Pose files: KITTI (12 values a row, row-major 3x4) and TUM (`t x y z qx qy qz qw`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sgloc.errors import DatasetError
from sgloc.io.keyframes import float_text, format_stamp, parse_stamp
from sgloc.io.text import read_numbers, read_text_file


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


def read_tum(path: Path, increasing: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stamps_ns (N,), xyz (N,3), quat (N,4), x-first) of a TUM file (`stamp tx ty tz qx qy qz
    qw` rows, `#` comments), stamps exact: the one TUM reader. `increasing`: a stamp that
    repeats or goes back is refused naming its line (keyframe poses)."""
    stamps, vals, lines = [], [], []
    for n, line in enumerate(read_text_file(path, "TUM odometry file").splitlines(), 1):
        s = line.split("#", 1)[0].split()
        if not s:
            continue
        if len(s) != 8:
            raise DatasetError(
                f"{path}:{n}: expected 8 values `stamp tx ty tz qx qy qz qw`, got {len(s)}."
            )
        try:
            stamps.append(parse_stamp(s[0], f"{path}:{n}"))
            vals.append([float(v) for v in s[1:]])
        except DatasetError:  # a stamp out of range: its own message
            raise
        except ValueError:
            raise DatasetError(f"{path}:{n}: non-numeric value in {line.strip()[:60]!r}.") from None
        if not np.all(np.isfinite(vals[-1])):
            raise DatasetError(f"{path}:{n}: NaN or infinite value; fix or drop the line.")
        if len(vals) == 1:
            check_quaternion_order(vals[0][3:], f"{path}:{n}")
        elif increasing and stamps[-1] <= stamps[-2]:
            how = "repeats" if stamps[-1] == stamps[-2] else "comes before"
            raise DatasetError(f"{path}:{n}: stamp {s[0]} {how} the stamp of line {lines[-1]}; "
                               "give one pose per stamp, in increasing order.")
        lines.append(n)
    if not stamps:
        raise DatasetError(f"{path}: no poses; give `stamp tx ty tz qx qy qz qw` lines.")
    v = np.array(vals, dtype=np.float64)
    return np.array(stamps, dtype=np.int64), v[:, :3], v[:, 3:]


def check_quaternion_order(quat: Sequence[float], where: str) -> None:
    """DatasetError naming `where` when a first pose's quaternion, read x-first (qx qy qz qw),
    is exactly a half turn about x, `1 0 0 0`: the identity written w-first (qw qx qy qz), the
    usual start of an odometry file whose columns are in the wrong order."""
    qx, qy, qz, qw = (float(v) for v in quat)
    if abs(qx) == 1.0 and qy == qz == qw == 0.0:
        raise DatasetError(
            f"{where}: the first pose's quaternion reads, in the TUM order qx qy qz qw, as a half "
            "turn about x, and as the identity if written w-first: the quaternions look written "
            "`qw qx qy qz`; write each line `stamp tx ty tz qx qy qz qw` (qw last). A first "
            "pose that really is a half turn about x: write its qw as 1e-12, not 0."
        )


def write_tum(
    path: str | Path, stamps_ns: np.ndarray, xyz: np.ndarray, quat: np.ndarray
) -> Path:
    """Write TUM rows `stamp tx ty tz qx qy qz qw`, stamps and values exactly (read_tum gives
    back the same numbers): the one TUM writer."""
    rows = [
        " ".join([format_stamp(s), *map(float_text, (*p, *q))])
        for s, p, q in zip(stamps_ns, xyz, quat, strict=True)
    ]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(f"{r}\n" for r in rows))
    return path


def read_tum_poses(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps (N,) in seconds, poses (N,4,4)) of a TUM file (`read_tum`)."""
    stamps_ns, xyz, quat = read_tum(Path(path))
    from scipy.spatial.transform import Rotation  # deferred: scipy.spatial loads in ~0.2 s

    T = np.tile(np.eye(4), (len(xyz), 1, 1))
    unit = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    T[:, :3, :3] = Rotation.from_quat(unit).as_matrix()
    T[:, :3, 3] = xyz
    return stamps_ns / 1e9, T


def write_tum_poses(path: str | Path, timestamps: np.ndarray, poses: np.ndarray) -> Path:
    """Write (N,4,4) poses at `timestamps` (seconds, kept to the nanosecond) as TUM rows
    (`write_tum`)."""
    from scipy.spatial.transform import Rotation

    poses = np.asarray(poses)
    stamps_ns = np.round(np.asarray(timestamps, np.float64) * 1e9).astype(np.int64)
    quat = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
    return write_tum(path, stamps_ns, poses[:, :3, 3], quat)
