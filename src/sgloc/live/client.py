"""A robot's side of the live server: publish keyframes, receive the fleet correction.

    from sgloc.live.client import RobotClient
    with RobotClient("alpha", "tcp/127.0.0.1:7447") as robot:
        robot.send_keyframe(stamp_ns, T_odom_sensor, positions, labels)
        c = robot.wait_correction(timeout=1.0)   # Correction: placed, T_fleet_odom (map->odom)
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sgloc.errors import SglocError
from sgloc.live import messages as msg
from sgloc.live.transport import DEFAULT_ENDPOINT, PREFIX, check_robot, key, open_session, zenoh


class RobotClient:
    """One robot's Zenoh session to a server at `connect`: `send_keyframe`, `end`, `hello`;
    the server's corrections arrive on its own thread (`on_correction(c)` when given) and the
    latest is `correction`. zenoh_config: a Zenoh configuration file (TLS, access control)."""

    def __init__(self, robot: str, connect: str = DEFAULT_ENDPOINT, prefix: str = PREFIX,
                 on_correction: Callable[[msg.Correction], None] | None = None,
                 zenoh_config: str | Path | None = None) -> None:
        self.robot = check_robot(robot)
        self.seq = 0
        self.correction: msg.Correction | None = None
        self._changed = threading.Condition()
        self._callback = on_correction
        self._session = open_session("client", connect=connect, config_file=zenoh_config)
        # a full link slows the robot down rather than losing its keyframes
        self._pub = self._session.declare_publisher(
            key(robot, "keyframe", prefix), congestion_control=zenoh().CongestionControl.BLOCK)
        self._sub = self._session.declare_subscriber(key(robot, "correction", prefix),
                                                     self._receive)

    def _receive(self, sample) -> None:
        try:
            c = msg.decode(sample.payload.to_bytes())
        except msg.MessageError:
            return
        if not isinstance(c, msg.Correction):
            return
        with self._changed:
            self.correction = c
            self._changed.notify_all()
        if self._callback is not None:
            self._callback(c)

    def send_keyframe(self, stamp_ns: int, T_odom_sensor: np.ndarray, positions: np.ndarray,
                      labels: np.ndarray) -> int:
        """Publish one keyframe (stamp ns; T_odom_sensor (4,4); positions (n,3) metres in the
        sensor frame; labels (n,) class ids); returns its seq."""
        self.seq += 1
        self._pub.put(msg.encode_keyframe(self.seq, stamp_ns, T_odom_sensor, positions, labels))
        return self.seq

    def end(self, stamp_ns: int) -> int:
        """Say that the keyframe at `stamp_ns` was the last (the server tries it once more)."""
        self.seq += 1
        self._pub.put(msg.encode_end(self.seq, stamp_ns))
        return self.seq

    def hello(self) -> None:
        """Ask the server for this robot's correction (after connecting or a restart)."""
        self._pub.put(msg.encode_hello())

    def sync(self, timeout: float = 10.0) -> msg.Correction:
        """Say hello and wait for the server's answer; later seqs follow the last one it
        took from this robot (a reconnected robot carries on). Returns the correction."""
        end = time.monotonic() + timeout
        with self._changed:
            self.correction = None
        while True:
            self.hello()
            try:
                c = self.wait_correction(timeout=min(0.5, max(end - time.monotonic(), 0.01)))
                break
            except SglocError:
                if time.monotonic() >= end:
                    raise
        self.seq = max(self.seq, c.seq)
        return c

    def put_raw(self, payload: bytes) -> None:
        """Publish `payload` as it is on the keyframe key (tests, other encoders)."""
        self._pub.put(bytes(payload))

    def wait_correction(self, seq: int | None = None, timeout: float = 5.0
                        ) -> msg.Correction:
        """The latest correction, once one answering `seq` (or later) came (None: any);
        SglocError after `timeout` seconds."""
        return wait_for_correction(
            self._changed, lambda: self.correction, seq, timeout,
            f"robot {self.robot!r}: no correction from the server within {timeout:g} s; is "
            "`sgloc serve` running?")

    def close(self) -> None:
        """Close the session (the server keeps the robot's place)."""
        self._session.close()

    def __enter__(self) -> RobotClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def wait_for_correction(changed: threading.Condition, latest: Callable[[], msg.Correction | None],
                        seq: int | None, timeout: float, missing: str) -> msg.Correction:
    """`latest()` once it is a correction of seq `seq` or later (None: any), waiting on
    `changed` (notified when it changes); SglocError(`missing`) after `timeout` seconds."""
    end = time.monotonic() + timeout
    with changed:
        while (c := latest()) is None or (seq is not None and c.seq < seq):
            left = end - time.monotonic()
            if left <= 0:
                raise SglocError(missing)
            changed.wait(left)
        return c
