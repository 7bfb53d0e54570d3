"""Play recorded robots to a live server (`sgloc stream`): one Zenoh session per robot, the
keyframes of all robots in stamp order (as `sgloc replay` interleaves them), in real time
times `rate`, as fast as possible (rate 0), or in lockstep (each keyframe's correction awaited
before the next: the replay's order exactly, resumed where the server's state left off when
it restarted)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sgloc.errors import SglocError
from sgloc.io.keyframes import RobotLog
from sgloc.live.client import RobotClient
from sgloc.live.transport import PREFIX
from sgloc.replay.stream import check_names, keyframe_order


@dataclass
class StreamRecord:
    """What a stream measured: keyframes sent; per robot, the latency (ms) from each keyframe
    sent to its correction received (lockstep or when it came); the last correction; how many
    times the server was resynchronised (lockstep, after a restart); when the stream began and,
    per robot, when its first placed correction came (`time.perf_counter()` seconds)."""

    sent: int = 0
    latency_ms: dict[str, list[float]] = field(default_factory=dict)
    corrections: dict[str, object] = field(default_factory=dict)
    resyncs: int = 0
    started: float = float("nan")
    first_placed: dict[str, float] = field(default_factory=dict)


class _Robot:
    """A robot's client and its log, keeping the send time of each keyframe seq."""

    def __init__(self, log: RobotLog, to: str, prefix: str, rec: StreamRecord,
                 zenoh_config=None, ros2_domain: int | None = None) -> None:
        self.log, self.rec = log, rec
        self.obs = list(log.observations())
        self.poses = log.poses
        self.sent: dict[int, float] = {}
        rec.latency_ms[log.name] = []
        if ros2_domain is None:
            self.client = RobotClient(log.name, to, prefix, self._corrected, zenoh_config)
        else:
            from sgloc.live.ros2 import Ros2Client

            self.client = Ros2Client(log, to, ros2_domain, on_correction=self._corrected,
                                     zenoh_config=zenoh_config)

    def _corrected(self, c) -> None:
        now = time.perf_counter()
        for seq in [s for s in self.sent if s <= c.seq]:
            self.rec.latency_ms[self.log.name].append((now - self.sent.pop(seq)) * 1e3)
        self.rec.corrections[self.log.name] = c
        if c.placed:
            self.rec.first_placed.setdefault(self.log.name, now)

    def send(self, k: int) -> int:
        _, pos, lab = self.obs[k]
        t = time.perf_counter()
        if isinstance(self.client, RobotClient):
            seq = self.client.send_keyframe(int(self.log.stamps_ns[k]), self.poses[k], pos, lab)
        else:
            seq = self.client.send(k)
        self.sent[seq] = t
        self.rec.sent += 1
        return seq


def stream_logs(
    logs: Sequence[RobotLog], to: str, rate: float = 1.0, lockstep: bool = False,
    timeout: float = 30.0, prefix: str = PREFIX,
    progress: Callable[[int], None] | None = None, restart_timeout: float = 120.0,
    record: StreamRecord | None = None, zenoh_config: str | Path | None = None,
    ros2_domain: int | None = None,
) -> StreamRecord:
    """Play `logs` to the server at `to` (see the module); returns the `StreamRecord`
    (`record` when given: it holds what was measured even when this raises).
    rate: speed-up over the stamps (1: real time; 0: no waiting); lockstep: wait for each
    correction (`timeout` seconds per message, then resynchronising with a server that is
    back within `restart_timeout` seconds); zenoh_config: a Zenoh configuration file for
    every robot's session (TLS, access control); ros2_domain: play each robot as a ROS 2 robot
    on that domain (`sgloc.live.ros2.Ros2Client`) instead of with sgloc's own messages."""
    check_names(logs)
    if rate < 0 or not np.isfinite(rate):
        raise SglocError(f"--rate {rate}: give a speed-up >= 0 (1: real time, 0: at once).")
    if lockstep and ros2_domain is not None:
        raise SglocError("--lockstep needs sgloc's own messages (a ROS 2 robot does not wait "
                         "for answers): drop --lockstep or --as ros2.")
    rec = StreamRecord() if record is None else record
    robots = [_Robot(g, to, prefix, rec, zenoh_config, ros2_domain) for g in logs]
    try:
        for r in robots:
            r.client.sync(timeout)
        order = keyframe_order(logs)
        rec.started = time.perf_counter()
        if lockstep:
            _lockstep(robots, order, (timeout, restart_timeout), rec, progress)
        else:
            _timed(robots, order, rate, progress)
            for r in robots:  # the last corrections
                r.client.wait_correction(r.client.seq, timeout)
    finally:
        for r in robots:
            r.client.close()
    return rec


def _timed(robots: list[_Robot], order: np.ndarray, rate: float, progress) -> None:
    t0 = time.perf_counter()
    first = min(int(r.log.stamps_ns[0]) for r in robots)
    for i, k in order:
        r = robots[i]
        if rate > 0:
            wait = (int(r.log.stamps_ns[k]) - first) * 1e-9 / rate - (time.perf_counter() - t0)
            if wait > 0:
                time.sleep(wait)
        r.send(int(k))
        if k == len(r.log) - 1:
            r.client.end(int(r.log.stamps_ns[k]))
        if progress is not None:
            progress(1)


def _lockstep(robots: list[_Robot], order: np.ndarray, timeouts: tuple[float, float],
              rec: StreamRecord, progress) -> None:
    """Each message answered before the next; when an answer does not come (the server
    restarted), resynchronise on what the server holds and carry on from there."""
    p, (timeout, restart) = 0, timeouts
    while p < len(order):
        i, k = (int(v) for v in order[p])
        r = robots[i]
        c = rec.corrections.get(r.log.name)
        try:
            stamp = int(r.log.stamps_ns[k])
            if c is None or c.held_ns < stamp:
                r.client.wait_correction(r.send(k), timeout)
            if k == len(r.log) - 1 and not rec.corrections[r.log.name].finished:
                r.client.wait_correction(r.client.end(stamp), timeout)
        except SglocError:
            p = _resync(robots, order, restart, rec)
            continue
        p += 1
        if progress is not None:
            progress(1)


def _resync(robots: list[_Robot], order: np.ndarray, timeout: float, rec: StreamRecord) -> int:
    """Ask every robot's correction again (the server back); the first position of `order`
    the server does not hold."""
    rec.resyncs += 1
    for r in robots:
        r.sent.clear()
        rec.corrections[r.log.name] = r.client.sync(timeout)
    for p, (i, k) in enumerate(order):
        r = robots[int(i)]
        c = rec.corrections[r.log.name]
        if c.held_ns < int(r.log.stamps_ns[k]) or (k == len(r.log) - 1 and not c.finished):
            return p
    return len(order)
