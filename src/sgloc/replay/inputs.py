"""What `sgloc replay` reads: a plain layout, a ROS 2 bag / mcap, or a cut data set."""

from __future__ import annotations

from pathlib import Path

from sgloc.errors import DatasetError
from sgloc.io.keyframes import RobotLog

BAG_SUFFIXES = (".mcap", ".db3")


def is_bag(path: Path) -> bool:
    """True for a rosbag2 folder (metadata.yaml inside) or an .mcap / .db3 file."""
    return (path.is_dir() and (path / "metadata.yaml").is_file()) or (
        path.suffix.lower() in BAG_SUFFIXES
    )


def read_logs(
    path: Path,
    classes: Path | None = None,
    odom_topic: str | None = None,
    objects_topic: str | None = None,
) -> list[RobotLog]:
    """The robots of a plain layout folder or a ROS 2 bag (folder, .mcap or .db3)."""
    from sgloc.io.class_names import read_class_table
    from sgloc.io.plain_layout import read_plain_layout

    path = Path(path)
    if not path.exists():
        raise DatasetError(
            f"{path}: no such file or folder; give a plain layout folder, a rosbag2 folder or an "
            ".mcap file."
        )
    if not is_bag(path):
        if odom_topic or objects_topic:
            raise DatasetError(f"{path}: not a bag, so --odom-topic/--objects-topic do not apply.")
        return read_plain_layout(path, classes)
    from sgloc.io import rosbag

    table = read_class_table(classes) if classes is not None else None
    return rosbag.read_bag(
        path, odom_topic or rosbag.ODOM_TOPIC, objects_topic or rosbag.OBJECTS_TOPIC, table
    )
