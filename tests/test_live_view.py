"""The live view over a real Foxglove WebSocket connection (no mocks): a protocol-level client
(tornado, subprotocol foxglove.sdk.v1) takes the advertise, subscribes, and decodes each
message with the schema the server advertised (protobuf); what it decodes is the session's
fleet map, trajectories, links, transforms and events. The server listens on loopback unless
told otherwise, and a port in use or a missing extra is a one-line error. The city streamed
over Zenoh to a server with the view reaches a viewer whole."""

from __future__ import annotations

import asyncio
import base64
import json
import socket
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("foxglove")
pytest.importorskip("tornado")
pytest.importorskip("google.protobuf")

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402
from tornado.websocket import websocket_connect  # noqa: E402

from sgloc import lie  # noqa: E402
from sgloc.errors import SglocError  # noqa: E402
from sgloc.live import view_messages as vm  # noqa: E402
from sgloc.live.view import FleetView  # noqa: E402
from sgloc.maps.classes import class_colours  # noqa: E402
from sgloc.online import OnlineConfig, OnlineSession  # noqa: E402
from sgloc.optional import MissingExtraError  # noqa: E402
from sgloc.replay.outputs import fleet_maps, merged_map  # noqa: E402

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
T_AB = lie.se3_exp([0, 0, 0.4, 60.0, -5.0, 0.0])


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _add(s: OnlineSession, robot: str, k: int, pts: np.ndarray, labels: np.ndarray) -> None:
    s.add_keyframe(robot, float(k), lie.se3_exp([0, 0, 0.1 * k, 4.0 * k, 0, 0]), pts, labels)


@pytest.fixture
def session() -> OnlineSession:
    """Robots a (the root) and b placed by an added link, c unplaced; keyframe back-end."""
    s = OnlineSession(online=OnlineConfig(backend="keyframes", min_observations=1,
                                          max_attempts=0, solver="scipy"))
    rng = np.random.default_rng(3)
    pts, labels = rng.uniform(-20, 20, (12, 3)), rng.integers(0, 5, 12)
    for k in range(4):
        for r in ("a", "b", "c"):
            _add(s, r, k, pts, labels)
    s.add_link("a", "b", T_AB, np.eye(6) * 1e-4)
    assert sorted(s.corrections()) == ["a", "b"] and len(s.links) == 1
    return s


# -- a Foxglove WebSocket client -----------------------------------------------------------------
def _decoder(channel: dict):
    """The protobuf message class of an advertised channel, from its FileDescriptorSet."""
    assert channel["encoding"] == "protobuf"
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool, files = descriptor_pool.DescriptorPool(), list(fds.file)
    while files:  # dependencies first, in whatever order the set lists them
        f = files.pop(0)
        try:
            pool.Add(f)
        except TypeError:
            files.append(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


class Client:
    """Connects, takes serverInfo and the advertised channels, subscribes, decodes."""

    def __init__(self, port: int, host: str = "127.0.0.1") -> None:
        self.url = f"ws://{host}:{port}/"
        self.channels: dict[str, dict] = {}  # topic -> advertised channel
        self.subs: dict[int, str] = {}  # subscription id -> topic
        self.got: dict[str, list] = {}  # topic -> decoded messages, in order

    async def connect(self, topics: set[str], timeout: float = 5.0) -> None:
        self.ws = await websocket_connect(self.url, subprotocols=SUBPROTOCOLS)
        assert self.ws.selected_subprotocol in SUBPROTOCOLS
        end = time.monotonic() + timeout
        while not topics <= self.channels.keys():
            self._take(await self._read(end))
        subs = [{"id": i, "channelId": self.channels[t]["id"]} for i, t in enumerate(topics)]
        self.subs = dict(enumerate(topics))
        self.decoders = {t: _decoder(self.channels[t]) for t in topics}
        await self.ws.write_message(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def _read(self, end: float):
        m = await asyncio.wait_for(self.ws.read_message(), max(end - time.monotonic(), 0.01))
        assert m is not None, "the server closed the connection"
        return m

    def _take(self, m) -> None:
        if isinstance(m, str):
            d = json.loads(m)
            if d["op"] == "advertise":
                self.channels.update({c["topic"]: c for c in d["channels"]})
            return
        op, sub, _ = struct.unpack_from("<BIQ", m)
        if op == 1:  # Message Data: opcode, subscription id, timestamp, payload
            topic = self.subs[sub]
            self.got.setdefault(topic, []).append(self.decoders[topic].FromString(m[13:]))

    async def until(self, done, timeout: float = 10.0) -> None:
        """Read until `done(self.got)`."""
        end = time.monotonic() + timeout
        while not done(self.got):
            self._take(await self._read(end))

    def close(self) -> None:
        self.ws.close()


def _matrix(t, q) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = t.x, t.y, t.z
    return T


def _xyz(points) -> np.ndarray:
    return np.array([[p.x, p.y, p.z] for p in points]).reshape(-1, 3)


def _rgb(c) -> tuple:
    return tuple(round(v * 255) for v in (c.r, c.g, c.b))


# -- what the client decodes is the session ------------------------------------------------------
def _check_scene(got: dict, s: OnlineSession) -> None:
    exp = merged_map(fleet_maps(s, s.robots), s.online.fuse_radius)
    assert len(exp) == len(s.map("a")) + len(s.map("b"))  # 60 m apart: nothing fused
    (ent,) = got[vm.MAP][-1].entities
    assert ent.frame_id == "map" and len(ent.spheres) == len(exp)
    np.testing.assert_allclose(_xyz([sp.pose.position for sp in ent.spheres]), exp.positions,
                               atol=1e-9)
    assert [_rgb(sp.color) for sp in ent.spheres] == [
        tuple(int(h[i:i + 2], 16) for i in (1, 3, 5)) for h in class_colours(exp.labels)]
    for r in ("a", "b"):
        (line,) = got[vm.trajectory_topic(r)][-1].entities[0].lines
        np.testing.assert_allclose(_xyz(line.points), s.trajectory(r)[1][:, :3, 3], atol=1e-9)
    assert got[vm.trajectory_topic("c")][-1].deletions[0].id == "c/trajectory"  # unplaced
    tf = {(t.parent_frame_id, t.child_frame_id): _matrix(t.translation, t.rotation)
          for t in got[vm.TF][-1].transforms}
    assert set(tf) == {("map", "a/odom"), ("map", "b/odom"), ("a/odom", "a/base_link"),
                       ("b/odom", "b/base_link"), ("c/odom", "c/base_link")}
    for r in ("a", "b"):
        np.testing.assert_allclose(tf["map", f"{r}/odom"], s.T_fleet_robot(r), atol=1e-9)
        np.testing.assert_allclose(tf[f"{r}/odom", f"{r}/base_link"], s.keyframes(r)[1][-1],
                                   atol=1e-9)
    np.testing.assert_allclose(tf["map", "b/odom"], T_AB, atol=1e-6)
    (lk,) = s.links
    (links,) = got[vm.LINKS][-1].entities[0].lines
    ends = [s.trajectory(lk.robot_a)[1][lk.keyframe_a, :3, 3],
            s.trajectory(lk.robot_b)[1][lk.keyframe_b, :3, 3]]
    np.testing.assert_allclose(_xyz(links.points), ends, atol=1e-9)
    np.testing.assert_allclose([(c.r, c.g, c.b, c.a) for c in links.colors], [vm.ACTIVE] * 2)


def _has(topics, n_events: int):
    return lambda got: all(t in got for t in topics) and len(got.get(vm.EVENTS, [])) >= n_events


TOPICS = {vm.MAP, vm.LINKS, vm.TF, vm.EVENTS} | {vm.trajectory_topic(r) for r in "abc"}


def test_a_viewer_decodes_the_sessions_fleet_and_follows_it(session):
    s = session
    with FleetView(port=0) as view:
        assert view.update(s, force=True) and view.flush()

        async def run():
            c = Client(view.port)  # connects after the update: sent the latest again
            await c.connect(TOPICS)
            await c.until(_has(TOPICS, len(s.events)))
            _check_scene(c.got, s)
            logs = c.got[vm.EVENTS]
            assert [g.message for g in logs] == [
                f"t={e.stamp:.3f} s {e.kind} {', '.join(e.robots)}: {e.detail}"
                for e in s.events]
            # the session moves on: a's new keyframe reaches the viewer at the next update
            n = len(s.keyframes("a")[0])
            _add(s, "a", n, s.map("a").positions[:3], s.map("a").labels[:3])
            time.sleep(1.0 / view.rate)
            assert view.update(s)
            assert not view.update(s)  # within 1/rate s of the last: no snapshot
            traj = vm.trajectory_topic("a")
            await c.until(lambda got: len(got[traj][-1].entities[0].lines[0].points) == n + 1)
            _check_scene(c.got, s)
            c.close()

        asyncio.run(run())


def test_the_messages_decode_without_a_socket(session):
    s = session
    snap = vm.snapshot(s)
    got = {}
    for topic, m in vm.messages(snap).items():
        kind = {vm.TF: "FrameTransforms"}.get(topic, "SceneUpdate")
        schema = m.get_schema()
        assert schema.name == f"foxglove.{kind}" and schema.encoding == "protobuf"
        channel = {"encoding": "protobuf", "schemaName": schema.name,
                   "schema": base64.b64encode(schema.data).decode()}
        got[topic] = [_decoder(channel).FromString(m.encode())]
    _check_scene(got, s)
    assert len(vm.event_messages(snap)) == len(s.events) > 0
    assert vm.event_messages(vm.snapshot(s, len(s.events))) == []  # only the new ones


def test_an_update_sends_only_the_topics_that_changed(session):
    s = session
    first = vm.snapshot(s)
    assert vm.changed(first, None) == set(vm.messages(first)) == TOPICS - {vm.EVENTS}
    assert vm.changed(vm.snapshot(s), first) == {vm.TF}  # nothing moved: only /tf again
    _add(s, "c", 4, s.map("a").positions[:2], s.map("a").labels[:2])  # c is not placed
    assert vm.changed(vm.snapshot(s), first) == {vm.TF}
    _add(s, "a", 4, s.map("a").positions[:2], s.map("a").labels[:2])
    now = vm.snapshot(s)
    assert {vm.trajectory_topic("a"), vm.TF} <= vm.changed(now, first)
    assert vm.trajectory_topic("c") not in vm.changed(now, first)
    assert set(vm.messages(now, before=first)) == vm.changed(now, first)


def _listening(port: int) -> list[str]:
    """The local addresses of the sockets listening on `port` (Linux /proc/net/tcp*)."""
    out = []
    for name, width in (("/proc/net/tcp", 8), ("/proc/net/tcp6", 32)):
        try:
            lines = open(name).read().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            local, _, state = line.split()[1:4]
            addr, p = local.split(":")
            if state == "0A" and int(p, 16) == port and len(addr) == width:
                raw = bytes.fromhex(addr)
                words = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
                fam = socket.AF_INET if width == 8 else socket.AF_INET6
                out.append(socket.inet_ntop(fam, words))
    return out


def _outside_address() -> str | None:
    """This machine's address on its default route, when it has one off loopback."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
            u.connect(("10.255.255.255", 1))  # no packet is sent: picks the interface
            ip = u.getsockname()[0]
    except OSError:
        return None
    return None if ip.startswith("127.") else ip


def test_the_view_listens_on_loopback_only_by_default():
    from sgloc.live.server import ServeOptions

    assert ServeOptions().view_host == FleetView().host == "127.0.0.1"
    assert not ServeOptions().view
    with FleetView(port=0) as view:
        if not sys.platform.startswith("linux"):
            pytest.skip("reads /proc/net/tcp")
        assert _listening(view.port) == ["127.0.0.1"]
        ip = _outside_address()
        if ip is not None:
            with socket.socket() as probe:
                probe.settimeout(2.0)
                assert probe.connect_ex((ip, view.port)) != 0


def test_a_port_in_use_is_a_one_line_error():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        with pytest.raises(SglocError) as e:
            FleetView(port=port).start()
        assert f"127.0.0.1:{port}" in str(e.value) and "--view-port" in str(e.value)
        assert "\n" not in str(e.value)
        pytest.importorskip("zenoh")
        proc = subprocess.run(
            [sys.executable, "-m", "sgloc", "serve", "--view", "--view-port", str(port),
             "--listen", f"tcp/127.0.0.1:{_port()}", "--seconds", "1", "--quiet"],
            capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    assert len(lines) == 1 and f"127.0.0.1:{port}" in lines[0], lines


def test_a_host_that_cannot_be_listened_on_is_a_one_line_error():
    with pytest.raises(SglocError, match="--view-host") as e:
        FleetView(host="no-such-host.invalid", port=0).start()
    assert "no-such-host.invalid" in str(e.value) and "\n" not in str(e.value)


def test_without_foxglove_the_view_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove: ImportError
    with pytest.raises(MissingExtraError, match=r"pip install 'sgloc\[live\]'"):
        FleetView(port=0).start()


def test_a_server_with_view_shows_the_robots_it_serves():
    pytest.importorskip("zenoh")
    from sgloc.live.client import RobotClient
    from sgloc.live.server import LiveServer, ServeOptions

    ep = f"tcp/127.0.0.1:{_port()}"
    rng = np.random.default_rng(5)
    pts, labels = rng.uniform(-10, 10, (8, 3)), rng.integers(0, 4, 8)
    online = OnlineConfig(backend="keyframes", min_observations=1, solver="scipy")
    opts = ServeOptions(listen=ep, sync=True, view=True, view_port=0, view_rate=20.0)
    with LiveServer(online=online, options=opts) as srv, RobotClient("r0", ep) as robot:
        for k in range(3):
            T = lie.se3_exp([0, 0, 0.05 * k, 2.0 * k, 0, 0])
            assert robot.wait_correction(robot.send_keyframe(10**9 * (k + 1), T, pts, labels))

        async def run():
            c = Client(srv.view.port)
            traj = vm.trajectory_topic("r0")
            await c.connect({vm.TF, traj})

            def three(got):
                return traj in got and len(got[traj][-1].entities[0].lines[0].points) == 3
            await c.until(three)
            tf = {(t.parent_frame_id, t.child_frame_id): _matrix(t.translation, t.rotation)
                  for t in c.got[vm.TF][-1].transforms}
            c.close()
            return tf

        tf = asyncio.run(run())
        np.testing.assert_allclose(tf["map", "r0/odom"], srv.session.T_fleet_robot("r0"),
                                   atol=1e-9)
        np.testing.assert_allclose(tf["r0/odom", "r0/base_link"],
                                   srv.session.keyframes("r0")[1][-1], atol=1e-9)


def test_the_city_streamed_to_a_server_with_view_is_seen_whole():
    """Four robots of the city over Zenoh (lockstep, --sync) while a viewer watches: at the
    end it holds the server's fleet map, every link, transform and event."""
    pytest.importorskip("zenoh")
    from sgloc.evaluation.replay_scenarios import city_scenario
    from sgloc.live.server import LiveServer, ServeOptions
    from sgloc.live.stream import stream_logs
    from sgloc.pipeline.presets import localizer_preset

    ep = f"tcp/127.0.0.1:{_port()}"
    opts = ServeOptions(listen=ep, sync=True, view=True, view_port=0)
    logs = city_scenario(4, 0).logs
    with LiveServer(localizer_preset("city-objects"), OnlineConfig(), opts) as srv:
        s = srv.session

        async def run():
            c = Client(srv.view.port)
            await c.connect({vm.MAP, vm.LINKS, vm.TF, vm.EVENTS})
            await asyncio.to_thread(stream_logs, logs, ep, rate=0, lockstep=True, timeout=30)
            assert await asyncio.to_thread(srv.wait_idle, 30)
            n = len(merged_map(fleet_maps(s, s.robots), s.online.fuse_radius))
            await c.until(lambda got: len(got.get(vm.EVENTS, [])) == len(s.events)
                          and {vm.MAP, vm.TF} <= got.keys()
                          and len(got[vm.MAP][-1].entities[0].spheres) == n
                          and len(got[vm.TF][-1].transforms) == 2 * len(s.robots), timeout=15)
            c.close()
            return c.got

        got = asyncio.run(run())
    exp = merged_map(fleet_maps(s, s.robots), s.online.fuse_radius)
    assert len(s.corrections()) == 4 and len(s.links) > 0
    spheres = got[vm.MAP][-1].entities[0].spheres
    np.testing.assert_allclose(_xyz([sp.pose.position for sp in spheres]), exp.positions,
                               atol=1e-9)
    assert len(got[vm.LINKS][-1].entities[0].lines[0].points) == 2 * sum(
        not lk.revoked for lk in s.links)
    tf = {(t.parent_frame_id, t.child_frame_id): _matrix(t.translation, t.rotation)
          for t in got[vm.TF][-1].transforms}
    for r, T in s.corrections().items():
        np.testing.assert_allclose(tf["map", f"{r}/odom"], T, atol=1e-9)
