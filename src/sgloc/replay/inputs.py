"""What `sgloc replay` reads: a plain layout, a ROS 2 bag / mcap, one source per robot, or a cut
data set.

One source holds every robot: a plain layout folder (a folder per robot) or a bag whose topics
carry the robot names (`/{robot}/odom`). Several sources (or one named `NAME=PATH`) hold one
robot each: a bag of that robot (its topics the templates with `{robot}` filled in, or plain
names such as `/odom`) or a plain-layout robot folder (odometry.tum, objects.csv). Such a robot
is named by NAME, else by the source's stem (`runs/alpha.mcap` -> `alpha`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

from sgloc.errors import DatasetError
from sgloc.io.keyframes import RobotLog

BAG_SUFFIXES = (".mcap", ".db3")
SOURCE_KINDS = "a plain layout folder, a rosbag2 folder or an .mcap/.db3 file"


def is_bag(path: Path) -> bool:
    """True for a rosbag2 folder (metadata.yaml inside) or an .mcap / .db3 file."""
    return (path.is_dir() and (path / "metadata.yaml").is_file()) or (
        path.suffix.lower() in BAG_SUFFIXES
    )


def _class_table(classes: Path | None) -> dict[str, int] | None:
    from sgloc.io.class_table import read_class_table

    return read_class_table(classes) if classes is not None else None


def _exists(path: Path) -> Path:
    if not path.exists():
        raise DatasetError(f"{path}: no such file or folder; give {SOURCE_KINDS}.")
    return path


def _not_a_source(path: Path) -> str:
    """The refusal of a file that is neither a bag nor a folder (e.g. a robot's odometry.tum)."""
    parent = path.parent
    hint = (f" (for one robot, give its folder {parent}; for every robot, the layout folder "
            f"{parent.parent})") if path.name in ("odometry.tum", "objects.csv") else ""
    return f"{path}: is a file, not a source; give {SOURCE_KINDS}{hint}."


def read_logs(
    path: Path,
    classes: Path | None = None,
    odom_topic: str | None = None,
    objects_topic: str | None = None,
) -> list[RobotLog]:
    """The robots of one source: a plain layout folder or a ROS 2 bag (folder, .mcap or .db3).
    A bag read with a plain odometry topic (no `{robot}`), or a plain-layout robot folder, is
    one robot, named by the bag or folder."""
    from sgloc.io.plain_layout import ODOMETRY_FILE, read_plain_layout

    path = _exists(Path(path))
    if not is_bag(path):
        if not path.is_dir():
            raise DatasetError(_not_a_source(path))
        if odom_topic or objects_topic:
            raise DatasetError(f"{path}: not a bag, so --odom-topic/--objects-topic do not apply.")
        if (path / ODOMETRY_FILE).is_file():  # one robot's folder
            return read_robot_sources([(None, path)], classes)
        return read_plain_layout(path, classes)
    from sgloc.io import rosbag

    if odom_topic is not None and "{robot}" not in odom_topic:
        return read_robot_sources([(None, path)], classes, odom_topic, objects_topic)
    return rosbag.read_bag(
        path, odom_topic or rosbag.ODOM_TOPIC, objects_topic or rosbag.OBJECTS_TOPIC,
        _class_table(classes),
    )


def source_name(path: Path) -> str:
    """The robot name of a one-robot source: its file or folder name without the suffix."""
    path = Path(path)
    return path.stem if path.suffix.lower() in BAG_SUFFIXES else path.name


def read_robot_sources(
    sources: Sequence[tuple[str | None, Path]],
    classes: Path | None = None,
    odom_topic: str | None = None,
    objects_topic: str | None = None,
) -> list[RobotLog]:
    """One robot from each (name or None, path) source (a bag or a plain-layout robot folder),
    sorted by name as a bag of all of them reads; an unnamed one is named by `source_name`.
    DatasetError when two robots get one name."""
    table = _class_table(classes)
    named = [(name or source_name(p), Path(p)) for name, p in sources]
    seen: dict[str, Path] = {}
    for name, p in named:
        if name in seen:
            raise DatasetError(
                f"{seen[name]} and {p} both name robot {name!r}; name them with --robot "
                "NAME=PATH."
            )
        seen[name] = p
    logs = [_read_source(name, p, table, odom_topic, objects_topic) for name, p in named]
    return sorted(logs, key=lambda g: g.name)


def _read_source(name, path: Path, table, odom_topic, objects_topic) -> RobotLog:
    from sgloc.io.plain_layout import ODOMETRY_FILE, read_robot_folder

    path = _exists(path)
    if is_bag(path):
        from sgloc.io import rosbag

        return rosbag.read_robot_bag(path, name, odom_topic or rosbag.ODOM_TOPIC,
                                     objects_topic or rosbag.OBJECTS_TOPIC, table)
    if odom_topic or objects_topic:
        raise DatasetError(f"{path}: not a bag, so --odom-topic/--objects-topic do not apply.")
    if not (path / ODOMETRY_FILE).is_file():
        raise DatasetError(
            f"{path}: neither a bag nor a robot folder ({ODOMETRY_FILE}, objects.csv); give one "
            "bag or robot folder per robot, or a single plain layout folder."
        )
    return dataclasses.replace(read_robot_folder(path, table), name=name)
