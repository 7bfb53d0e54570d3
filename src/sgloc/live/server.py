"""`LiveServer`: one online session hosted over Zenoh. Robots publish keyframes on
`sgloc/<robot>/keyframe` (discovered as they appear); each gets its fleet correction on
`sgloc/<robot>/correction` at once after each of its messages and whenever it changes; the
session's events go to `sgloc/events`. ROS 2 robots take part without a ROS install
(`sgloc.live.ros2`, docs/live_ros2.md): their odometry and markers in CDR on rmw_zenoh's or
zenoh-bridge-ros2dds's keys; /tf (map -> odom), paths and the fleet map go back to ROS 2.

One thread owns the session: it takes messages from one bounded queue (a robot with more than
`robot_queue` waiting is dropped with a warning, so a flood never exhausts memory), checks
them (malformed, duplicated, out-of-order and late messages are counted, logged and dropped),
adds keyframes, and plans attempts that run off that thread on worker processes or a Dask
cluster (`plan_attempts` / `run_batch` / `apply_attempts`), or inline with `sync` (exactly as
`sgloc replay`). The state is saved atomically on a schedule and on stop, and a server started
on an existing state file resumes from it."""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from collections import Counter
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from sgloc.errors import SglocError
from sgloc.live import messages as msg
from sgloc.live import ros2
from sgloc.live.transport import DEFAULT_ENDPOINT, PREFIX, check_endpoint, key, open_session
from sgloc.online import OnlineConfig, OnlineSession
from sgloc.online.batch import run_batch
from sgloc.pipeline.config import LocalizerConfig

log = logging.getLogger("sgloc.live")
#: Counted drops and what they mean (`LiveServer.counts`).
DROPS = {"malformed": "not a valid sgloc message", "duplicate": "a message seen already",
         "out_of_order": "older than one already taken", "late": "a stamp not after the "
         "robot's last keyframe", "rejected": "refused by the session", "flood": "the robot "
         "had too many messages waiting", "bad_key": "not on sgloc/<robot>/keyframe",
         "unpaired": "ROS 2 markers with no odometry of the robot at or before their stamp"}


@dataclass(frozen=True)
class ServeOptions:
    """How a server runs.

    listen: the Zenoh endpoint it listens on (loopback unless told otherwise).
    state: the state file (.npz) saved every `save_every` seconds and on stop, resumed from
        when it exists (None: no state kept).
    sync: attempts inline after each keyframe, exactly as `sgloc replay` (no workers).
    workers: processes for attempts (asynchronous mode); scheduler: a Dask scheduler address
        instead. max_attempts: attempts per planned batch (None: all due).
    queue: messages waiting at most (all robots); robot_queue: per robot.
    plan_every: seconds between plans of attempts at most while keyframes are waiting (a
        plan weighs every pair of robots; with no keyframe waiting, one after each message).
    solve_every: seconds between re-solves of the fleet frame at most while keyframes are
        waiting (the batches of attempts that finished meanwhile are solved at once).
    ros2_domain: the ROS 2 domain (ROS_DOMAIN_ID) of ROS 2 robots and outputs; "auto": 0
        when the ROS 2 message types (rosbags) are installed, else none; None: no ROS 2.
    odom_topic / objects_topic: ROS 2 robots' topic templates (`sgloc.io.rosbag`);
        classes: {class name: id} for class names in their markers' namespaces.
    """

    listen: str = DEFAULT_ENDPOINT
    state: Path | None = None
    save_every: float = 30.0
    sync: bool = False
    workers: int = 1
    scheduler: str | None = None
    max_attempts: int | None = 2
    queue: int = 4096
    robot_queue: int = 256
    plan_every: float = 0.05
    solve_every: float = 0.5
    prefix: str = PREFIX
    ros2_domain: int | str | None = "auto"
    odom_topic: str = ros2.ODOM_TOPIC
    objects_topic: str = ros2.OBJECTS_TOPIC
    classes: dict[str, int] | None = None

    def ros2(self) -> ros2.Ros2Options | None:
        """The ROS 2 side's options; None when off. SglocError for a bad domain."""
        d = self.ros2_domain
        if d is None or (d == "auto" and not ros2.available()):
            return None
        if d != "auto" and (isinstance(d, bool) or not isinstance(d, int) or not 0 <= d <= 232):
            raise SglocError(f"--ros2-domain {d!r}: give a ROS 2 domain id in 0 .. 232.")
        return ros2.Ros2Options(0 if d == "auto" else d, self.odom_topic, self.objects_topic,
                                classes=self.classes)


class LiveServer:
    """One online session served over Zenoh (`start`, `stop`; or `with LiveServer(...)`).

    Args:
        config / online: the session's settings when it starts fresh (a resumed session
            keeps those of its state file).
        options: `ServeOptions`.
        root: the robot whose odometry frame is the fleet frame (default: the first to send
            a keyframe).
    """

    def __init__(self, config: LocalizerConfig | None = None, online: OnlineConfig | None = None,
                 options: ServeOptions | None = None, root: str | None = None) -> None:
        self.options = o = options or ServeOptions()
        check_endpoint(o.listen)
        self._ros2_options = o.ros2()
        self.session = self._session(config, online, root)
        self.counts: Counter = Counter()
        self._queue: queue.Queue = queue.Queue(o.queue)
        self._waiting: Counter = Counter()  # robot -> its messages in the queue
        self._lock = threading.Lock()
        self._seq: dict[str, int] = {}
        self._stamp = {r: int(round(self.session.keyframes(r)[0][-1] * 1e9))
                       for r in self.session.robots}  # robot -> its last keyframe's stamp ns
        self._rev = -1  # the session's revision when the corrections were last published
        self._sent: dict[str, Any] = {}  # robot -> the correction it was last sent
        self._flight: list[tuple[Any, Any]] = []  # (batch, future)
        self._finishing: list[tuple[str, float]] = []  # (robot, stamp) of Ends not planned
        self._stop = threading.Event()
        self._idle = threading.Event()
        self._saved_at = self._planned_at = self._solved_at = time.monotonic()
        self._dirty = False
        self._dirty_plan = True  # something changed since the last plan found nothing
        self._n_events = len(self.session.events)
        self._pool = self._zenoh = self._thread = self._ros2 = None

    def _session(self, config, online, root) -> OnlineSession:
        o = self.options
        budget = (online or OnlineConfig()).max_attempts if o.sync else 0
        if o.state is not None and Path(o.state).exists():
            s = OnlineSession.load(o.state)
            log.info("resumed %s: %d robots, %d links", o.state, len(s.robots), len(s.links))
            budget = OnlineConfig().max_attempts if o.sync else 0
        else:
            s = OnlineSession(config, online, root)
        s.online = replace(s.online, max_attempts=budget)
        return s

    # -- life cycle ----------------------------------------------------------------------------
    def start(self) -> LiveServer:
        """Open the Zenoh session, subscribe, start the session's thread."""
        o = self.options
        if not o.sync:
            self._pool = _Workers(o.workers, o.scheduler)
        self._zenoh = open_session("router", listen=o.listen)
        self._sub = self._zenoh.declare_subscriber(f"{o.prefix}/*/keyframe", self._receive)
        if self._ros2_options is not None:
            self._ros2 = ros2.Ros2Bridge(self._zenoh, self._ros2_options)
            self._ros2.subscribe(self._enqueue)
        self._thread = threading.Thread(target=self._loop, name="sgloc-live", daemon=True)
        self._thread.start()
        log.info("listening on %s (%s)", o.listen, "sync" if o.sync else "async")
        return self

    def stop(self) -> None:
        """Finish the batches in flight, save the state, close."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._ros2 is not None:
            self._ros2.close()
        if self._zenoh is not None:
            self._zenoh.close()
        if self._pool is not None:
            self._pool.close()

    def __enter__(self) -> LiveServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Wait until no message waits and no batch is in flight; False on timeout."""
        self._idle.clear()
        return self._idle.wait(timeout)

    # -- Zenoh's thread: take, never wait ------------------------------------------------------
    def _receive(self, sample) -> None:
        parts = str(sample.key_expr).split("/")
        self._enqueue(parts[1] if len(parts) == 3 else "", None, sample.payload.to_bytes())

    def _enqueue(self, robot: str, kind: str | None, data: bytes) -> None:
        """One message of `robot` into the queue: kind None for sgloc's own, else the ROS 2
        topic's ("odom", "objects")."""
        with self._lock:
            if self._waiting[robot] >= self.options.robot_queue:
                self._drop("flood", robot, "slow down: messages dropped")
                return
            try:
                self._queue.put_nowait((robot, kind, data))
            except queue.Full:
                self._drop("flood", robot, "the server's queue is full: messages dropped")
                return
            self._waiting[robot] += 1

    def _drop(self, kind: str, robot: str, why: str) -> None:
        self.counts[kind] += 1
        n = self.counts[kind]
        if n <= 10 or n % 1000 == 0:
            log.warning("robot %r: %s dropped (%s; %d so far): %s", robot, kind.replace("_", " "),
                        DROPS[kind], n, why)

    # -- the session's thread ------------------------------------------------------------------
    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                robot, kind, data = self._queue.get(timeout=0.01)
            except queue.Empty:
                robot = None
            if robot is not None:
                with self._lock:
                    self._waiting[robot] -= 1
                if kind is None:
                    self._handle(robot, data)
                else:
                    self._handle_ros2(robot, kind, data)
            self._collect()
            self._schedule()
            self._publish_changes()
            self._save_when_due()
            if self._queue.empty() and not self._flight and not self._finishing:
                self._idle.set()
        self._collect(wait=True)
        self._publish_changes(final=True)
        self.save()

    def _handle(self, robot: str, data: bytes) -> None:
        """One message of `robot`: checked, taken, answered with the robot's correction."""
        try:
            key(robot, "keyframe")
            m = msg.decode(data)
        except SglocError as e:
            self._drop("bad_key" if not robot or "robot name" in str(e) else "malformed",
                       robot, str(e))
            return
        self.counts["received"] += 1
        seq = getattr(m, "seq", self._seq.get(robot, 0))
        if isinstance(m, msg.Keyframe | msg.End) and self._fresh(robot, m):
            self._take(robot, m)
        self._answer(robot, seq)

    def _handle_ros2(self, robot: str, kind: str, data: bytes) -> None:
        """One ROS 2 message of `robot`: odometry kept, markers taken as keyframes (numbered
        on from the robot's last seq), the robot's correction sent when one was."""
        if not robot:
            self._drop("bad_key", robot, "a ROS 2 topic naming no robot of 1-64 letters, "
                       "digits, '_' or '-'")
            return
        try:
            frames = self._ros2.decode(robot, kind, data)
        except msg.MessageError as e:
            self._drop("unpaired" if isinstance(e, ros2.UnpairedError) else "malformed",
                       robot, str(e))
            return
        self.counts["received"] += 1
        for stamp, T, positions, labels in frames:
            m = msg.Keyframe(self._seq.get(robot, 0) + 1, stamp, T, positions, labels)
            if self._fresh(robot, m):
                self._take(robot, m)
        if frames:
            self._answer(robot, self._seq.get(robot, 0))

    def _fresh(self, robot: str, m) -> bool:
        """Whether `m` is new: a seq after the robot's last, a keyframe stamp after its last."""
        last = self._seq.get(robot, 0)
        if m.seq == last:
            self._drop("duplicate", robot, f"seq {m.seq}")
            return False
        if m.seq < last:
            self._drop("out_of_order", robot, f"seq {m.seq} after seq {last}")
            return False
        self._seq[robot] = m.seq
        if isinstance(m, msg.Keyframe) and m.stamp_ns <= self._stamp.get(robot, -1):
            self._drop("late", robot, f"stamp {m.stamp_ns} ns")
            return False
        return True

    def _take(self, robot: str, m) -> None:
        s = self.session
        try:
            if isinstance(m, msg.Keyframe):
                s.add_keyframe(robot, m.stamp_ns * 1e-9, m.T_odom_sensor, m.positions, m.labels)
                self._stamp[robot] = m.stamp_ns
                if self._ros2 is not None:
                    self._ros2.note(m.stamp_ns)
                self.counts["keyframes"] += 1
            elif robot in s.robots and self.options.sync:
                s.finish(robot, m.stamp_ns * 1e-9)
            elif robot in s.robots:  # planned once no attempt of the robot is in flight
                self._finishing = [f for f in self._finishing if f[0] != robot]
                self._finishing.append((robot, m.stamp_ns * 1e-9))
        except SglocError as e:
            self._drop("rejected", robot, str(e))
            return
        self._dirty = self._dirty_plan = True

    def _answer(self, robot: str, seq: int) -> None:
        """Send `robot` its correction now (answering its message `seq`)."""
        if robot not in self.session.robots:
            T = None
        else:
            T = self.session.T_fleet_robot(robot)
        self._sent[robot] = T
        s = self.session
        self._zenoh.put(key(robot, "correction", self.options.prefix), msg.encode_correction(
            seq, self._stamp.get(robot, -1), s.revision, T, robot in s.finished))

    def _publish_changes(self, final: bool = False) -> None:
        """The corrections that changed since each robot's last, the new events, the ROS 2
        outputs when due (all of them when `final`)."""
        s = self.session
        if self._ros2 is not None:
            self._ros2.publish(s, self._stamp, force=final)
        events = s.events[self._n_events:]
        self._n_events = len(s.events)
        for e in events:
            self._zenoh.put(f"{self.options.prefix}/events", msg.encode_event(e.to_dict()))
        if s.revision == self._rev:
            return
        self._rev = s.revision
        now = s.corrections()
        for robot, last in list(self._sent.items()):
            T = now.get(robot)
            if (T is None) != (last is None) or (T is not None and (T != last).any()):
                self._answer(robot, self._seq.get(robot, 0))

    # -- attempts off the ingest path ----------------------------------------------------------
    def _schedule(self) -> None:
        """Plan the next batch when a worker is free and the session changed since the last
        plan that found nothing due."""
        if self._pool is None or len(self._flight) >= self._pool.size or not self._dirty_plan:
            return
        now = time.monotonic()
        if not self._queue.empty() and now - self._planned_at < self.options.plan_every:
            return  # keyframes first: a plan weighs every pair of robots
        self._planned_at = now
        busy = {k for b, _ in self._flight for pair in b.pairs for k in pair}
        for robot, stamp in self._finishing:
            if self.session.robots.index(robot) not in busy:
                self._finishing.remove((robot, stamp))
                self._submit(self.session.plan_attempts(stamp, finishing=robot))
                return
        batch = self.session.plan_attempts(max_attempts=self.options.max_attempts)
        self._dirty_plan = batch is not None
        self._submit(batch)

    def _submit(self, batch) -> None:
        if batch is not None:
            self._flight.append((batch, self._pool.submit(batch, self.session.config)))

    def _collect(self, wait: bool = False) -> None:
        """Apply the batches that finished (all of them with `wait`), in planning order."""
        while self._flight and (wait or self._flight[0][1].done()):
            batch, fut = self._flight.pop(0)
            try:
                results = fut.result()
            except Exception as e:  # a worker that died: the pairs are planned again
                log.warning("a batch of %d attempts failed (%s); planned again", len(batch), e)
                self.session.release(batch)
                self._dirty_plan = True
                continue
            self.session.apply_attempts(batch, results, solve=False)
            self._dirty = self._dirty_plan = True
        now = time.monotonic()
        if self.session.solve_due and (wait or self._queue.empty()
                                       or now - self._solved_at >= self.options.solve_every):
            self._solved_at = now  # one solve for the batches that came meanwhile
            self.session.solve_pending()

    # -- state ---------------------------------------------------------------------------------
    def _save_when_due(self) -> None:
        if time.monotonic() - self._saved_at >= self.options.save_every:
            self.save()

    def save(self) -> Path | None:
        """Write the state file atomically (a temporary file beside it, then renamed)."""
        self._saved_at = time.monotonic()
        path = self.options.state
        if path is None or not self._dirty:
            return None
        path = Path(path)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
        try:
            self.session.save(tmp)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        self._dirty = False
        return path


class _Workers:
    """Where batches run: a process pool of `size` workers, or a Dask cluster."""

    def __init__(self, workers: int, scheduler: str | None) -> None:
        self.size = max(int(workers), 1)
        if scheduler is not None:
            from sgloc.optional import require

            require("distributed", "dask", "--scheduler (attempts on a Dask cluster)")
            from distributed import Client

            self._client = Client(scheduler, timeout=15)
            self.size = max(self.size, len(self._client.scheduler_info()["workers"]))
            self._pool = None
        else:
            from sgloc.runtime.workers import process_pool

            self._client = None
            self._stack = ExitStack()
            self._pool = self._stack.enter_context(process_pool(self.size))

    def submit(self, batch, config):
        if self._client is not None:
            return self._client.submit(run_batch, batch, config, pure=False)
        return self._pool.submit(run_batch, batch, config)

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
        else:
            self._stack.close()


def serve(config: LocalizerConfig | None = None, online: OnlineConfig | None = None,
          options: ServeOptions | None = None, seconds: float | None = None,
          report: Any = None, root: str | None = None) -> LiveServer:
    """Run a `LiveServer` until interrupted (Ctrl-C, SIGTERM: it then saves and closes) or for
    `seconds`; `report(server)` every few seconds when given. Returns the stopped server."""
    server = LiveServer(config, online, options, root)
    end = None if seconds is None else time.monotonic() + seconds
    with server:
        shown = time.monotonic()
        if report is not None:
            report(server)
        while end is None or time.monotonic() < end:
            time.sleep(0.1)
            if report is not None and time.monotonic() - shown >= 5.0:
                shown = time.monotonic()
                report(server)
    return server
