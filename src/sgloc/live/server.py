"""`LiveServer`: one online session hosted over Zenoh. Robots publish keyframes on
`sgloc/<robot>/keyframe` (discovered as they appear); each gets its fleet correction on
`sgloc/<robot>/correction` at once after each of its messages and whenever it changes; the
session's events go to `sgloc/events`. ROS 2 robots take part without a ROS install
(`sgloc.live.ros2`, docs/live_ros2.md): their odometry and markers in CDR on rmw_zenoh's or
zenoh-bridge-ros2dds's keys; /tf (map -> odom), paths and the fleet map go back to ROS 2.

Zenoh's thread checks each message (malformed, duplicated, out-of-order and late messages are
counted, logged and dropped) and queues it; it is answered at once with the robot's correction
as last published, never waiting on the session: in the asynchronous mode by the front, a
process of its own holding the Zenoh router (`sgloc.live.front`; this process is its client),
so that a long solve holding this process's interpreter holds no answer back. The queue is
bounded (a robot with more than `robot_queue` waiting is dropped with a warning, so a flood
never exhausts memory). One thread owns the session: it takes the queued keyframes, publishes
the corrections that change, and plans attempts that run off that thread on worker processes or
a Dask cluster (`plan_attempts` / `run_batch` / `apply_attempts`), or inline with `sync`
(exactly as `sgloc replay`). The state is saved atomically on a schedule and on stop, and a
server started on an existing state file resumes from it."""

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
from sgloc.live.front import Front, published_key
from sgloc.live.transport import (
    DEFAULT_ENDPOINT,
    PREFIX,
    check_endpoint,
    is_robot_name,
    key,
    open_session,
)
from sgloc.live.view import DEFAULT_VIEW_HOST, DEFAULT_VIEW_PORT, FleetView
from sgloc.online import OnlineConfig, OnlineSession
from sgloc.online.batch import run_batch
from sgloc.pipeline.config import LocalizerConfig

log = logging.getLogger("sgloc.live")
#: Added to the attempt workers' niceness: a robot's keyframes come before attempts.
WORKER_NICENESS = 10
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
    solve_every: seconds between re-solves of the fleet frame at most while keyframes wait
        (the batches of attempts that finished meanwhile are solved at once); and always three
        times the last solve's duration at least (solves take a quarter of the session's
        thread at most, so keyframes keep flowing as the pose graph grows).
    zenoh_config: a Zenoh configuration file (TLS, access control; docs/live.md).
    ros2_domain: the ROS 2 domain (ROS_DOMAIN_ID) of ROS 2 robots and outputs; "auto": 0
        when the ROS 2 message types (rosbags) are installed, else none; None: no ROS 2.
    odom_topic / objects_topic: ROS 2 robots' topic templates (`sgloc.io.rosbag`);
        classes: {class name: id} for class names in their markers' namespaces.
    view: also serve the live view to Foxglove (`sgloc.live.view.FleetView`) on
        ws://`view_host`:`view_port` (loopback unless told otherwise; port 0: any free port),
        updated `view_rate` times a second at most.
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
    zenoh_config: Path | None = None
    view: bool = False
    view_host: str = DEFAULT_VIEW_HOST
    view_port: int = DEFAULT_VIEW_PORT
    view_rate: float = 2.0
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
        self._lock = threading.Lock()  # counts, seqs, stamps, published corrections
        self._seq: dict[str, int] = {}
        self._held = {r: int(round(self.session.keyframes(r)[0][-1] * 1e9))
                      for r in self.session.robots}  # robot -> the session's last stamp ns
        self._stamp = dict(self._held)  # robot -> the last keyframe stamp admitted (ns)
        self._revision = self.session.revision  # of the corrections last published
        T_now, done = self.session.corrections(), self.session.finished
        self._current: dict[str, tuple] = {r: (T_now.get(r), r in done)
                                           for r in self.session.robots}  # (T, finished)
        self._flight: list[tuple[Any, Any]] = []  # (batch, future)
        self._finishing: list[tuple[str, float]] = []  # (robot, stamp) of Ends not planned
        self._stop = threading.Event()
        self._idle = threading.Event()
        self._saved_at = self._planned_at = self._solved_at = time.monotonic()
        self._solve_took = 0.0  # seconds the last solve took
        self._dirty = False
        self._dirty_plan = True  # something changed since the last plan found nothing
        self._n_events = len(self.session.events)
        self._pool = self._zenoh = self._thread = self._ros2 = self._front = None
        self.view: FleetView | None = None

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
        """Start the view (with `view`), open the Zenoh session, subscribe, start the
        session's thread."""
        o = self.options
        try:  # what started is closed again when a later step fails (a port in use)
            if o.view:
                self.view = FleetView(o.view_host, o.view_port, o.view_rate).start()
            if not o.sync:
                self._pool = _Workers(o.workers, o.scheduler)
            if self._ros2_options is not None:
                ros2.typestore()  # built before robots can connect: it takes a while
            if o.sync:
                self._zenoh = open_session("router", listen=o.listen,
                                           config_file=o.zenoh_config)
            else:  # answers from a process of their own (`sgloc.live.front`)
                self._front = Front(o.listen, o.prefix, o.zenoh_config)
                self._zenoh = open_session("client", connect=self._front.start(),
                                           config_file=o.zenoh_config)
            self._sub = self._zenoh.declare_subscriber(f"{o.prefix}/*/keyframe", self._receive)
            if self._ros2_options is not None:
                self._ros2 = ros2.Ros2Bridge(self._zenoh, self._ros2_options)
                self._ros2.subscribe(self._receive_ros2)
        except BaseException:
            self.stop()
            raise
        if self._front is not None:  # the front answers with these from now on
            for robot in self.session.robots:
                self._answer(robot)
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
        if self._front is not None:
            self._front.stop()
        if self._pool is not None:
            self._pool.close()
        if self.view is not None:
            self.view.stop()

    def __enter__(self) -> LiveServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Wait until no message waits and no batch is in flight; False on timeout."""
        self._idle.clear()
        return self._idle.wait(timeout)

    # -- Zenoh's thread: check, answer, queue; never wait on the session ---------------------
    def _receive(self, sample) -> None:
        parts = str(sample.key_expr).split("/")
        robot = parts[1] if len(parts) == 3 else ""
        data = sample.payload.to_bytes()
        with self._lock:
            if self._flooded(robot):
                return
            m = self._admit(robot, data)
            # sync: a hello waits its turn too, answered once what came before it is taken
            queued = isinstance(m, msg.Keyframe | msg.End) or (m is not None and self.options.sync)
            if queued:
                self._put(robot, m)
            if self._front is not None:  # asynchronous: the front answers
                if isinstance(m, msg.Hello):  # its copy refreshed (a robot back after a restart)
                    self._answer(robot)
            elif is_robot_name(robot) and not queued:  # sync: a queued message once taken
                self._answer(robot)  # at once: the correction as it stands now

    def _flooded(self, robot: str) -> bool:
        """Whether `robot`'s next message is dropped for a flood (counted); lock held."""
        if self._waiting[robot] >= self.options.robot_queue:
            self._drop("flood", robot, "slow down: messages dropped")
            return True
        if self._queue.full():  # only Zenoh's thread puts: the check holds
            self._drop("flood", robot, "the server's queue is full: messages dropped")
            return True
        return False

    def _put(self, robot: str, m) -> None:
        self._queue.put_nowait((robot, m))
        self._waiting[robot] += 1

    def _receive_ros2(self, robot: str, kind: str, data: bytes) -> None:
        """One ROS 2 message of `robot` (Zenoh's thread): odometry kept, markers made
        keyframes (numbered on from the robot's last seq) and queued. A ROS 2 robot's answer
        is /tf (`sgloc.live.ros2`)."""
        with self._lock:
            if not robot:
                self._drop("bad_key", robot, "a ROS 2 topic naming no robot of 1-64 letters, "
                           "digits, '_' or '-'")
                return
            if self._flooded(robot):
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
                if not self._flooded(robot) and self._fresh(robot, m):
                    self._put(robot, m)

    def _admit(self, robot: str, data: bytes):
        """The decoded message when it is valid and new (else None, counted and logged)."""
        try:
            key(robot, "keyframe")
            m = msg.decode(data)
        except SglocError as e:
            self._drop("bad_key" if not robot or "robot name" in str(e) else "malformed",
                       robot, str(e))
            return None
        self.counts["received"] += 1
        return m if isinstance(m, msg.Hello) or (
            isinstance(m, msg.Keyframe | msg.End) and self._fresh(robot, m)) else None

    def _drop(self, kind: str, robot: str, why: str) -> None:
        self.counts[kind] += 1
        n = self.counts[kind]
        if n <= 10 or n % 1000 == 0:
            log.warning("robot %r: %s dropped (%s; %d so far): %s", robot, kind.replace("_", " "),
                        DROPS[kind], n, why)

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
        if isinstance(m, msg.Keyframe):
            if m.stamp_ns <= self._stamp.get(robot, -1):
                self._drop("late", robot, f"stamp {m.stamp_ns} ns")
                return False
            self._stamp[robot] = m.stamp_ns
        return True

    def _answer(self, robot: str) -> None:
        """Send `robot` its correction as last published (answering its latest message; to
        the front, which answers from it); called with the lock held."""
        T, finished = self._current.get(robot, (None, False))
        prefix = self.options.prefix
        self._zenoh.put(key(robot, "correction", prefix) if self._front is None
                        else published_key(prefix, robot), msg.encode_correction(
            self._seq.get(robot, 0), self._held.get(robot, -1), self._revision, T, finished))

    # -- the session's thread ------------------------------------------------------------------
    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                robot, m = self._queue.get(timeout=0.01)
            except queue.Empty:
                robot = None
            if robot is not None:
                with self._lock:
                    self._waiting[robot] -= 1
                self._take(robot, m)
            self._collect()
            self._schedule()
            self._publish_changes()
            self._save_when_due()
            if self.view is not None:
                self.view.update(self.session)
            if self._queue.empty() and not (self._flight or self._finishing
                                            or self.session.solve_due):
                self._idle.set()
        self._collect(wait=True)
        self._publish_changes(final=True)
        if self.view is not None:
            self.view.update(self.session, force=True)
        self.save()

    def _take(self, robot: str, m) -> None:
        """One checked message of `robot` into the session (then, with `sync`, answered)."""
        s = self.session
        try:
            if isinstance(m, msg.Keyframe):
                s.add_keyframe(robot, m.stamp_ns * 1e-9, m.T_odom_sensor, m.positions, m.labels)
                with self._lock:
                    self.counts["keyframes"] += 1
                    self._held[robot] = m.stamp_ns
                    if self._front is not None:  # the keyframe held, for the front's answers
                        self._answer(robot)
                if self._ros2 is not None:
                    self._ros2.note(m.stamp_ns)
            elif isinstance(m, msg.Hello):
                pass
            elif robot in s.robots and self.options.sync:
                s.finish(robot, m.stamp_ns * 1e-9)
            elif robot in s.robots:  # planned once no attempt of the robot is in flight
                self._finishing = [f for f in self._finishing if f[0] != robot]
                self._finishing.append((robot, m.stamp_ns * 1e-9))
        except SglocError as e:
            with self._lock:
                self._drop("rejected", robot, str(e))
        else:
            self._dirty = self._dirty_plan = True
        if self.options.sync:
            self._publish_changes(robot)

    def _publish_changes(self, asked: str | None = None, final: bool = False) -> None:
        """The new events; the corrections that changed since last published (and `asked`'s
        in any case, answering its latest message); the ROS 2 outputs when due (all of them
        when `final`)."""
        s = self.session
        if self._ros2 is not None:
            self._ros2.publish(s, self._held, force=final)
        events = s.events[self._n_events:]
        self._n_events = len(s.events)
        for e in events:
            self._zenoh.put(f"{self.options.prefix}/events", msg.encode_event(e.to_dict()))
        changed = [] if asked is None else [asked]
        if s.revision != self._revision or asked is not None:
            now, finished = s.corrections(), s.finished
            with self._lock:
                self._revision = s.revision
                for robot in s.robots:
                    c = (now.get(robot), robot in finished)
                    last = self._current.get(robot, (None, False))
                    if (c[0] is None) != (last[0] is None) or c[1] != last[1] or (
                            c[0] is not None and (c[0] != last[0]).any()):
                        self._current[robot] = c
                        changed.append(robot)
                for robot in dict.fromkeys(changed):
                    self._answer(robot)

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
        # keyframes first: while they wait, a solve comes every solve_every s, or three times
        # its own duration when longer (solves take a quarter of the thread at most)
        spacing = max(self.options.solve_every, 3.0 * self._solve_took)
        if self.session.solve_due and (wait or self._queue.empty()
                                       or now - self._solved_at >= spacing):
            self.session.solve_pending()  # one solve for the batches that came meanwhile
            self._solved_at = time.monotonic()
            self._solve_took = self._solved_at - now

    # -- state ---------------------------------------------------------------------------------
    def _save_when_due(self) -> None:
        if time.monotonic() - self._saved_at >= self.options.save_every:
            self.save()

    def save(self) -> Path | None:
        """Write the state file atomically (a temporary file beside it, then renamed); nothing
        while no keyframe came (a robot's hello alone leaves nothing to resume from)."""
        self._saved_at = time.monotonic()
        path = self.options.state
        if path is None or not self._dirty or not self.session.robots:
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
            # attempts yield the processor to the keyframes' intake and the answers
            self._pool = self._stack.enter_context(process_pool(self.size, WORKER_NICENESS))

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
