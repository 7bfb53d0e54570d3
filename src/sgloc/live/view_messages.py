"""What the live view shows, as Foxglove's well-known messages: a `FleetSnapshot` taken from an
online session (plain arrays, cheap, on the session's thread) and the messages built from it
(no socket: `sgloc.live.view` sends them).

Frames: `map` is the fleet frame; `<robot>/odom` each placed robot's odometry frame (the
transform map -> <robot>/odom is its correction, `OnlineSession.T_fleet_robot`), and
`<robot>/base_link` its newest keyframe's sensor pose in that odometry frame.

Topics (`topics`): `/map` (SceneUpdate: the fleet map, one sphere per object coloured by class),
`/robots/<robot>/trajectory` (SceneUpdate: the corrected keyframe poses as a line strip),
`/links` (SceneUpdate: a line per link between the two keyframes it relates, or between the
two odometry origins with the back-end "robots"; active links green, held ones orange;
revoked links are not drawn), `/tf` (FrameTransforms), `/events` (Log: one per session
event)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np

from sgloc.maps.classes import CLASS_PALETTE, class_colours
from sgloc.maps.graph import SemanticGraph
from sgloc.online.records import Event
from sgloc.optional import require

MAP, TF, LINKS, EVENTS = "/map", "/tf", "/links", "/events"
ACTIVE, HELD = (0.1, 0.8, 0.2, 1.0), (1.0, 0.55, 0.0, 1.0)  # link colours (RGBA)


def trajectory_topic(robot: str) -> str:
    """The topic of `robot`'s corrected trajectory."""
    return f"/robots/{robot}/trajectory"


@dataclass(frozen=True)
class FleetSnapshot:
    """The fleet as the view draws it, in plain arrays (fleet frame, metres).

    maps: each placed robot's confirmed objects in the fleet frame (`fuse_radius` fuses them
        into the fleet map). trajectories: robot -> (k,3) corrected keyframe positions, None
        while unplaced. corrections: placed robot -> (4,4) T_map_odom. odometry: robot ->
        (4,4) its newest keyframe's T_odom_sensor. links: (m,2,3) segments, active: (m,)
        bool. events: the session's events not in an earlier snapshot. stamp_ns: wall clock.
    """

    robots: list[str]
    maps: dict[str, SemanticGraph]
    fuse_radius: float
    trajectories: dict[str, np.ndarray | None]
    corrections: dict[str, np.ndarray]
    odometry: dict[str, np.ndarray]
    links: np.ndarray
    active: np.ndarray
    events: list[Event] = field(default_factory=list)
    stamp_ns: int = 0


def snapshot(session: Any, events_from: int = 0) -> FleetSnapshot:
    """What the view shows of `session` now (its events from index `events_from` on).
    Call it on the thread that owns the session."""
    from sgloc.replay.outputs import fleet_maps  # deferred: loads the replay's writers

    robots, T = session.robots, session.corrections()
    traj, odom = {}, {}
    for r in robots:
        odom[r] = session.keyframes(r)[1][-1]
        t = session.trajectory(r)
        traj[r] = None if t is None else t[1][:, :3, 3].copy()
    links, active = _link_segments(session.links, traj, T)
    return FleetSnapshot(robots, fleet_maps(session, robots), float(session.online.fuse_radius),
                         traj, T, odom, links, active, list(session.events[events_from:]),
                         time.time_ns())


def _link_segments(links: Sequence[Any], traj: dict, T: dict) -> tuple[np.ndarray, np.ndarray]:
    """(m,2,3) the drawn links' ends and (m,) whether each is active: a keyframe link between
    its two keyframes' corrected positions, a robot link between the two odometry origins;
    revoked links and links of an unplaced robot are left out."""
    segs, active = [], []
    for lk in links:
        if lk.revoked or lk.robot_a not in T or lk.robot_b not in T:
            continue
        if lk.keyframe_a is None:
            a, b = T[lk.robot_a][:3, 3], T[lk.robot_b][:3, 3]
        else:
            a, b = traj[lk.robot_a][lk.keyframe_a], traj[lk.robot_b][lk.keyframe_b]
        segs.append((a, b))
        active.append(bool(lk.active))
    return np.asarray(segs, float).reshape(-1, 2, 3), np.asarray(active, bool)


@cache
def _fm():
    return require("foxglove.messages", "live", "--view (the live view in Foxglove)")


def _stamp(s: FleetSnapshot):
    return _fm().Timestamp(s.stamp_ns // 1_000_000_000, s.stamp_ns % 1_000_000_000)


def _colour(rgba: Sequence[float]):
    r, g, b, a = (float(v) for v in rgba)
    return _fm().Color(r=r, g=g, b=b, a=a)


def _hex_rgba(hexes: Sequence[str]) -> list:
    return [_colour((int(h[1:3], 16) / 255, int(h[3:5], 16) / 255, int(h[5:7], 16) / 255, 1.0))
            for h in hexes]


def _points(xyz: np.ndarray) -> list:
    fm = _fm()
    return [fm.Point3(x=x, y=y, z=z) for x, y, z in np.asarray(xyz, float).tolist()]


def _frame(T: np.ndarray) -> tuple[Any, Any]:
    """(Vector3, Quaternion) of a (4,4) transform."""
    from scipy.spatial.transform import Rotation  # deferred: scipy.spatial loads in ~0.2 s

    fm = _fm()
    qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat().tolist()
    x, y, z = T[:3, 3].tolist()
    return fm.Vector3(x=x, y=y, z=z), fm.Quaternion(x=qx, y=qy, z=qz, w=qw)


def _pose(T: np.ndarray):
    """A Foxglove Pose of a (4,4) transform."""
    t, q = _frame(T)
    return _fm().Pose(position=t, orientation=q)


def map_message(s: FleetSnapshot, object_size: float = 1.0):
    """SceneUpdate: the fleet map (the placed robots' objects fused), a sphere per object."""
    from sgloc.replay.outputs import merged_map

    fm = _fm()
    m = merged_map(s.maps, s.fuse_radius)
    size = fm.Vector3(x=object_size, y=object_size, z=object_size)
    upright = fm.Quaternion(w=1.0)
    classes = np.unique(m.labels).tolist()
    colour = dict(zip(classes, _hex_rgba(class_colours(classes)), strict=True))
    spheres = [fm.SpherePrimitive(pose=fm.Pose(position=fm.Vector3(x=x, y=y, z=z),
                                               orientation=upright),
                                  size=size, color=colour[c])
               for (x, y, z), c in zip(m.positions.tolist(), m.labels.tolist(), strict=True)]
    meta = [fm.KeyValuePair(key="objects", value=str(len(m)))]
    return fm.SceneUpdate(entities=[fm.SceneEntity(
        timestamp=_stamp(s), frame_id="map", id="fleet_map", spheres=spheres, metadata=meta)])


def trajectory_message(s: FleetSnapshot, robot: str, thickness: float = 0.3):
    """SceneUpdate: `robot`'s corrected keyframe positions as a line strip (a deletion while
    the robot is unplaced)."""
    fm = _fm()
    entity = f"{robot}/trajectory"
    xyz = s.trajectories.get(robot)
    if xyz is None:
        return fm.SceneUpdate(deletions=[fm.SceneEntityDeletion(
            timestamp=_stamp(s), type=fm.SceneEntityDeletionType.MatchingId, id=entity)])
    colour = CLASS_PALETTE[s.robots.index(robot) % len(CLASS_PALETTE)]
    line = fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, pose=_pose(np.eye(4)),
                            thickness=thickness, points=_points(xyz),
                            color=_hex_rgba([colour])[0])
    return fm.SceneUpdate(entities=[fm.SceneEntity(
        timestamp=_stamp(s), frame_id="map", id=entity, lines=[line])])


def links_message(s: FleetSnapshot, thickness: float = 0.15):
    """SceneUpdate: one line list of every drawn link (active green, held orange)."""
    fm = _fm()
    colours = [_colour(ACTIVE if a else HELD) for a in s.active.tolist() for _ in (0, 1)]
    line = fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineList, pose=_pose(np.eye(4)),
                            thickness=thickness, points=_points(s.links.reshape(-1, 3)),
                            color=_colour(ACTIVE), colors=colours)
    return fm.SceneUpdate(entities=[fm.SceneEntity(
        timestamp=_stamp(s), frame_id="map", id="links", lines=[line])])


def tf_message(s: FleetSnapshot):
    """FrameTransforms: map -> <robot>/odom (its correction) of each placed robot and
    <robot>/odom -> <robot>/base_link (its newest keyframe) of every robot."""
    fm = _fm()
    out = []
    for r in s.robots:
        pairs = [("map", f"{r}/odom", s.corrections.get(r)),
                 (f"{r}/odom", f"{r}/base_link", s.odometry.get(r))]
        for parent, child, T in pairs:
            if T is not None:
                t, q = _frame(T)
                out.append(fm.FrameTransform(timestamp=_stamp(s), parent_frame_id=parent,
                                             child_frame_id=child, translation=t, rotation=q))
    return fm.FrameTransforms(transforms=out)


def event_messages(s: FleetSnapshot) -> list:
    """Log: one per new event ("<kind> <robots>: <detail>", at the snapshot's wall time; the
    session's stamp leads the message)."""
    fm = _fm()
    return [fm.Log(timestamp=_stamp(s), level=fm.LogLevel.Info, name="sgloc",
                   message=f"t={e.stamp:.3f} s {e.kind} {', '.join(e.robots)}"
                           + (f": {e.detail}" if e.detail else ""))
            for e in s.events]


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return (a is None) == (b is None) and (a is None or (a.shape == b.shape
                                                         and np.array_equal(a, b)))


def changed(s: FleetSnapshot, before: FleetSnapshot | None) -> set[str]:
    """The topics whose message differs between `before` and `s` (all of them without
    `before`; /tf always: it is small)."""
    if before is None:
        return {MAP, LINKS, TF} | {trajectory_topic(r) for r in s.robots}
    topics = {TF}
    same_map = s.maps.keys() == before.maps.keys() and all(
        _same(g.positions, before.maps[r].positions) and _same(g.labels, before.maps[r].labels)
        for r, g in s.maps.items())
    if not same_map:
        topics.add(MAP)
    if not (_same(s.links, before.links) and _same(s.active, before.active)):
        topics.add(LINKS)
    for r in s.robots:
        if r not in before.trajectories or not _same(s.trajectories[r], before.trajectories[r]):
            topics.add(trajectory_topic(r))
    return topics


def messages(s: FleetSnapshot, object_size: float = 1.0,
             before: FleetSnapshot | None = None) -> dict[str, Any]:
    """topic -> the message of each drawn topic that changed since `before` (all without it;
    not the events: `event_messages`)."""
    topics = changed(s, before)
    build = {MAP: lambda: map_message(s, object_size), LINKS: lambda: links_message(s),
             TF: lambda: tf_message(s)}
    out = {t: build[t]() for t in (MAP, LINKS, TF) if t in topics}
    for r in s.robots:
        if trajectory_topic(r) in topics:
            out[trajectory_topic(r)] = trajectory_message(s, r)
    return out
