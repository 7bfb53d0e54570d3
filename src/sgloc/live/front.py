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

import multiprocessing as mp
import os
import signal
import socket
import threading

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
    the loopback endpoint the server connects to), answering on `prefix`'s keys."""

    def __init__(self, listen: str, prefix: str, config_file=None) -> None:
        self.listen, self.prefix, self.config_file = listen, prefix, config_file
        self.internal = free_loopback_endpoint()
        self._proc = None

    def start(self) -> str:
        """Start the process; return the endpoint the server connects to. SglocError when its
        router cannot listen (the port in use)."""
        ctx = mp.get_context("spawn")
        self._stop, ready = ctx.Event(), ctx.Queue()
        self._proc = ctx.Process(target=_run, name="sgloc-front", daemon=True, args=(
            self.listen, self.internal, self.prefix, self.config_file, os.getpid(), ready,
            self._stop))
        self._proc.start()
        try:
            status, why = ready.get(timeout=START_TIMEOUT_S)
        except Exception:  # queue.Empty: the process died or hangs
            status, why = "error", f"the front process did not start within {START_TIMEOUT_S:g} s"
        if status != "ready":
            self.stop()
            raise SglocError(why)
        return self.internal

    def stop(self) -> None:
        """End the process (its router closes)."""
        if self._proc is None:
            return
        self._stop.set()
        self._proc.join(10)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(5)
        self._proc = None


def _run(listen, internal, prefix, config_file, parent, ready, stop) -> None:
    """The front process: route, answer, pass corrections on, until `stop` or the server
    process is gone."""
    from sgloc.runtime.workers import watch_parent

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the server handles Ctrl-C and stops this
    watch_parent(parent)
    try:
        zenoh = open_session("router", listen=[listen, internal], config_file=config_file)
    except SglocError as e:
        ready.put(("error", str(e)))
        return
    answers = _Answers(zenoh, prefix)
    subs = [zenoh.declare_subscriber(f"{prefix}/*/keyframe", answers.on_message),
            zenoh.declare_subscriber(published_key(prefix, "*"), answers.on_published)]
    ready.put(("ready", None))
    while not stop.wait(0.2):
        pass
    for s in subs:
        s.undeclare()
    zenoh.close()


class _Answers:
    """Each robot's last seq (of its messages) and its correction as the server last published
    it; the answers and the changes sent on."""

    def __init__(self, zenoh, prefix: str) -> None:
        self._zenoh, self._prefix = zenoh, prefix
        self._lock = threading.Lock()
        self._seq: dict[str, int] = {}
        self._last: dict[str, msg.Correction] = {}

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
        c = self._last.get(robot)
        payload = msg.encode_correction(self._seq.get(robot, 0), -1, 0) if c is None else \
            msg.encode_correction(self._seq.get(robot, 0), c.held_ns, c.revision,
                                  c.T_fleet_odom if c.placed else None, c.finished)
        self._zenoh.put(key(robot, "correction", self._prefix), payload)
