"""`FleetView`: the live fleet in Foxglove. A Foxglove WebSocket server (foxglove-sdk, loopback
by default) that a user opens in the Foxglove app (Open connection -> Foxglove WebSocket ->
ws://127.0.0.1:8765); the topics and frames are `sgloc.live.view_messages`'s.

The session's owner calls `update(session)` as often as it likes: at most `rate` times a second
it takes a snapshot (plain arrays; only when the session changed) and hands it to the view's
own thread, which builds and sends the messages of the topics that changed. The hand-off holds
one snapshot (a newer one replaces it, its events kept), so a slow viewer never holds up the
session, and after each update the view rests twice as long as it worked (building messages
holds the GIL: a large fleet's map is then updated less often, not at the session's expense).
A viewer that subscribes late is sent each topic's latest message and the last `backlog`
events."""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import replace
from typing import Any

from sgloc.errors import SglocError
from sgloc.live import view_messages as vm
from sgloc.optional import require

log = logging.getLogger("sgloc.live")
DEFAULT_VIEW_HOST, DEFAULT_VIEW_PORT = "127.0.0.1", 8765


class FleetView:
    """The fleet served to Foxglove (`start`, `update`, `stop`; or `with FleetView(...)`).

    Args:
        host, port: where the WebSocket server listens (loopback by default; port 0: any free
            port, see `port`).
        rate: snapshots per second at most. object_size: the map's spheres' diameter (m).
        backlog: events sent again to a viewer that subscribes late.
    """

    def __init__(self, host: str = DEFAULT_VIEW_HOST, port: int = DEFAULT_VIEW_PORT,
                 rate: float = 2.0, object_size: float = 1.0, backlog: int = 100) -> None:
        if not rate > 0:
            raise SglocError(f"the live view's rate must be > 0 per second, got {rate!r}.")
        self.host, self.rate, self.object_size = host, float(rate), float(object_size)
        self._port = int(port)
        self._server = self._thread = None
        self._channels: dict[str, Any] = {}
        self._last: dict[str, Any] = {}  # topic -> its latest message
        self._sent: vm.FleetSnapshot | None = None  # the last snapshot sent
        self._events: deque = deque(maxlen=backlog)
        self._cv = threading.Condition()
        self._pending: vm.FleetSnapshot | None = None
        self._resend: set[str] = set()
        self._closing = False
        self._busy = False
        self._at = -float("inf")
        self._rest_until = -float("inf")  # the view thread's own limit (`_run`)
        self._key: tuple | None = None
        self._n_events = 0

    # -- life cycle ----------------------------------------------------------------------------
    def start(self) -> FleetView:
        """Start the WebSocket server and the view's thread."""
        fg = require("foxglove", "live", "--view (the live view in Foxglove)")
        self._ctx = fg.Context()
        try:
            self._server = fg.start_server(name="sgloc", host=self.host, port=self._port,
                                           context=self._ctx, server_listener=_listener(self))
        except RuntimeError as e:
            why = str(e).rsplit(": ", 1)[-1]
            fix = ("choose another --view-port (Python: ServeOptions.view_port) or stop what "
                   "uses it" if "in use" in why else "check --view-host and --view-port "
                   "(Python: ServeOptions.view_host, view_port)")
            raise SglocError(f"the live view cannot listen on {self.host}:{self._port} ({why}): "
                             f"{fix}.") from None
        for topic in (vm.MAP, vm.LINKS, vm.TF, vm.EVENTS):
            self._channel(topic)
        self._thread = threading.Thread(target=self._run, name="sgloc-view", daemon=True)
        self._thread.start()
        log.info("live view on %s", self.url)
        return self

    def stop(self) -> None:
        """Send what is pending, then stop the server."""
        with self._cv:
            self._closing = True
            self._cv.notify_all()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._server is not None:
            self._port = self._server.port
            self._server.stop()
            self._server = None

    def __enter__(self) -> FleetView:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return self._server.port if self._server is not None else self._port

    @property
    def url(self) -> str:
        """The address a Foxglove viewer connects to."""
        return f"ws://{self.host}:{self.port}"

    # -- the session's thread ------------------------------------------------------------------
    def update(self, session: Any, force: bool = False) -> bool:
        """Hand a snapshot of `session` to the view when `1/rate` s passed since the last and
        the session changed (`force`: now, whatever changed). Never waits for the viewers;
        call it on the thread that owns the session. True when a snapshot was taken."""
        now = time.monotonic()
        if not force and (now - self._at < 1.0 / self.rate or now < self._rest_until):
            return False
        self._at = now
        key = (session.revision, len(session.events),
               tuple(len(session.keyframes(r)[0]) for r in session.robots))
        if key == self._key and not force:
            return False
        self._key = key
        snap = vm.snapshot(session, self._n_events)
        self._n_events = len(session.events)
        with self._cv:
            if self._pending is not None:  # not sent yet: replaced, its events kept
                snap = replace(snap, events=self._pending.events + snap.events)
            self._pending = snap
            self._cv.notify_all()
        return True

    def flush(self, timeout: float = 10.0) -> bool:
        """Wait until every handed snapshot is sent; False on timeout."""
        with self._cv:
            return self._cv.wait_for(lambda: self._pending is None and not self._busy, timeout)

    # -- the view's thread ---------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._cv:
                self._cv.wait_for(lambda: self._pending is not None or self._resend
                                  or self._closing)
                snap, self._pending = self._pending, None
                resend, self._resend = self._resend, set()
                if snap is None and not resend and self._closing:
                    return
                self._busy = True
            t0 = time.monotonic()
            try:
                if snap is not None:
                    self._publish(snap)
                for topic in resend:
                    self._send_again(topic)
            except Exception as e:  # noqa: BLE001 - the view must not take the server down
                log.warning("the live view could not send an update: %s", e)
            # Building messages holds the GIL: on a large fleet the view rests twice as long
            # as it worked, so it takes a third of the session thread's time at most.
            self._rest_until = time.monotonic() + 2.0 * (time.monotonic() - t0)
            with self._cv:
                self._busy = False
                self._cv.notify_all()

    def _publish(self, snap: vm.FleetSnapshot) -> None:
        """Send the topics that changed since the last snapshot sent, and the new events."""
        for topic, m in vm.messages(snap, self.object_size, self._sent).items():
            self._channel(topic).log(m, log_time=snap.stamp_ns)
            self._last[topic] = m
        self._sent = snap
        for m in vm.event_messages(snap):
            self._channel(vm.EVENTS).log(m, log_time=snap.stamp_ns)
            self._events.append(m)

    def _send_again(self, topic: str) -> None:
        """A late subscriber's first messages: the topic's latest (the events' backlog)."""
        if topic == vm.EVENTS:
            for m in list(self._events):
                self._channel(topic).log(m)
        elif topic in self._last:
            self._channel(topic).log(self._last[topic])

    def _channel(self, topic: str) -> Any:
        ch = self._channels.get(topic)
        if ch is None:
            fc = require("foxglove.channels", "live", "--view (the live view in Foxglove)")
            kind = {vm.TF: fc.FrameTransformsChannel, vm.EVENTS: fc.LogChannel}.get(
                topic, fc.SceneUpdateChannel)
            ch = self._channels[topic] = kind(topic, context=self._ctx)
        return ch

    def _subscribed(self, topic: str) -> None:
        with self._cv:
            self._resend.add(topic)
            self._cv.notify_all()


def _listener(view: FleetView) -> Any:
    """foxglove's callbacks (on its own thread): a new subscription asks for a resend."""
    ws = require("foxglove.websocket", "live", "--view (the live view in Foxglove)")

    class Listener(ws.ServerListener):  # the protocol's defaults for every other callback
        def on_subscribe(self, client: Any, channel: Any) -> None:
            view._subscribed(channel.topic)

    return Listener()
