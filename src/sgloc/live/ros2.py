"""ROS 2 robots on a live server without a ROS install: CDR messages over Zenoh (the types of
`sgloc.io.rosbag`, through `rosbags`, extra `sgloc[live]` or `sgloc[ros]`; docs/live_ros2.md).

In: each robot's nav_msgs/Odometry and visualization_msgs/MarkerArray, on rmw_zenoh's key
expressions `<domain>/<topic>/<dds type>/<type hash>` (any hash) or zenoh-bridge-ros2dds's
`<topic>` (topics without the leading slash; the templates of `sgloc.io.rosbag`). Each
MarkerArray is turned into keyframes by the bag reader's conversion (`messages_to_log`, live:
at the latest odometry at or before the markers' stamp).
Out, on rmw_zenoh's keys with its attachment (sequence number, source timestamp, source gid)
and liveliness tokens (so `ros2 topic list` shows them): tf2_msgs/TFMessage on /tf
(map -> each placed robot's odometry frame), nav_msgs/Path per robot (its keyframes corrected)
and the merged fleet map as visualization_msgs/MarkerArray, at bounded rates.
"""

from __future__ import annotations

import importlib.util
import itertools
import os
import re
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from sgloc.errors import SglocError
from sgloc.io.rosbag import (
    MARKERS,
    OBJECTS_TOPIC,
    ODOM_TOPIC,
    ODOMETRY,
    messages_to_log,
    odometry_pose,
    ros_header,
    topic_regex,
)
from sgloc.live.client import wait_for_correction
from sgloc.live.messages import MessageError
from sgloc.live.transport import check_robot, zenoh
from sgloc.optional import require

TF, PATH = "tf2_msgs/msg/TFMessage", "nav_msgs/msg/Path"
TF_TOPIC, PATH_TOPIC, MAP_TOPIC = "/tf", "/{robot}/fleet_path", "/fleet/map"
MAP_FRAME = "map"
#: Odometry messages kept per robot to pair markers with (the latest at or before their stamp).
ODOM_HISTORY = 512
_NODE = "sgloc_server"


class UnpairedError(MessageError):
    """Markers with no odometry of their robot at or before their stamp."""


@dataclass(frozen=True)
class Ros2Options:
    """ROS 2 on a server: `domain` (ROS_DOMAIN_ID) of rmw_zenoh's keys, the robots' topic
    templates (`{robot}`), seconds between /tf messages, between a robot's Path messages and
    between fleet maps at most; `classes` resolves class names in marker namespaces."""

    domain: int = 0
    odom_topic: str = ODOM_TOPIC
    objects_topic: str = OBJECTS_TOPIC
    tf_every: float = 0.1
    path_every: float = 0.5
    map_every: float = 1.0
    classes: dict[str, int] | None = None


def available() -> bool:
    """Whether the ROS 2 message types (`rosbags`) are installed."""
    return importlib.util.find_spec("rosbags") is not None


def typestore() -> Any:
    """The ROS 2 type store of `sgloc.io.rosbag` (built once), or one error naming the
    extra."""
    require("rosbags", "live", "ROS 2 messages on the live server")
    from sgloc.io.rosbag import ros2_typestore

    return ros2_typestore()


def dds_type(msgtype: str) -> str:
    """rmw_zenoh's type chunk: nav_msgs/msg/Odometry -> nav_msgs::msg::dds_::Odometry_."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def topic_key(domain: int, topic: str, msgtype: str) -> str:
    """rmw_zenoh's key expression of `topic` (ROS name, /tf) carrying `msgtype`."""
    return f"{domain}/{topic.strip('/')}/{dds_type(msgtype)}/{typestore().hash_rihs01(msgtype)}"


def attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's attachment (zenoh-ext serialisation): sequence number and source timestamp
    (int64 little-endian), the source gid (16 bytes, after their LEB128 count)."""
    return struct.pack("<qqB", int(seq), int(stamp_ns), len(gid)) + bytes(gid)


def _qos(depth: int) -> str:
    """rmw_zenoh's QoS chunk of a liveliness token: reliable, volatile, keep last `depth`
    (empty fields: rmw_zenoh's defaults)."""
    return f"::,{int(depth)}:,:,:,,"


class Node:
    """A ROS 2 node as rmw_zenoh announces it, on an open zenoh session: `publisher`s that put
    CDR with the attachment; liveliness tokens for the node and each publisher."""

    _ids = itertools.count(1)

    def __init__(self, session: Any, domain: int, name: str) -> None:
        self.session, self.domain, self.name = session, int(domain), name
        self._zid = str(session.zid())
        self._nid = next(Node._ids)
        self._tokens = [self._token(f"{self._nid}/NN/%/%/{name}")]
        self._pubs: dict[tuple[str, str], _Publisher] = {}

    def _token(self, tail: str) -> Any:
        return self.session.liveliness().declare_token(
            f"@ros2_lv/{self.domain}/{self._zid}/{self._nid}/{tail}")

    def publisher(self, topic: str, msgtype: str, depth: int = 10) -> _Publisher:
        """The publisher of `topic` (declared on first use)."""
        if (topic, msgtype) not in self._pubs:
            key = topic_key(self.domain, topic, msgtype)
            eid = next(Node._ids)
            mangled = "%" + topic.strip("/").replace("/", "%")
            self._tokens.append(self._token(
                f"{eid}/MP/%/%/{self.name}/{mangled}/{key.split('/')[-2]}/{key.split('/')[-1]}/"
                f"{_qos(depth)}"))
            self._pubs[(topic, msgtype)] = _Publisher(self.session, key, msgtype)
        return self._pubs[(topic, msgtype)]

    def close(self) -> None:
        for t in self._tokens:
            t.undeclare()
        for p in self._pubs.values():
            p.pub.undeclare()
        self._tokens, self._pubs = [], {}


class _Publisher:
    def __init__(self, session: Any, key: str, msgtype: str) -> None:
        self.key, self.msgtype, self.seq = key, msgtype, 0
        self.gid = os.urandom(16)
        z = zenoh()  # not for the server's own ROS 2 subscriptions (they would always match)
        self.pub = session.declare_publisher(key, congestion_control=z.CongestionControl.BLOCK,
                                             allowed_destination=z.Locality.REMOTE)

    def matched(self) -> bool:
        """Whether any subscriber listens (messages are built only for someone)."""
        return bool(self.pub.matching_status.matching)

    def put(self, msg: Any) -> None:
        self.seq += 1
        self.pub.put(bytes(typestore().serialize_cdr(msg, self.msgtype)),
                     attachment=attachment(self.seq, time.time_ns(), self.gid))


def subscription_keys(domain: int, odom_topic: str, objects_topic: str) -> tuple[str, str]:
    """(rmw_zenoh's, zenoh-bridge-ros2dds's) key expression covering both robot topics: one
    subscriber each, so that a robot's odometry and markers keep their order."""
    def chunks(template: str, msgtype: str | None) -> list[str]:
        out = ["*" if "{robot}" in c else c for c in template.strip("/").split("/")]
        return [str(domain), *out, dds_type(msgtype), "*"] if msgtype else out

    def common(a: list[str], b: list[str]) -> str:
        if len(a) != len(b):
            n = next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y),
                     min(len(a), len(b)))
            return "/".join([*a[:n], "**"])
        return "/".join(x if x == y else "*" for x, y in zip(a, b, strict=True))

    return (common(chunks(odom_topic, ODOMETRY), chunks(objects_topic, MARKERS)),
            common(chunks(odom_topic, None), chunks(objects_topic, None)))


class Topics:
    """Which robot and message a key expression of either naming carries."""

    def __init__(self, options: Ros2Options) -> None:
        self.domain = str(options.domain)
        self._kinds = [(topic_regex(t.strip("/")), kind, msgtype) for t, kind, msgtype in (
            (options.odom_topic, "odom", ODOMETRY), (options.objects_topic, "objects", MARKERS))]
        self._dds = re.compile(r"^[A-Za-z0-9_]+::[a-z]+::dds_::[A-Za-z0-9_]+_$")

    def parse(self, key: str) -> tuple[str, str, bool] | None:
        """(robot, "odom" or "objects", whether the key's type is right) of a key; None for a
        key of neither topic."""
        parts = key.split("/")
        rmw = len(parts) >= 4 and parts[0] == self.domain and self._dds.match(parts[-2])
        topic = "/".join(parts[1:-2]) if rmw else key
        for pattern, kind, msgtype in self._kinds:
            m = pattern.match(topic)
            if m:
                return m["robot"], kind, not rmw or parts[-2] == dds_type(msgtype)
        return None


class Decoder:
    """A robot's CDR messages to keyframes (`feed`), keeping its latest odometry messages."""

    def __init__(self, classes: dict[str, int] | None = None, history: int = ODOM_HISTORY):
        self.classes, self.history = classes, history
        self._odom: dict[str, deque] = {}
        self.frames: dict[str, str] = {}  # robot -> the frame_id of its odometry

    def feed(self, robot: str, kind: str, data: bytes) -> tuple[int, list[tuple]]:
        """(the message's stamp ns, its keyframes [(stamp ns, T_odom_sensor, positions,
        labels)]): none for odometry. MessageError for a payload that is not a valid CDR
        message of its topic's type, UnpairedError for markers with no odometry before them."""
        msgtype = ODOMETRY if kind == "odom" else MARKERS
        try:
            m = typestore().deserialize_cdr(bytes(data), msgtype)
        except Exception as e:  # rosbags raises many kinds (struct, index, unicode, value)
            raise MessageError(f"not a CDR {msgtype} ({type(e).__name__}: {e})"[:200]) from None
        if kind == "odom":
            stamp, xyz, quat = odometry_pose(m)
            if not (np.isfinite(xyz).all() and np.isfinite(quat).all()) or stamp < 0:
                raise MessageError(f"{msgtype}: a negative stamp or a non-finite pose.")
            self._odom.setdefault(robot, deque(maxlen=self.history)).append(m)
            self.frames[robot] = m.header.frame_id or f"{robot}/odom"
            return stamp, []
        try:
            log = messages_to_log(robot, self._odom.get(robot, ()), [m], self.classes,
                                  f"robot {robot!r}: {msgtype}", live=True)
        except SglocError as e:
            err = UnpairedError if "at or before" in str(e) else MessageError
            raise err(str(e)) from None
        poses = log.poses
        frames = [(int(log.stamps_ns[i]), poses[i], p, c) for i, p, c in log.observations()]
        return frames[-1][0], frames


class Ros2Bridge:
    """A server's ROS 2 side on its zenoh session: `subscribe(put)` hands each robot message
    (robot, kind, payload) to `put` (a bad key: robot ""); `decode` turns one into keyframes;
    `publish(session)` sends /tf, paths and the fleet map when due."""

    def __init__(self, zsession: Any, options: Ros2Options) -> None:
        typestore()  # the error naming the extra now, not on the first message
        self.options = o = options
        self.topics, self.decoder = Topics(o), Decoder(o.classes)
        self.node = Node(zsession, o.domain, _NODE)
        self._zenoh, self._subs = zsession, []
        self._clock = (None, 0.0)  # (latest stamp ns seen, time.monotonic() then)
        self._tf_at = self._map_at = -np.inf
        self._path_at: dict[str, float] = {}
        self._shown: dict[str, tuple] = {}  # robot -> (keyframes, revision) of its last Path
        self._map_rev = -1

    def subscribe(self, put: Callable[[str, str, bytes], None]) -> None:
        def receive(sample) -> None:
            got = self.topics.parse(str(sample.key_expr))
            if got is None:
                return
            robot, kind, typed = got
            try:
                check_robot(robot)
            except SglocError:
                robot = ""
            put(robot, kind if typed else "bad_type", sample.payload.to_bytes())

        origin = zenoh().Locality.REMOTE  # not the server's own outputs
        for k in subscription_keys(self.options.domain, self.options.odom_topic,
                                   self.options.objects_topic):
            self._subs.append(self._zenoh.declare_subscriber(k, receive, allowed_origin=origin))

    def decode(self, robot: str, kind: str, data: bytes) -> list[tuple]:
        """The keyframes of one message (see `Decoder.feed`), noting its stamp for the clock."""
        if kind == "bad_type":
            raise MessageError("a message of another type than its topic's.")
        stamp, frames = self.decoder.feed(robot, kind, data)
        self.note(stamp)
        return frames

    def note(self, stamp_ns: int) -> None:
        """A robot's stamp: output stamps follow the robots' clock (wall or simulated)."""
        if self._clock[0] is None or stamp_ns > self.now():
            self._clock = (int(stamp_ns), time.monotonic())

    def now(self) -> int:
        """The robots' clock now (ns): their latest stamp plus the time since; wall time
        before any."""
        last, at = self._clock
        return time.time_ns() if last is None else last + int((time.monotonic() - at) * 1e9)

    def publish(self, session: Any, stamps: dict[str, int], force: bool = False) -> None:
        """/tf every `tf_every` s, a robot's Path when it changed (a new keyframe: `stamps`,
        robot -> its latest keyframe's; or a new revision) at most every `path_every` s, the
        fleet map when it changed at most every `map_every` s; all at once with `force`."""
        t, o = time.monotonic(), self.options
        if force or t - self._tf_at >= o.tf_every:
            self._tf_at = t
            self._publish_tf(session)
        for r in session.robots:
            state = (stamps.get(r), session.revision)
            if self._shown.get(r) != state and (force or t - self._path_at.get(r, -np.inf)
                                                >= o.path_every):
                self._shown[r], self._path_at[r] = state, t
                pub = self.node.publisher(PATH_TOPIC.replace("{robot}", r), PATH)
                if pub.matched():
                    pub.put(path_message(session, r, self.odom_frame(r)))
        if session.revision != self._map_rev and (force or t - self._map_at >= o.map_every):
            pub = self.node.publisher(MAP_TOPIC, MARKERS)
            if pub.matched():
                self._map_rev, self._map_at = session.revision, t
                pub.put(map_message(session, self.now()))

    def odom_frame(self, robot: str) -> str:
        return self.decoder.frames.get(robot, f"{robot}/odom")

    def _publish_tf(self, session: Any) -> None:
        placed = session.corrections()
        pub = self.node.publisher(TF_TOPIC, TF, depth=100)
        if placed and pub.matched():
            frames = {r: self.odom_frame(r) for r in placed}
            pub.put(tf_message(placed, frames, self.now()))

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self.node.close()


def _header(ns: int, frame: str) -> Any:
    return ros_header(typestore(), ns, frame)


def _quat(R: np.ndarray) -> Any:
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(R)[:3, :3]).as_quat()
    return typestore().types["geometry_msgs/msg/Quaternion"](*map(float, q))


def tf_message(transforms: dict[str, np.ndarray], frames: dict[str, str], stamp_ns: int) -> Any:
    """tf2_msgs/TFMessage: map -> frames[robot] = T_map_odom of each robot, at `stamp_ns`."""
    t = typestore().types
    return t[TF](transforms=[t["geometry_msgs/msg/TransformStamped"](
        header=_header(stamp_ns, MAP_FRAME), child_frame_id=frames[r],
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](*map(float, T[:3, 3])), rotation=_quat(T)))
        for r, T in transforms.items()])


def path_message(session: Any, robot: str, odom_frame: str) -> Any:
    """nav_msgs/Path of `robot`'s keyframes: in the map frame once placed, before that in its
    odometry frame; stamped with its latest keyframe."""
    t = typestore().types
    stamps, poses = session.keyframes(robot)
    T = session.T_fleet_robot(robot)
    frame = MAP_FRAME if T is not None else odom_frame
    if T is not None:
        poses = T @ poses
    ns = np.round(np.asarray(stamps) * 1e9).astype(np.int64)
    return t[PATH](header=_header(int(ns[-1]) if len(ns) else 0, frame), poses=[
        t["geometry_msgs/msg/PoseStamped"](header=_header(int(s), frame), pose=t[
            "geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](*map(float, P[:3, 3])),
                                      orientation=_quat(P)))
        for s, P in zip(ns, poses, strict=True)])


def map_message(session: Any, stamp_ns: int) -> Any:
    """visualization_msgs/MarkerArray of the merged fleet map (`sgloc replay`'s merged.json)
    in the map frame: a DELETEALL, then one SPHERE_LIST marker per class (ns "fleet", id the
    class id)."""
    from sgloc.replay.outputs import fleet_maps, merged_map

    t = typestore().types
    merged = merged_map(fleet_maps(session, session.robots), session.online.fuse_radius)
    M = t["visualization_msgs/msg/Marker"]
    marks = [_sphere_list(stamp_ns, 0, np.zeros((0, 3)), M.DELETEALL)]
    for c in np.unique(merged.labels):
        marks.append(_sphere_list(stamp_ns, int(c), merged.positions[merged.labels == c], M.ADD))
    return t[MARKERS](markers=marks)


def _sphere_list(stamp_ns: int, cls: int, points: np.ndarray, action: int) -> Any:
    from matplotlib.colors import hsv_to_rgb

    t = typestore().types
    M, P = t["visualization_msgs/msg/Marker"], t["geometry_msgs/msg/Point"]
    r, g, b = map(float, hsv_to_rgb([(cls * 0.618034) % 1.0, 0.8, 0.9]))  # a hue per class
    return M(header=_header(stamp_ns, MAP_FRAME), ns="fleet", id=cls, type=M.SPHERE_LIST,
             action=action, pose=t["geometry_msgs/msg/Pose"](
                 position=P(0.0, 0.0, 0.0),
                 orientation=t["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0)),
             scale=t["geometry_msgs/msg/Vector3"](0.6, 0.6, 0.6),
             color=t["std_msgs/msg/ColorRGBA"](r, g, b, 1.0),
             lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
             frame_locked=False, points=[P(*map(float, p)) for p in points], colors=[],
             texture_resource="", texture=t["sensor_msgs/msg/CompressedImage"](
                 header=_header(0, ""), format="", data=np.zeros(0, np.uint8)),
             uv_coordinates=[], text="", mesh_resource="",
             mesh_file=t["visualization_msgs/msg/MeshFile"](filename="",
                                                           data=np.zeros(0, np.uint8)),
             mesh_use_embedded_materials=False)


class Ros2Client:
    """A recorded robot played as a ROS 2 robot with rmw_zenoh would (`sgloc stream --as
    ros2`): each keyframe's Odometry then MarkerArray (`sgloc.io.rosbag.robot_messages`; a
    DELETEALL marker when it saw nothing) on rmw_zenoh's keys. Its correction comes back from
    the server's /tf (map -> `<robot>/odom`); its Path says which keyframes the server holds.
    The surface of `sgloc.live.client.RobotClient` that `sgloc.live.stream` uses."""

    def __init__(self, log: Any, connect: str, domain: int = 0, odom_topic: str = ODOM_TOPIC,
                 objects_topic: str = OBJECTS_TOPIC,
                 on_correction: Callable[[Any], None] | None = None,
                 zenoh_config: Any = None) -> None:
        import threading

        from sgloc.io.rosbag import robot_messages
        from sgloc.live.transport import open_session

        self.robot = check_robot(log.name)
        self.seq, self.correction = 0, None
        self._messages = list(robot_messages(log, mark_empty=True))
        self._stamps: list[int] = []  # stamp of each keyframe sent, by seq - 1
        self._T, self._held = None, -1
        self._changed, self._callback = threading.Condition(), on_correction
        self._session = open_session("client", connect=connect, config_file=zenoh_config)
        self.node = Node(self._session, domain, f"{self.robot}_player")
        self._odom = self.node.publisher(odom_topic.replace("{robot}", self.robot), ODOMETRY)
        self._objects = self.node.publisher(objects_topic.replace("{robot}", self.robot),
                                            MARKERS)
        self._subs = [
            self._session.declare_subscriber(topic_key(domain, TF_TOPIC, TF), self._tf),
            self._session.declare_subscriber(topic_key(
                domain, PATH_TOPIC.replace("{robot}", self.robot), PATH), self._path)]

    def send(self, k: int) -> int:
        """Publish keyframe `k` of the log (its odometry, then its markers); its seq."""
        ns, odometry, markers = self._messages[k]
        self._odom.put(odometry)
        self._objects.put(markers)
        self.seq += 1
        self._stamps.append(ns)
        return self.seq

    def _tf(self, sample) -> None:
        try:
            m = typestore().deserialize_cdr(sample.payload.to_bytes(), TF)
        except Exception:  # another publisher's bad /tf message: not this robot's
            return
        for t in m.transforms:
            if t.child_frame_id == f"{self.robot}/odom":
                from scipy.spatial.transform import Rotation

                tr, q = t.transform.translation, t.transform.rotation
                T = np.eye(4)
                T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
                T[:3, 3] = (tr.x, tr.y, tr.z)
                self._update(T=T)

    def _path(self, sample) -> None:
        try:
            m = typestore().deserialize_cdr(sample.payload.to_bytes(), PATH)
        except Exception:  # not the server's
            return
        self._update(held=m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec)

    def _update(self, T: np.ndarray | None = None, held: int | None = None) -> None:
        from sgloc.live.messages import Correction

        with self._changed:
            self._T = T if T is not None else self._T
            self._held = held if held is not None else self._held
            seq = int(np.searchsorted(self._stamps, self._held, side="right"))
            placed = self._T is not None
            self.correction = c = Correction(seq, self._held, 0, placed,
                                             self._T if placed else np.eye(4))
            self._changed.notify_all()
        if self._callback is not None:
            self._callback(c)

    def wait_correction(self, seq: int | None = None, timeout: float = 5.0) -> Any:
        """The latest correction once the server holds keyframe `seq` (None: any);
        SglocError after `timeout` seconds."""
        return wait_for_correction(
            self._changed, lambda: self.correction, seq, timeout,
            f"robot {self.robot!r}: the server's ROS 2 path did not show its keyframes within "
            f"{timeout:g} s; is `sgloc serve` running with ROS 2 on this domain?")

    def sync(self, timeout: float = 10.0) -> None:
        """Nothing to say first: a ROS 2 robot just publishes."""

    def end(self, stamp_ns: int) -> int:
        """A ROS 2 robot does not say it has finished: its last keyframe is simply the last."""
        return self.seq

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self.node.close()
        self._session.close()
