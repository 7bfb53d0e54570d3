"""One robot's recorded keyframes: stamps, odometry poses and what each keyframe saw.

The common in-memory form of every replay input (plain layout, ROS 2 bag, cut data sets).
Stamps are kept as integer nanoseconds (exact for any decimal stamp a file can hold, and what
ROS messages carry), poses as translation + unit quaternion (x, y, z, w) as in TUM files and
ROS messages, so that a log written in one form and read back in another is bit-identical.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation

import numpy as np

from sgloc.errors import DatasetError
from sgloc.io.keyframe_checks import check_increasing, check_quaternions


@dataclass(frozen=True)
class RobotLog:
    """The keyframes of one robot.

    name: robot name (unique in a fleet).
    stamps_ns: (N,) int64 keyframe stamps, nanoseconds, strictly increasing.
    xyz, quat: (N,3) metres and (N,4) unit quaternions (x, y, z, w): T_odom_sensor of each
        keyframe (the sensor pose in the robot's odometry frame).
    keyframe: (M,) int64 index into the keyframes of each observed object.
    positions: (M,3) object positions in that keyframe's SENSOR frame, metres.
    labels: (M,) int64 class ids (>= 0).
    """

    name: str
    stamps_ns: np.ndarray
    xyz: np.ndarray
    quat: np.ndarray
    keyframe: np.ndarray
    positions: np.ndarray
    labels: np.ndarray

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    @property
    def stamps(self) -> np.ndarray:
        """(N,) keyframe stamps in seconds (float64)."""
        return self.stamps_ns * 1e-9

    @property
    def poses(self) -> np.ndarray:
        """(N,4,4) T_odom_sensor of each keyframe."""
        from scipy.spatial.transform import Rotation  # deferred: scipy.spatial loads slowly

        T = np.tile(np.eye(4), (len(self), 1, 1))
        q = self.quat / np.linalg.norm(self.quat, axis=1, keepdims=True)
        T[:, :3, :3] = Rotation.from_quat(q).as_matrix()
        T[:, :3, 3] = self.xyz
        return T

    def observations(self) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        """(keyframe index, positions (n,3) sensor frame, labels (n,)) for every keyframe, in
        order (n may be 0)."""
        bounds = np.searchsorted(self.keyframe, np.arange(len(self) + 1))
        for i in range(len(self)):
            s = slice(bounds[i], bounds[i + 1])
            yield i, self.positions[s], self.labels[s]


def make_robot_log(
    name: str,
    stamps_ns: np.ndarray,
    xyz: np.ndarray,
    quat: np.ndarray,
    keyframe: np.ndarray,
    positions: np.ndarray,
    labels: np.ndarray,
    where: str = "",
) -> RobotLog:
    """A checked RobotLog (observations sorted by keyframe, stably); DatasetError naming
    `where` when stamps do not increase, a pose is not finite or a quaternion is zero."""
    where = where or f"robot {name!r}"
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    quat = np.asarray(quat, dtype=np.float64).reshape(-1, 4)
    if len(stamps_ns) == 0:
        raise DatasetError(f"{where}: no keyframes; give at least one odometry pose.")
    # The same stamp and pose rules as the online session's (sgloc.io.keyframe_checks).
    check_increasing(where, stamps_ns, format_stamp, DatasetError)
    if not np.all(np.isfinite(xyz)):
        raise DatasetError(f"{where}: NaN or infinite odometry values; fix or drop those poses.")
    check_quaternions(where, quat, DatasetError)
    keyframe = np.asarray(keyframe, dtype=np.int64).reshape(-1)
    order = np.argsort(keyframe, kind="stable")
    return RobotLog(
        name,
        stamps_ns,
        xyz,
        quat,
        keyframe[order],
        np.asarray(positions, dtype=np.float64).reshape(-1, 3)[order],
        np.asarray(labels, dtype=np.int64).reshape(-1)[order],
    )


#: Integer stamps (digits only: no decimal point, no exponent) from this value on are integer
#: nanoseconds (a common ROS export; 1e17 ns is 1973), smaller ones seconds.
NS_INTEGER_MIN = 10**17
#: Integer stamps from this value (1e11 s is the year 5138) up to NS_INTEGER_MIN are neither
#: plausible seconds nor nanoseconds since 1973 (milliseconds or microseconds): refused.
UNCLEAR_INTEGER_MIN = 10**11
INT64_MAX = 2**63 - 1
_MAX_SECONDS = Decimal(INT64_MAX).scaleb(-9)
STAMP_RULE = (
    "write seconds (`1700000043.75`) or integer nanoseconds (`1700000043750000000`, digits only)"
)


def parse_stamp(text: str, where: str = "") -> int:
    """A stamp -> exact integer nanoseconds. Seconds as any decimal (`1403636579.763555527`,
    `12`, `1.5e3`), or integer nanoseconds: digits only and >= NS_INTEGER_MIN
    (`1403636579763555527`). ValueError if it is not a finite number; DatasetError naming
    `where` for an integer in the unclear range or a stamp beyond int64 nanoseconds."""
    t = text.strip()
    try:
        d = Decimal(t)
    except InvalidOperation:
        raise ValueError(text) from None
    if not d.is_finite():
        raise ValueError(text)
    digits = t.lstrip("+-").isdigit()
    if digits and UNCLEAR_INTEGER_MIN <= d.copy_abs() < NS_INTEGER_MIN:
        raise DatasetError(
            f"{where}: stamp {t} is an integer too large for seconds and too small for "
            f"nanoseconds since 1973 (milliseconds or microseconds?); {STAMP_RULE}."
        )
    ns = d if digits and d.copy_abs() >= NS_INTEGER_MIN else None
    if ns is None and d.copy_abs() <= _MAX_SECONDS:  # compared first: 1e999999999 * 1e9 overflows
        ns = d * 1_000_000_000
    if ns is None or ns.copy_abs() > INT64_MAX:  # a Decimal: never a Python int of a million digits
        raise DatasetError(
            f"{where}: stamp {t[:40]} is beyond the range of stamps (+-{INT64_MAX // 10**9} s, "
            f"the year 2262, in nanoseconds); {STAMP_RULE}."
        )
    return int(ns.to_integral_value())


def format_stamp(ns: int | np.integer) -> str:
    """Integer nanoseconds -> `seconds.nanoseconds` text (exact; parse_stamp inverts it)."""
    ns = int(ns)
    sign = "-" if ns < 0 else ""
    s, f = divmod(abs(ns), 1_000_000_000)
    return f"{sign}{s}.{f:09d}"


def float_text(x: float) -> str:
    """The shortest text that reads back as exactly `x`."""
    return repr(float(x))
