"""Checks of keyframes, poses and links, shared by the file readers (plain layout, bags) and the
online session (its calls and its saved files): stamps are finite, within int64 nanoseconds
and strictly increasing per robot; poses are rigid (orthonormal rotation, det +1, bottom row
0 0 0 1) and within the coordinate limit; a keyframe's sightings stay within it once moved into
the odometry frame. Each failure is an SglocError naming the value and the fix; nothing is
changed before a check passes. Imports nothing of the pipeline, so every stage may use it."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from sgloc.errors import SglocError
from sgloc.validation import MAX_CLASSES, MAX_COORDINATE, MAX_VERTICES, check_graph_arrays

#: Largest |stamp|, seconds: int64 nanoseconds (how bags, TUM exports and the outputs hold it).
MAX_STAMP = (2**63 - 1) // 1_000_000_000
#: Largest deviation of R^T R from the identity (and of det R from 1, and of the bottom row from
#: 0 0 0 1) a rotation may have: float32 poses and chained products stay orders below it, while a
#: scaled (x1.0001 or more), sheared or mirrored matrix is far beyond it.
ROTATION_TOLERANCE = 1e-4


class InvalidKeyframeError(SglocError):
    """A keyframe, pose or link that is not what the session can hold: a stamp that does not
    increase, a pose that is not rigid, sightings beyond the coordinate limit."""


def check_stamp(where: str, stamp: Any, error: type[SglocError] = InvalidKeyframeError) -> float:
    """`stamp` (seconds) as a float: finite and within +-MAX_STAMP."""
    try:
        s = float(stamp)
    except (TypeError, ValueError, OverflowError):
        s = math.nan
    if not math.isfinite(s) or abs(s) > MAX_STAMP:
        raise error(
            f"{where}: stamp {stamp!r:.40} is not a finite number of seconds within "
            f"+-{MAX_STAMP} s; give stamps in seconds (not nanoseconds)."
        )
    return s


def first_not_increasing(stamps: np.ndarray) -> int | None:
    """Index of the first stamp that is not strictly greater than the one before (None: all
    increase)."""
    bad = np.flatnonzero(np.diff(np.asarray(stamps)) <= 0)
    return None if bad.size == 0 else int(bad[0]) + 1


def check_increasing(
    where: str,
    stamps: Sequence[Any] | np.ndarray,
    text: Callable[[Any], str] = str,
    error: type[SglocError] = InvalidKeyframeError,
) -> None:
    """Refuse keyframe stamps that go backwards or repeat (`text` formats a stamp for the
    message, e.g. nanoseconds as seconds)."""
    k = first_not_increasing(np.asarray(stamps))
    if k is not None:
        raise error(
            f"{where}: keyframe {k + 1} (stamp {text(stamps[k])}) does not come after the one "
            f"before (stamp {text(stamps[k - 1])}); give keyframes in increasing stamp order, "
            "one pose per stamp."
        )


def check_quaternions(where: str, quat: np.ndarray,
                      error: type[SglocError] = InvalidKeyframeError) -> None:
    """Refuse (n,4) quaternions that are not finite or are zero (they are normalised after)."""
    q = np.asarray(quat, dtype=np.float64).reshape(-1, 4)
    if not np.all(np.isfinite(q)):
        raise error(f"{where}: NaN or infinite odometry values; fix or drop those poses.")
    if np.any(np.linalg.norm(q, axis=1) < 1e-9):
        raise error(f"{where}: a zero quaternion; give unit quaternions qx qy qz qw.")


def rigid_defect(T: np.ndarray) -> np.ndarray:
    """(k,) how far each of (k,4,4) transforms is from rigid: the largest of |R^T R - I|,
    |det R - 1| and |bottom row - (0 0 0 1)| (NaN -> inf)."""
    T = np.asarray(T, dtype=np.float64).reshape(-1, 4, 4)
    R = T[:, :3, :3]
    gram = np.abs(np.einsum("kji,kjl->kil", R, R) - np.eye(3)).max(axis=(1, 2), initial=0.0)
    det = np.abs(np.linalg.det(R) - 1.0) if len(T) else np.zeros(0)
    row = np.abs(T[:, 3, :] - [0.0, 0.0, 0.0, 1.0]).max(axis=1, initial=0.0)
    d = np.maximum(np.maximum(gram, det), row)
    return np.where(np.isfinite(d), d, np.inf)


def _finite_matrix(where: str, value: Any, shape: tuple[int, int], rule: str,
                   error: type[SglocError]) -> np.ndarray:
    """`value` as a float64 array of `shape`, all finite; else `error`: "where: rule, got ..."."""
    try:
        M = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        M = np.zeros(0)
    if M.shape != shape or not np.all(np.isfinite(M)):
        raise error(f"{where}: {rule}, got "
                    f"{'shape ' + str(M.shape) if M.shape != shape else 'NaN or inf'}.")
    return M


def check_rigid(where: str, T: Any, name: str = "pose",
                error: type[SglocError] = InvalidKeyframeError) -> np.ndarray:
    """`T` as a (4,4) float64 rigid transform (orthonormal rotation with det +1, bottom row
    0 0 0 1, translation within +-MAX_COORDINATE m); else `error` naming `where` and `name`."""
    M = _finite_matrix(where, T, (4, 4), f"{name} must be a finite 4x4 matrix", error)
    defect = float(rigid_defect(M)[0])
    if defect > ROTATION_TOLERANCE:
        det = float(np.linalg.det(M[:3, :3]))
        raise error(
            f"{where}: {name} is not a rigid transform (rotation det {det:.6g}, off orthonormal "
            f"by {defect:.3g}; a scaled, mirrored, sheared or zero rotation block, or a bottom "
            "row other than 0 0 0 1); give a rotation matrix and a translation in metres."
        )
    if np.abs(M[:3, 3]).max() > MAX_COORDINATE:
        raise error(f"{where}: {name} translation {M[:3, 3].tolist()} is beyond "
                    f"+-{MAX_COORDINATE:g} m; give metres in a local frame.")
    return M


def check_covariance(where: str, cov: Any,
                     error: type[SglocError] = InvalidKeyframeError) -> np.ndarray:
    """`cov` as a (6,6) float64 covariance: finite, entries within +-MAX_VARIANCE, symmetric
    and positive semi-definite (to 1e-9 relative)."""
    C = _finite_matrix(where, cov, (6, 6),
                       "covariance must be a finite 6x6 matrix (rx ry rz tx ty tz)", error)
    if np.abs(C).max() > MAX_VARIANCE:
        raise error(f"{where}: covariance entries must be within +-{MAX_VARIANCE:g} (rad^2, "
                    "m^2); a larger variance carries no information.")
    scale = max(float(np.abs(C).max()), 1e-300)
    if (np.abs(C - C.T).max() > 1e-9 * scale
            or np.linalg.eigvalsh(0.5 * (C + C.T)).min() < -1e-9 * scale):
        raise error(f"{where}: covariance must be symmetric positive semi-definite.")
    return C


#: Largest variance (rad^2 or m^2) a link's covariance may hold: a standard deviation of 1 km
#: (or 1000 rad) is no information already, and larger values make the solvers ill-conditioned.
MAX_VARIANCE = 1e6


def check_link(
    where: str, T_a_b: Any, covariance: Any, confidence: Any = 1.0, stamp: Any = None
) -> tuple[np.ndarray, np.ndarray, float, float | None]:
    """(T_a_b (4,4), covariance (6,6), confidence, stamp or None) of a link, checked: T rigid,
    the covariance finite, symmetric, positive semi-definite with variances <= MAX_VARIANCE,
    the confidence in [0, 1], the stamp (when given) as `check_stamp`."""
    T = check_rigid(where, T_a_b, "T_a_b")
    C = check_covariance(where, covariance)
    try:
        c = float(confidence)
    except (TypeError, ValueError):
        c = math.nan
    if not 0.0 <= c <= 1.0:
        raise InvalidKeyframeError(f"{where}: confidence {confidence!r:.40} must be in [0, 1].")
    return T, C, c, None if stamp is None else check_stamp(where, stamp)


def check_keyframe(
    where: str,
    stamp: Any,
    previous: float | None,
    T_odom_sensor: Any,
    positions: Any,
    labels: Any,
    map_labels: np.ndarray | None = None,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(stamp, T (4,4), positions (n,3), labels (n,)) of one keyframe, checked: the stamp
    after `previous` (the robot's last; None for its first), T rigid, the sightings valid graph
    arrays that stay within +-MAX_COORDINATE m once moved into the odometry frame, and the
    robot's map (`map_labels`: its objects' class ids so far) within MAX_VERTICES objects and
    MAX_CLASSES classes with them."""
    s = check_stamp(where, stamp)
    if previous is not None:
        check_increasing(where, [previous, s], lambda v: f"{v!r} s")
    T = check_rigid(where, T_odom_sensor, "T_odom_sensor")
    pos, lab = check_graph_arrays(f"{where} keyframe", positions, labels)
    moved = pos @ T[:3, :3].T + T[:3, 3]
    if moved.size and not np.abs(moved).max() <= MAX_COORDINATE:
        raise InvalidKeyframeError(
            f"{where}: the keyframe's pose puts its sightings beyond +-{MAX_COORDINATE:g} m in "
            "the odometry frame; give the pose and positions in metres in a local frame."
        )
    if map_labels is not None and len(lab):
        if len(map_labels) + len(lab) > MAX_VERTICES:
            raise InvalidKeyframeError(
                f"{where}: the robot's map would exceed {MAX_VERTICES:,} objects; split the "
                "run into several robots or drop small detections."
            )
        # Ids below MAX_CLASSES cannot name more classes than that: no count needed.
        small = lab.max() < MAX_CLASSES and (len(map_labels) == 0
                                             or map_labels.max() < MAX_CLASSES)
        n_classes = 0 if small else len(np.union1d(map_labels, lab))
        if n_classes > MAX_CLASSES:
            raise InvalidKeyframeError(
                f"{where}: the robot's map would hold {n_classes} distinct classes, more than "
                f"the limit of {MAX_CLASSES}; are the labels class ids (not instance ids)?"
            )
    return s, T, pos, lab
