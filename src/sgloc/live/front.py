"""The live server's front: a process of its own that holds the Zenoh router robots connect to
and answers each robot message at once with the robot's correction as last published.

In one process an answer waits whenever the session holds the interpreter (a pose-graph solve
of a long run does, for a second or more); the front's process never runs the session, so its
answers do not wait. The server connects to the front as a Zenoh client on a loopback endpoint
of the front's own: it takes the keyframes (the checks, counts and queue are the server's) and
publishes each robot's correction on `published_key` after each keyframe it takes and whenever
the correction changes; the front keeps the latest of each robot, answers with it, and passes a
changed one on to the robot on `<prefix>/<robot>/correction`."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

from sgloc.errors import SglocError
from sgloc.live import messages as msg
from sgloc.live.transport import is_robot_name, key, open_session

#: The part of the key expressions the server publishes the corrections on for the front.
PUBLISHED = "_published"
#: Seconds the server waits for the front's router to listen.
START_TIMEOUT_S = 60.0


def published_key(prefix: str, robot: str) -> str:
    """Where the server publishes `robot`'s correction for the front."""
    return f"{prefix}/{PUBLISHED}/{robot}/correction"


def free_loopback_endpoint() -> str:
    """A TCP endpoint on loopback with a port free now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


class Front:
    """The front process (`start`, `stop`): a router listening on `listen` (and on `internal`,
    the loopback endpoint the server connects to), answering on `prefix`'s keys. It is a
    program of its own (`python -m sgloc.live.front`), so a script that starts a server needs
    no main-module guard; it ends when its standard input closes (the server stopped or died)."""

    def __init__(self, listen: str, prefix: str, config_file=None) -> None:
        self.listen, self.prefix, self.config_file = listen, prefix, config_file
        self.internal = free_loopback_endpoint()
        self._proc: subprocess.Popen | None = None

    def start(self) -> str:
        """Start the process; return the endpoint the server connects to. SglocError when its
        router cannot listen (the port in use)."""
        args = [sys.executable, "-m", "sgloc.live.front", self.listen, self.internal,
                self.prefix] + ([str(self.config_file)] if self.config_file else [])
        env = dict(os.environ)  # the same sgloc as this process's
        env["PYTHONPATH"] = os.pathsep.join(
            [str(Path(__file__).resolve().parents[2]), *filter(None, [env.get("PYTHONPATH")])])
        self._proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      env=env, text=True)
        line = _read_line(self._proc.stdout, START_TIMEOUT_S)
        if line != "ready":
            self.stop()
            raise SglocError(line.removeprefix("error: ") or "the server's front process did "
                             f"not start within {START_TIMEOUT_S:g} s")
        return self.internal

    def stop(self) -> None:
        """End the process (its router closes)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        with contextlib.suppress(OSError):
            proc.stdin.close()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        proc.stdout.close()


def _read_line(stream, timeout: float) -> str:
    """The first line of `stream` (stripped), or "" when none came within `timeout` s."""
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(stream.readline()), daemon=True)
    reader.start()
    reader.join(timeout)
    return got[0].strip() if got else ""


def main(argv: list[str]) -> int:
    """The front process: route, answer, pass corrections on, until standard input closes.
    argv: LISTEN INTERNAL PREFIX [ZENOH_CONFIG]."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the server handles Ctrl-C and stops this
    listen, internal, prefix, *config = argv
    try:
        zenoh = open_session("router", listen=[listen, internal],
                             config_file=config[0] if config else None)
    except SglocError as e:
        print(f"error: {e}", flush=True)
        return 2
    answers = _Answers(zenoh, prefix)
    subs = [zenoh.declare_subscriber(f"{prefix}/*/keyframe", answers.on_message),
            zenoh.declare_subscriber(published_key(prefix, "*"), answers.on_published)]
    print("ready", flush=True)
    sys.stdin.read()  # until the server closes it (or is gone)
    answers.close()
    for s in subs:
        s.undeclare()
    zenoh.close()
    return 0


class _Answers:
    """Each robot's last seq (of its messages) and its correction as the server last published
    it; the answers and the changes sent on."""

    def __init__(self, zenoh, prefix: str) -> None:
        self._zenoh, self._prefix = zenoh, prefix
        self._lock = threading.Lock()
        self._seq: dict[str, int] = {}
        self._last: dict[str, msg.Correction] = {}
        self._closed = False

    def close(self) -> None:
        """Send nothing more (the session is closing; callbacks may still come)."""
        with self._lock:
            self._closed = True

    def on_message(self, sample) -> None:
        parts = str(sample.key_expr).split("/")
        robot = parts[1] if len(parts) == 3 else ""
        if not is_robot_name(robot):
            return
        try:
            m = msg.decode(sample.payload.to_bytes())
        except msg.MessageError:
            m = None
        with self._lock:
            if isinstance(m, msg.Keyframe | msg.End):
                self._seq[robot] = max(self._seq.get(robot, 0), m.seq)
            self._send(robot)

    def on_published(self, sample) -> None:
        parts = str(sample.key_expr).split("/")
        robot = parts[2] if len(parts) == 4 else ""
        try:
            c = msg.decode(sample.payload.to_bytes())
        except msg.MessageError:
            return
        if not is_robot_name(robot) or not isinstance(c, msg.Correction):
            return
        with self._lock:
            last = self._last.get(robot)
            self._last[robot] = c
            self._seq[robot] = max(self._seq.get(robot, 0), c.seq)
            if last is None or last.placed != c.placed or last.finished != c.finished \
                    or not np.array_equal(last.T_fleet_odom, c.T_fleet_odom):
                self._send(robot)

    def _send(self, robot: str) -> None:
        if self._closed:
            return
        c = self._last.get(robot)
        payload = msg.encode_correction(self._seq.get(robot, 0), -1, 0) if c is None else \
            msg.encode_correction(self._seq.get(robot, 0), c.held_ns, c.revision,
                                  c.T_fleet_odom if c.placed else None, c.finished)
        self._zenoh.put(key(robot, "correction", self._prefix), payload)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
