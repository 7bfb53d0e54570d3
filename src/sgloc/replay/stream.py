"""Stream the keyframes of all robots, interleaved by stamp, through one online session."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sgloc.errors import DatasetError
from sgloc.io.keyframes import RobotLog


@dataclass
class ReplayRecord:
    """What a replay measured.

    latency_ms: per robot, (N,) wall time of each add_keyframe call (milliseconds).
    joined_ns: per robot, the stamp of the first keyframe after which the robot had a fleet
        frame (None: never placed).
    transforms: (stamp ns, robot, T_fleet_odom) each time a robot's fleet frame took a new value.
    join_objects: per placed robot, its confirmed objects (k,3) (odometry frame, metres) when it
        was first placed: what the join was decided on.
    event_ns: the exact stamp (ns) of each of the session's events, in order (the keyframe's
        stamp as read; the events themselves hold it as float seconds); None for events the
        session had before the replay.
    """

    latency_ms: dict[str, np.ndarray]
    joined_ns: dict[str, int | None]
    transforms: list[tuple[int, str, np.ndarray]] = field(default_factory=list)
    join_objects: dict[str, np.ndarray] = field(default_factory=dict)
    event_ns: list[int | None] = field(default_factory=list)


def keyframe_order(logs: Sequence[RobotLog]) -> np.ndarray:
    """(K,2) (robot index, keyframe index) of every keyframe, by stamp; ties by robot order."""
    r = np.concatenate([np.full(len(g), i) for i, g in enumerate(logs)])
    k = np.concatenate([np.arange(len(g)) for g in logs])
    s = np.concatenate([g.stamps_ns for g in logs])
    order = np.lexsort((k, r, s))
    return np.column_stack([r[order], k[order]])


def check_names(logs: Sequence[RobotLog]) -> None:
    """DatasetError when two robots share a name (their outputs would collide)."""
    seen: set[str] = set()
    for g in logs:
        if g.name in seen:
            raise DatasetError(f"two robots are named {g.name!r}; give every robot its own name.")
        seen.add(g.name)


def replay_logs(
    logs: Sequence[RobotLog],
    session: Any,
    progress: Callable[[int], None] | None = None,
    finish: bool = True,
) -> ReplayRecord:
    """Feed every keyframe of `logs` to `session.add_keyframe` in stamp order (as if the
    robots ran at once); time each call and track when each robot's fleet frame changes.
    With `finish`, a robot's last keyframe is followed by `session.finish(robot)` (its final
    attempts, timed as part of that keyframe's update). `progress(1)` after each keyframe."""
    check_names(logs)
    obs = [list(g.observations()) for g in logs]
    poses = [g.poses for g in logs]
    lat = {g.name: np.zeros(len(g)) for g in logs}
    joined: dict[str, int | None] = {g.name: None for g in logs}
    last: dict[str, np.ndarray] = {}
    rec = ReplayRecord(lat, joined, event_ns=[None] * len(session.events))
    for r, k in keyframe_order(logs):
        g, (_, pos, lab) = logs[r], obs[r][k]
        n_events = len(session.events)
        t0 = time.perf_counter_ns()
        session.add_keyframe(g.name, float(g.stamps[k]), poses[r][k], pos, lab)
        if finish and k == len(g) - 1:
            session.finish(g.name, float(g.stamps[k]))
        lat[g.name][k] = (time.perf_counter_ns() - t0) * 1e-6
        rec.event_ns += [int(g.stamps_ns[k])] * (len(session.events) - n_events)
        _track(session, int(g.stamps_ns[k]), last, rec)
        if progress is not None:
            progress(1)
    return rec


def _track(session: Any, stamp_ns: int, last: dict[str, np.ndarray], rec: ReplayRecord) -> None:
    """Record robots whose fleet frame appeared or changed after the update at `stamp_ns`."""
    for robot in session.robots:
        T = session.T_fleet_robot(robot)
        if T is None:
            last.pop(robot, None)
            continue
        if rec.joined_ns.get(robot) is None:
            rec.joined_ns[robot] = stamp_ns
            rec.join_objects[robot] = session.map(robot).positions.copy()
        if robot not in last or not np.array_equal(last[robot], T):
            last[robot] = T
            rec.transforms.append((stamp_ns, robot, T))
