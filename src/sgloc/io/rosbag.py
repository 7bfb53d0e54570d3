"""ROS 2 bags and mcap files through `rosbags` (pure Python; no ROS install needed).

Message layout read and written (one robot = one pair of topics; `{robot}` in a topic template
is the robot name). A bag holds several robots (`read_bag`: every robot whose odometry topic
matches the template), or one robot (`read_robot_bag`: a bag per robot, the robot named by the
caller, its topics the templates with `{robot}` filled in or plain names such as `/odom`):

- `/{robot}/odom`, nav_msgs/msg/Odometry: one message per keyframe. header.stamp = the
  keyframe stamp; pose.pose = T_odom_sensor (the sensor pose in the robot's odometry frame;
  header.frame_id `{robot}/odom`, child_frame_id `{robot}/sensor` when written here).
- `/{robot}/objects`, visualization_msgs/msg/MarkerArray: what keyframes saw, one marker per
  object. marker.header.stamp = the stamp of the keyframe that saw it (an Odometry stamp of the
  same robot); pose.position = the object's position in that keyframe's SENSOR frame (metres);
  `ns` = the class: an integer id, or a name resolved through a class table. Markers whose
  action is not ADD (e.g. DELETEALL) are ignored. A keyframe that saw nothing needs no marker.
- Output: `/fleet/transforms` (default), geometry_msgs/msg/TransformStamped: header.frame_id
  `fleet`, child_frame_id `{robot}/odom`, the transform T_fleet_odom of a placed robot, stamped
  at the keyframe after which it took that value (and once more at the end).
"""

from __future__ import annotations

import contextlib
import functools
import re
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.errors import DatasetError
from sgloc.io.class_table import resolve_class
from sgloc.io.files import staged_folder
from sgloc.io.keyframes import RobotLog, make_robot_log
from sgloc.optional import require

ODOM_TOPIC, OBJECTS_TOPIC, FLEET_TOPIC = "/{robot}/odom", "/{robot}/objects", "/fleet/transforms"
ODOMETRY, MARKERS, TRANSFORM = (
    "nav_msgs/msg/Odometry",
    "visualization_msgs/msg/MarkerArray",
    "geometry_msgs/msg/TransformStamped",
)
FLEET_FRAME = "fleet"


def _rosbags() -> tuple[Any, Any, Any]:
    """(rosbags.rosbag2, rosbags.highlevel, the ROS 2 Humble typestore: built once), or one
    clear error."""
    require("rosbags", "ros", "reading and writing ROS 2 bags")
    return _loaded()


def ros2_typestore() -> Any:
    """The ROS 2 Humble type store bags and live messages are read and written with (built
    once), or one clear error."""
    return _rosbags()[2]


@functools.cache
def _loaded() -> tuple[Any, Any, Any]:
    from rosbags import highlevel, rosbag2
    from rosbags.typesys import Stores, get_typestore

    return rosbag2, highlevel, get_typestore(Stores.ROS2_HUMBLE)


def topic_regex(template: str) -> re.Pattern[str]:
    """A regex matching topics of a `{robot}` template; group `robot` is the robot name."""
    if template.count("{robot}") != 1:
        raise DatasetError(f"topic template {template!r}: must hold `{{robot}}` exactly once.")
    head, tail = template.split("{robot}")
    return re.compile(f"^{re.escape(head)}(?P<robot>.+?){re.escape(tail)}$")


@contextlib.contextmanager
def _open_bag(path: Path) -> Iterator[Any]:
    """A rosbags reader of the bag at `path`; DatasetError naming the bag when it is missing or
    cannot be read (also for read errors inside the block)."""
    _, highlevel, typestore = _rosbags()
    if not path.exists():
        raise DatasetError(f"{path}: no such bag; give a rosbag2 folder, .db3 or .mcap file.")
    try:
        with highlevel.AnyReader([path], default_typestore=typestore) as reader:
            yield reader
    except (highlevel.AnyReaderError, OSError, KeyError, AssertionError) as e:
        raise DatasetError(f"{path}: cannot read the bag ({e}).") from None


def read_bag(
    path: str | Path,
    odom_topic: str = ODOM_TOPIC,
    objects_topic: str = OBJECTS_TOPIC,
    classes: dict[str, int] | None = None,
    robots: Sequence[str] | None = None,
) -> list[RobotLog]:
    """Every robot of a ROS 2 bag (folder, .db3 or .mcap) in the layout above, sorted by name;
    `robots` selects some. DatasetError naming the bag, topic and fix on any mismatch."""
    path = Path(path)
    with _open_bag(path) as reader:
        return _read_robots(reader, path, odom_topic, objects_topic, classes, robots)


def _read_robots(reader, path, odom_topic, objects_topic, classes, robots) -> list[RobotLog]:
    pattern = topic_regex(odom_topic)
    found = {}
    for c in reader.connections:
        m = pattern.match(c.topic)
        if m and c.msgtype == ODOMETRY:
            found.setdefault(m["robot"], []).append(c)
    names = sorted(found) if robots is None else list(robots)
    missing = [r for r in names if r not in found]
    if not names or missing:
        raise DatasetError(
            f"{path}: no {ODOMETRY} topic matching {odom_topic!r} for robot(s) "
            f"{', '.join(missing) or 'any'} (topics in the bag: {_bag_topics(reader)}); set the "
            "topic template with --odom-topic."
        )
    return [
        _read_robot(reader, path, r, found[r], _topic(reader, path, r, objects_topic, MARKERS),
                    classes)
        for r in names
    ]


def _bag_topics(reader, shown: int = 30) -> str:
    """The bag's topics with their types (the first `shown`), for error messages."""
    topics = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
    more = f", and {len(topics) - shown} more" if len(topics) > shown else ""
    return ", ".join(topics[:shown]) + more if topics else "none"


def _topic(reader, path: Path, robot: str, template: str, msgtype: str) -> list:
    """The connections of robot `robot`'s topic `template` ({robot} filled in) of type
    `msgtype`; DatasetError listing the bag's topics when there is none."""
    topic = template.replace("{robot}", robot)
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns or any(c.msgtype != msgtype for c in conns):
        option = "--odom-topic" if msgtype == ODOMETRY else "--objects-topic"
        raise DatasetError(
            f"{path}: robot {robot!r} has no {msgtype} topic {topic!r} (topics in the bag: "
            f"{_bag_topics(reader)}); name the topic with {option}."
        )
    return conns


def read_robot_bag(
    path: str | Path,
    robot: str,
    odom_topic: str = ODOM_TOPIC,
    objects_topic: str = OBJECTS_TOPIC,
    classes: dict[str, int] | None = None,
) -> RobotLog:
    """One robot, `robot`, from a bag of its own (folder, .db3 or .mcap): its odometry and
    object topics are the templates with `{robot}` filled in, or the plain topic names given
    (`/odom`). DatasetError naming the bag, the topic, the bag's topics and the fix."""
    path = Path(path)
    with _open_bag(path) as reader:
        odom = _topic(reader, path, robot, odom_topic, ODOMETRY)
        objects = _topic(reader, path, robot, objects_topic, MARKERS)
        return _read_robot(reader, path, robot, odom, objects, classes)


def _read_robot(reader, path, name, odom_conns, obj_conns, classes) -> RobotLog:
    def messages(conns):
        return (reader.deserialize(raw, c.msgtype)
                for c, _, raw in reader.messages(connections=conns))

    return messages_to_log(name, messages(odom_conns), messages(obj_conns), classes,
                           f"{path}: {obj_conns[0].topic}", f"{path}: robot {name!r}")


def messages_to_log(name: str, odometry: Iterable[Any], marker_arrays: Iterable[Any],
                    classes: dict[str, int] | None = None, where: str = "",
                    log_where: str = "", live: bool = False) -> RobotLog:
    """Robot `name`'s keyframes from its nav_msgs/Odometry and visualization_msgs/MarkerArray
    messages (the layout above; `odometry` is read to its end first). From a bag (`live`
    False) every odometry message is a keyframe and each ADD marker carries the stamp of one.
    Live, the keyframes are the marker stamps of each MarkerArray (of its ADD markers and of
    any other marker stamped after 0: a DELETEALL marker alone is a keyframe that saw nothing),
    each at the pose of the robot's latest odometry at or before it. DatasetError naming
    `where` (the object topic) and the message on any mismatch, `log_where` on a bad pose."""
    odo = [odometry_pose(m) for m in odometry]
    ns = np.array([o[0] for o in odo], np.int64)
    order = np.argsort(ns, kind="stable")  # messages come by log time, not header stamp
    ns = ns[order]
    xyz = np.array([o[1] for o in odo], np.float64).reshape(-1, 3)[order]
    quat = np.array([o[2] for o in odo], np.float64).reshape(-1, 4)[order]
    frames, kf, pos, lab = [], [], [], []
    for n, m in enumerate(marker_arrays, 1):
        at = f"{where} message {n}"
        s, p, c = marker_objects(m, classes, at)
        if live:  # this message's keyframes, at the latest odometry at or before each
            others = [t for t in (_ns(mk.header.stamp) for mk in m.markers) if t > 0]
            key = np.unique(np.concatenate([s, np.array(others, np.int64)]))
            k = pair_objects(ns, key, name, at, exact=False)
            kf.append(pair_objects(key, s, name, at) + sum(len(f[0]) for f in frames))
            frames.append((key, xyz[k], quat[k]))
        else:
            kf.append(pair_objects(ns, s, name, at))
        pos.append(p)
        lab.append(c)
    if live:
        ns, xyz, quat = (np.concatenate([f[i] for f in frames]) if frames else
                         np.zeros((0,) + shape) for i, shape in enumerate([(), (3,), (4,)]))
    return make_robot_log(
        name, ns, xyz, quat,
        np.concatenate(kf) if kf else np.zeros(0, np.int64),
        np.concatenate(pos) if pos else np.zeros((0, 3)),
        np.concatenate(lab) if lab else np.zeros(0, np.int64),
        where=log_where or f"robot {name!r}",
    )


def odometry_pose(msg: Any) -> tuple[int, tuple[float, ...], tuple[float, ...]]:
    """(header stamp ns, position (x, y, z), orientation (x, y, z, w)) of a nav_msgs/Odometry:
    one keyframe's T_odom_sensor (bags and live ROS 2 robots)."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return _ns(msg.header.stamp), (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)


def marker_objects(msg: Any, classes: dict[str, int] | None, where: str
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stamps ns (n,), positions (n,3) sensor frame, class ids (n,)) of the ADD markers of a
    visualization_msgs/MarkerArray (bags and live ROS 2 robots); `where` names the message in
    errors (a class name not in `classes`)."""
    marks = [mk for mk in msg.markers if mk.action == 0]
    stamps = np.array([_ns(mk.header.stamp) for mk in marks], np.int64)
    pos = np.array([(mk.pose.position.x, mk.pose.position.y, mk.pose.position.z)
                    for mk in marks], np.float64).reshape(-1, 3)
    lab = np.array([resolve_class(mk.ns, classes, f"{where} marker {mk.id}") for mk in marks],
                   np.int64)
    return stamps, pos, lab


def pair_objects(odom_ns: np.ndarray, stamps: np.ndarray, robot: str, where: str,
                 exact: bool = True) -> np.ndarray:
    """The keyframe (index into the sorted odometry stamps `odom_ns`) of each object stamp:
    the odometry at that stamp, or with `exact` False the latest one at or before it.
    DatasetError naming `where` for an object with none."""
    k = np.searchsorted(odom_ns, stamps, side="right") - 1
    bad = k < 0
    if exact:
        bad |= odom_ns[np.maximum(k, 0)] != stamps if len(odom_ns) else True
    if np.any(bad):
        s = int(np.asarray(stamps)[np.argmax(bad)])
        rule = "at" if exact else "at or before"
        raise DatasetError(
            f"{where}: object stamp {s} ns has no {ODOMETRY} stamp of robot {robot!r} {rule} "
            "it; stamp each marker with the keyframe that saw it."
        )
    return k


def _ns(stamp: Any) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _stamp(ts, ns: int) -> Any:
    return ts.types["builtin_interfaces/msg/Time"](sec=int(ns) // 1_000_000_000,
                                                   nanosec=int(ns) % 1_000_000_000)


def ros_header(ts, ns: int, frame: str) -> Any:
    """A std_msgs/Header of the type store `ts`: stamp `ns` nanoseconds, frame `frame`."""
    return ts.types["std_msgs/msg/Header"](stamp=_stamp(ts, ns), frame_id=frame)


def _odometry(ts, name: str, ns: int, xyz: np.ndarray, quat: np.ndarray) -> Any:
    t = ts.types
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](*map(float, xyz)),
        orientation=t["geometry_msgs/msg/Quaternion"](*map(float, quat)),
    )
    zero3 = t["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0)
    return t[ODOMETRY](
        header=ros_header(ts, ns, f"{name}/odom"),
        child_frame_id=f"{name}/sensor",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=zero3, angular=zero3),
            covariance=np.zeros(36),
        ),
    )


def _marker(ts, name: str, ns: int, k: int, p: np.ndarray, cls: str, action: int = 0) -> Any:
    t = ts.types
    M = t["visualization_msgs/msg/Marker"]
    return M(
        header=ros_header(ts, ns, f"{name}/sensor"), ns=cls, id=k, type=M.SPHERE, action=action,
        pose=t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](*map(float, p)),
            orientation=t["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
        ),
        scale=t["geometry_msgs/msg/Vector3"](0.5, 0.5, 0.5),
        color=t["std_msgs/msg/ColorRGBA"](1.0, 0.5, 0.0, 1.0),
        lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
        frame_locked=False, points=[], colors=[], texture_resource="",
        texture=t["sensor_msgs/msg/CompressedImage"](
            header=ros_header(ts, 0, ""), format="", data=np.zeros(0, np.uint8)
        ),
        uv_coordinates=[], text="", mesh_resource="",
        mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
        mesh_use_embedded_materials=False,
    )


def robot_messages(log: RobotLog, class_names: Sequence[str] | None = None,
                   mark_empty: bool = False) -> Iterator[tuple[int, Any, Any | None]]:
    """(stamp ns, nav_msgs/Odometry, visualization_msgs/MarkerArray) of each keyframe of `log`
    in the layout above (classes as names when `class_names` is given, else integer ids). A
    keyframe that saw nothing has no MarkerArray (None), or with `mark_empty` one holding a
    single DELETEALL marker at its stamp (how a live ROS 2 robot says so)."""
    _, _, ts = _rosbags()
    for i, p, lab in log.observations():
        ns = int(log.stamps_ns[i])
        odom = _odometry(ts, log.name, ns, log.xyz[i], log.quat[i])
        cls = [class_names[c] if class_names else str(int(c)) for c in lab]
        marks = [_marker(ts, log.name, ns, k, q, c) for k, (q, c) in
                 enumerate(zip(p, cls, strict=True))]
        if not marks and mark_empty:
            marks = [_marker(ts, log.name, ns, 0, np.zeros(3), "", action=3)]
        yield ns, odom, ts.types[MARKERS](markers=marks) if marks else None


def _open_writer(rosbag2, path: Path) -> Any:
    if path.exists():
        raise DatasetError(f"{path}: exists already; give a new path for the output bag.")
    return rosbag2.Writer(path, version=9, storage_plugin=rosbag2.StoragePlugin.MCAP)


def write_bag(
    path: str | Path,
    logs: Sequence[RobotLog],
    class_names: Sequence[str] | None = None,
    odom_topic: str = ODOM_TOPIC,
    objects_topic: str = OBJECTS_TOPIC,
) -> Path:
    """Write robots as a ROS 2 bag folder (mcap storage) in the layout above; classes as names
    when `class_names` is given, else as integer ids. `path` must not exist."""
    rosbag2, _, ts = _rosbags()
    path = Path(path)
    with _open_writer(rosbag2, path) as w:
        for log in logs:
            odom = w.add_connection(odom_topic.replace("{robot}", log.name), ODOMETRY, typestore=ts)
            objs = w.add_connection(
                objects_topic.replace("{robot}", log.name), MARKERS, typestore=ts
            )
            for ns, odometry, markers in robot_messages(log, class_names):
                w.write(odom, ns, ts.serialize_cdr(odometry, ODOMETRY))
                if markers is not None:
                    w.write(objs, ns, ts.serialize_cdr(markers, MARKERS))
    return path


def write_fleet_bag(
    path: str | Path,
    transforms: Sequence[tuple[int, str, np.ndarray]],
    topic: str = FLEET_TOPIC,
) -> Path:
    """Write (stamp ns, robot, T_fleet_odom (4,4)) as geometry_msgs/TransformStamped on `topic`
    (frame `fleet` -> `{robot}/odom`) into a ROS 2 bag folder (mcap storage), by stamp: a new
    path, an empty folder or an earlier bag of sgloc (`sgloc.io.files.staged_folder`); of several
    transforms of one robot at one stamp only the last given is written."""
    rosbag2, _, ts = _rosbags()
    path = Path(path)
    with staged_folder(path, option="--out-bag") as stage:  # a whole bag or none
        # The bag writer makes its folder itself and names its storage file after that folder:
        # written as `stage/<name>`, then moved up, the bag's files carry the final name.
        inner = Path(stage) / path.name
        _write_transforms(rosbag2, ts, inner, transforms, topic)
        for f in inner.iterdir():
            f.rename(Path(stage) / f.name)
        inner.rmdir()
    return path


def _write_transforms(rosbag2, ts, path: Path, transforms, topic: str) -> None:
    from scipy.spatial.transform import Rotation

    t = ts.types
    latest = {}  # one message per child frame and stamp: the last one given wins
    for ns, robot, T in transforms:
        latest[(int(ns), robot)] = T
    with _open_writer(rosbag2, path) as w:
        conn = w.add_connection(topic, TRANSFORM, typestore=ts)
        for (ns, robot), T in sorted(latest.items(), key=lambda x: x[0]):
            q = Rotation.from_matrix(np.asarray(T)[:3, :3]).as_quat()
            msg = t[TRANSFORM](
                header=ros_header(ts, ns, FLEET_FRAME),
                child_frame_id=f"{robot}/odom",
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](*map(float, T[:3, 3])),
                    rotation=t["geometry_msgs/msg/Quaternion"](*map(float, q)),
                ),
            )
            w.write(conn, int(ns), ts.serialize_cdr(msg, TRANSFORM))


def read_fleet_bag(path: str | Path, topic: str = FLEET_TOPIC) -> list[tuple[int, str, np.ndarray]]:
    """The (stamp ns, robot, T_fleet_odom) messages of a bag written by write_fleet_bag."""
    from scipy.spatial.transform import Rotation

    _, highlevel, typestore = _rosbags()
    out = []
    with highlevel.AnyReader([Path(path)], default_typestore=typestore) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        for conn, _, raw in reader.messages(connections=conns):
            m = reader.deserialize(raw, conn.msgtype)
            tr, r = m.transform.translation, m.transform.rotation
            T = np.eye(4)
            T[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
            T[:3, 3] = (tr.x, tr.y, tr.z)
            robot = m.child_frame_id.removesuffix("/odom")
            out.append((m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, robot, T))
    return out
