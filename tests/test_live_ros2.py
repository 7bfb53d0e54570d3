"""ROS 2 robots on the live server over real Zenoh sessions on loopback (no mocks, no ROS
install): CDR Odometry + MarkerArray on rmw_zenoh's and zenoh-bridge-ros2dds's keys become
the keyframes the bag reader reads from the same messages; bad payloads are counted and
dropped; /tf, paths and the fleet map decode as ROS 2 messages; `stream --as ros2` places the
city's robots as the replay does."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

pytest.importorskip("zenoh")
pytest.importorskip("rosbags")

from sgloc.errors import SglocError  # noqa: E402
from sgloc.evaluation.replay_scenarios import city_scenario  # noqa: E402
from sgloc.io.keyframes import make_robot_log  # noqa: E402
from sgloc.io.rosbag import MARKERS, ODOMETRY, read_bag, robot_messages, write_bag  # noqa: E402
from sgloc.live import ros2  # noqa: E402
from sgloc.live.server import LiveServer, ServeOptions  # noqa: E402
from sgloc.live.stream import stream_logs  # noqa: E402
from sgloc.live.transport import open_session  # noqa: E402
from sgloc.online import OnlineConfig, OnlineSession  # noqa: E402

TS = ros2.typestore()


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cut(log, n: int):
    """The first `n` keyframes of a robot log."""
    m = int(np.searchsorted(log.keyframe, n))
    return make_robot_log(log.name, log.stamps_ns[:n], log.xyz[:n], log.quat[:n],
                          log.keyframe[:m], log.positions[:m], log.labels[:m])


def _wait(cond, timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.02)


def _matched_publishers(z, keys) -> dict:
    """A publisher per key, each returned once the server's subscription matches it, so that
    nothing is put before the server can receive it."""
    pubs = {key: z.declare_publisher(key) for key in keys}
    _wait(lambda: all(p.matching_status.matching for p in pubs.values()))
    return pubs


def test_cdr_on_rmw_zenoh_and_bridge_keys_gives_the_bag_readers_keyframes(live_city, tmp_path):
    logs, config, _ = live_city
    cut = [_cut(logs[0], 12), _cut(logs[1], 12)]
    bag = {g.name: g for g in read_bag(write_bag(tmp_path / "bag", cut))}
    ep = f"tcp/127.0.0.1:{_port()}"
    keys = {  # robot 0 on rmw_zenoh keys (any type hash), robot 1 as zenoh-bridge-ros2dds
        cut[0].name: (f"0/{cut[0].name}/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_abc",
                      f"0/{cut[0].name}/objects/visualization_msgs::msg::dds_::MarkerArray_/"
                      "TypeHashNotSupported"),
        cut[1].name: (f"{cut[1].name}/odom", f"{cut[1].name}/objects")}
    with LiveServer(config, OnlineConfig(), ServeOptions(listen=ep, sync=True)) as srv:
        z = open_session("client", connect=ep)
        pubs = _matched_publishers(z, [k for pair in keys.values() for k in pair])
        for g in cut:
            for _, odom, markers in robot_messages(g, mark_empty=True):
                pubs[keys[g.name][0]].put(bytes(TS.serialize_cdr(odom, ODOMETRY)))
                pubs[keys[g.name][1]].put(bytes(TS.serialize_cdr(markers, MARKERS)))
        _wait(lambda: srv.counts["keyframes"] == 24)
        z.close()
        s = srv.session
        for g in cut:
            stamps, poses = s.keyframes(g.name)
            ref = bag[g.name]
            assert np.array_equal(np.round(stamps * 1e9).astype(np.int64), ref.stamps_ns)
            assert np.array_equal(poses, ref.poses)
        direct = OnlineSession(config, OnlineConfig())
        for g in bag.values():
            for i, p, lab in g.observations():
                direct.add_keyframe(g.name, g.stamps[i], g.poses[i], p, lab)
        for g in cut:  # the same objects: the same maps
            a, b = s.map(g.name), direct.map(g.name)
            assert np.array_equal(a.positions, b.positions)
            assert np.array_equal(a.labels, b.labels)
        assert srv.counts["received"] == 48 and srv.counts["malformed"] == 0


def test_bad_cdr_payloads_are_counted_and_dropped(live_city, caplog):
    logs, config, _ = live_city
    g = _cut(logs[0], 3)
    msgs = list(robot_messages(g))
    odom = bytes(TS.serialize_cdr(msgs[0][1], ODOMETRY))
    marks = [bytes(TS.serialize_cdr(m[2], MARKERS)) for m in msgs]
    ok, mk = (f"0/{g.name}/odom/nav_msgs::msg::dds_::Odometry_/h",
              f"0/{g.name}/objects/visualization_msgs::msg::dds_::MarkerArray_/h")
    ep = f"tcp/127.0.0.1:{_port()}"
    with LiveServer(config, OnlineConfig(), ServeOptions(listen=ep, sync=True)) as srv:
        z = open_session("client", connect=ep)
        wrong_type = f"0/{g.name}/odom/visualization_msgs::msg::dds_::MarkerArray_/h"
        bad_name = "0/bad.name/objects/visualization_msgs::msg::dds_::MarkerArray_/h"
        pubs = _matched_publishers(z, [ok, mk, wrong_type, bad_name])
        bad = [(ok, b""), (ok, b"\x00\x01\x00\x00garbage"), (ok, odom[:-9]),
               (mk, marks[0][: len(marks[0]) // 2]), (wrong_type, marks[0])]
        for key, payload in [*bad, (mk, marks[0])]:  # markers before any odometry: unpaired
            pubs[key].put(payload)
        pubs[bad_name].put(marks[0])
        pubs[ok].put(odom)
        pubs[mk].put(marks[0])
        _wait(lambda: srv.counts["keyframes"] == 1)
        z.close()
        counts = dict(srv.counts)
    assert counts["malformed"] == len(bad)
    assert counts["unpaired"] == 1 and counts["bad_key"] == 1
    assert not [r for r in caplog.records if r.exc_info or r.levelname == "ERROR"]


def test_stream_as_ros2_places_the_city_and_tf_paths_map_decode(live_city):
    logs, config, ref = live_city
    ep = f"tcp/127.0.0.1:{_port()}"
    got: dict[str, list] = {"tf": [], "path": [], "map": [], "attachment": []}
    lock = threading.Lock()

    def keep(kind, msgtype):
        def receive(sample):
            with lock:
                got[kind].append(TS.deserialize_cdr(sample.payload.to_bytes(), msgtype))
                if kind == "tf":
                    got["attachment"].append(sample.attachment.to_bytes())
        return receive

    with LiveServer(config, OnlineConfig(), ServeOptions(listen=ep, workers=1),
                    root=ref.root) as srv:
        z = open_session("client", connect=ep)
        subs = [z.declare_subscriber("0/tf/tf2_msgs::msg::dds_::TFMessage_/*",
                                     keep("tf", ros2.TF)),
                z.declare_subscriber("0/*/fleet_path/nav_msgs::msg::dds_::Path_/*",
                                     keep("path", ros2.PATH)),
                z.declare_subscriber("0/fleet/map/visualization_msgs::msg::dds_::MarkerArray_/*",
                                     keep("map", MARKERS))]
        rec = stream_logs(logs, ep, rate=2.0, timeout=30, ros2_domain=0)
        assert srv.wait_idle(120)
        assert srv.counts["keyframes"] == rec.sent == sum(len(g) for g in logs)
        s = srv.session
        assert s.corrections().keys() == ref.corrections().keys()
        for r in ref.corrections():  # every keyframe placed, in the fleet frame
            assert len(s.trajectory(r)[1]) == len(ref.trajectory(r)[1]), r
        time.sleep(1.2)  # one more /tf, path and map after the last change
        tokens = [str(t.ok.key_expr) for t in z.liveliness().get("@ros2_lv/0/**") if t.ok]
        with lock:
            tf, path, fleet_map, att = (got[k][-1] for k in ("tf", "path", "map", "attachment"))
            seqs = [int.from_bytes(a[:8], "little") for a in got["attachment"]]
        for sub in subs:
            sub.undeclare()
        z.close()
        assert {t.header.frame_id for t in tf.transforms} == {"map"}
        frames = {t.child_frame_id: t.transform for t in tf.transforms}
        assert frames.keys() == {f"{r}/odom" for r in s.corrections()}
        for r, T in s.corrections().items():
            tr = frames[f"{r}/odom"]
            assert np.allclose([tr.translation.x, tr.translation.y, tr.translation.z],
                               T[:3, 3], atol=1e-9)
            q = tr.rotation
            assert np.allclose(_rotation([q.x, q.y, q.z, q.w]), T[:3, :3], atol=1e-9)
        assert len(att) == 33 and att[16] == 16 and seqs == sorted(seqs) and len(set(seqs)) > 1
        assert path.header.frame_id == "map" and len(path.poses) > 0
        assert fleet_map.markers[0].action == 3 and sum(len(m.points) for m in
                                                        fleet_map.markers[1:]) > 0
        assert any("/MP/" in t and "%tf/tf2_msgs::msg::dds_::TFMessage_/RIHS01_" in t
                   for t in tokens)


def _rotation(q) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(q).as_matrix()


def test_stream_as_ros2_refuses_lockstep_and_serve_a_bad_domain():
    with pytest.raises(SglocError, match="--lockstep"):
        stream_logs(city_scenario(2, 0).logs, "tcp/127.0.0.1:1", lockstep=True, ros2_domain=0)
    with pytest.raises(SglocError, match="--ros2-domain"):
        LiveServer(options=ServeOptions(ros2_domain=999))
    assert ServeOptions(ros2_domain=None).ros2() is None
    assert ServeOptions().ros2().domain == 0  # on by default: rosbags is installed here


def test_one_subscription_per_naming_covers_both_topics():
    rmw, bridge = ros2.subscription_keys(0, "/{robot}/odom", "/{robot}/objects")
    assert (rmw, bridge) == ("0/*/*/*/*", "*/*")
    assert ros2.subscription_keys(3, "/{robot}/odom", "/{robot}/perception/objects") == (
        "3/*/**", "*/**")
    topics = ros2.Topics(ros2.Ros2Options(domain=0))
    assert topics.parse("0/alpha/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_x") == (
        "alpha", "odom", True)
    assert topics.parse("alpha/objects") == ("alpha", "objects", True)
    assert topics.parse("0/alpha/odom/std_msgs::msg::dds_::String_/x") == ("alpha", "odom",
                                                                          False)
    assert topics.parse("0/tf/tf2_msgs::msg::dds_::TFMessage_/x") is None


@pytest.mark.parametrize("sync", [True, False])
def test_ros2_outputs_are_built_only_for_a_subscriber(sync):
    """No ROS 2 subscriber: the server's /tf, path and map publishers match nothing (its own
    ROS 2 input subscriptions do not count), so no output message is built; one subscriber to
    /tf: that publisher matches."""
    from sgloc.live.client import RobotClient

    ep = f"tcp/127.0.0.1:{_port()}"
    with LiveServer(options=ServeOptions(listen=ep, sync=sync, workers=1)) as srv:
        with RobotClient("alpha", ep) as robot:
            robot.sync()
            robot.wait_correction(robot.send_keyframe(
                10**9, np.eye(4), np.arange(9.0).reshape(3, 3), np.arange(3)))
            _wait(lambda: len(srv._ros2.node._pubs) == 3)
            time.sleep(0.5)
            assert not any(p.matched() for p in srv._ros2.node._pubs.values())
            z = open_session("client", connect=ep)
            sub = z.declare_subscriber("0/tf/**", lambda s: None)
            tf = srv._ros2.node.publisher(ros2.TF_TOPIC, ros2.TF)
            _wait(tf.matched)
            sub.undeclare()
            z.close()
