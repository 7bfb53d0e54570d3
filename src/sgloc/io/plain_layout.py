"""The plain replay layout: one folder per robot, anyone can write it.

    <layout>/
        classes.txt          optional: `class_id name` lines (names used in objects.csv)
        <robot>/odometry.tum keyframe poses T_odom_sensor, `stamp tx ty tz qx qy qz qw` (TUM)
        <robot>/objects.csv  header `stamp,x,y,z,class`; one row per object a keyframe saw, in
                             that keyframe's SENSOR frame (metres); `stamp` is one of the
                             keyframe stamps of odometry.tum; class an integer id or a name of
                             classes.txt

The folder name is the robot name. Stamps are seconds (any decimal), or integer nanoseconds
(digits only, >= 1e17: a common ROS export); both kept exactly as int64 nanoseconds
(`sgloc.io.keyframes.parse_stamp`). Quaternions are x-first as in TUM files; a first pose whose
quaternion is `1 0 0 0` (the identity written w-first) is refused as a likely column-order
mistake.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sgloc.errors import DatasetError
from sgloc.io.class_table import read_class_table, resolve_class, write_class_table
from sgloc.io.keyframes import RobotLog, float_text, format_stamp, make_robot_log, parse_stamp
from sgloc.io.poses import read_tum, write_tum
from sgloc.io.text import read_text_file

ODOMETRY_FILE, OBJECTS_FILE, CLASSES_FILE = "odometry.tum", "objects.csv", "classes.txt"
OBJECT_COLUMNS = ("stamp", "x", "y", "z", "class")


def read_plain_layout(
    folder: str | Path, classes: str | Path | None = None
) -> list[RobotLog]:
    """Every robot of a plain layout, sorted by name. `classes`: a class table (default: the
    layout's classes.txt when present)."""
    folder = Path(folder)
    if not folder.is_dir():
        what = "is a file, not a folder" if folder.exists() else "no such folder"
        raise DatasetError(f"{folder}: {what}; give a folder with one folder per robot.")
    if classes is None and (folder / CLASSES_FILE).is_file():
        classes = folder / CLASSES_FILE
    table = read_class_table(classes) if classes is not None else None
    robots = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not robots:
        raise DatasetError(
            f"{folder}: no robot folders; give one folder per robot holding {ODOMETRY_FILE} and "
            f"{OBJECTS_FILE}."
        )
    return [read_robot_folder(p, table) for p in robots]


def read_robot_folder(path: Path, table: dict[str, int] | None = None) -> RobotLog:
    """One robot folder (name = folder name) of the plain layout."""
    if not (path / ODOMETRY_FILE).is_file():
        raise DatasetError(
            f"{path}: no {ODOMETRY_FILE}; every robot folder needs its keyframe poses "
            "(`stamp tx ty tz qx qy qz qw` lines), or move the folder out of the layout."
        )
    if not (path / OBJECTS_FILE).is_file():
        raise DatasetError(
            f"{path}: no {OBJECTS_FILE}; write one (header `stamp,x,y,z,class`; header only if "
            "the robot saw nothing)."
        )
    stamps, xyz, quat = read_tum(path / ODOMETRY_FILE, increasing=True)
    kf, pos, lab = read_objects_csv(path / OBJECTS_FILE, stamps, table)
    return make_robot_log(path.name, stamps, xyz, quat, kf, pos, lab, where=str(path))


def read_objects_csv(
    path: Path, stamps_ns: np.ndarray, table: dict[str, int] | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(keyframe index (M,), positions (M,3), labels (M,)) of an objects.csv."""
    lines = read_text_file(path, "objects table").splitlines()
    rows = [(n, ln) for n, ln in enumerate(lines, 1) if ln.split("#", 1)[0].strip()]
    if not rows:
        raise DatasetError(f"{path}: empty; the first line must be the header stamp,x,y,z,class.")
    header = [h.strip().lower() for h in rows[0][1].split(",")]
    if sorted(header) != sorted(OBJECT_COLUMNS):
        raise DatasetError(
            f"{path}:{rows[0][0]}: header must name the columns stamp,x,y,z,class "
            f"(comma separated), got {rows[0][1].strip()!r}."
        )
    col = [header.index(c) for c in OBJECT_COLUMNS]
    index = {int(s): i for i, s in enumerate(stamps_ns)}
    kf, pos, lab = [], [], []
    for n, line in rows[1:]:
        f = line.split("#", 1)[0].split(",")
        where = f"{path}:{n}"
        if len(f) != len(OBJECT_COLUMNS):
            raise DatasetError(f"{where}: expected 5 comma-separated values, got {len(f)}.")
        try:
            stamp, xyz = parse_stamp(f[col[0]], where), [float(f[c]) for c in col[1:4]]
        except DatasetError:
            raise
        except ValueError:
            raise DatasetError(
                f"{where}: stamp, x, y, z must be numbers: {line.strip()!r}."
            ) from None
        if stamp not in index:
            raise DatasetError(
                f"{where}: stamp {f[col[0]].strip()} is not a keyframe stamp of "
                f"{ODOMETRY_FILE}; give each object the stamp of the keyframe that saw it."
            )
        if not np.all(np.isfinite(xyz)):
            raise DatasetError(f"{where}: NaN or infinite position; fix or drop the row.")
        kf.append(index[stamp])
        pos.append(xyz)
        lab.append(resolve_class(f[col[4]], table, where))
    return np.array(kf, np.int64), np.array(pos, np.float64).reshape(-1, 3), np.array(lab, np.int64)


def write_plain_layout(
    folder: str | Path, logs: Sequence[RobotLog], class_names: Sequence[str] | None = None
) -> Path:
    """Write robots in the plain layout (values written exactly; classes as names when
    `class_names` is given, with a classes.txt, else as integer ids)."""
    folder = Path(folder)
    bad = [g.name for g in logs if g.name != Path(g.name).name or g.name.startswith(".")]
    if bad:
        raise DatasetError(f"robot name {bad[0]!r} cannot be a folder name; rename the robot.")
    folder.mkdir(parents=True, exist_ok=True)
    if class_names is not None:
        write_class_table(folder / CLASSES_FILE, class_names)
    for log in logs:
        d = folder / log.name
        d.mkdir(parents=True, exist_ok=True)
        write_tum(d / ODOMETRY_FILE, log.stamps_ns, log.xyz, log.quat)
        objs = [",".join(OBJECT_COLUMNS)]
        for k, p, c in zip(log.keyframe, log.positions, log.labels, strict=True):
            cls = class_names[c] if class_names is not None else str(int(c))
            objs.append(",".join([format_stamp(log.stamps_ns[k]), *map(float_text, p), cls]))
        (d / OBJECTS_FILE).write_text("".join(f"{r}\n" for r in objs))
    return folder
