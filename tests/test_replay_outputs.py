"""`sgloc replay`'s outputs agree with their inputs and with each other: exact event stamps, one
bag message per robot and stamp, links.g2o ids named in g2o_keyframes.csv / summary.json,
revocation counts from the events, a reason for every unplaced robot, versioned JSON, corrected
maps and a merged fleet map on the true objects."""

from __future__ import annotations

import csv
import dataclasses
import json

import numpy as np
import pytest

from sgloc.cli import main
from sgloc.evaluation.replay_scenarios import lost_robot, world_scenario
from sgloc.geometry import apply, invert
from sgloc.io.g2o import read_g2o
from sgloc.io.keyframes import format_stamp, make_robot_log
from sgloc.io.plain_layout import write_plain_layout
from sgloc.io.poses import read_tum
from sgloc.maps.graph import SemanticGraph
from sgloc.online import OnlineConfig, OnlineSession
from sgloc.replay import outputs
from sgloc.replay.stream import ReplayRecord

#: Real-clock stamps: 1.7e9 s, where float seconds cannot hold every nanosecond.
OFFSET_NS = 1_700_000_043_750_000_000


def _logs():
    """world0 renamed `zulu`, world1 renamed `alpha` and starting 3 s later (so the order of
    first keyframes is not the alphabetical order), and `lost`, a robot in another world."""
    w = world_scenario()
    zulu = dataclasses.replace(w.logs[0], name="zulu", stamps_ns=w.logs[0].stamps_ns + OFFSET_NS)
    alpha = dataclasses.replace(w.logs[1], name="alpha",
                                stamps_ns=w.logs[1].stamps_ns + OFFSET_NS + 3_000_000_001)
    return [zulu, alpha, lost_robot(OFFSET_NS)]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("replay_outputs")
    logs = _logs()
    write_plain_layout(d / "run", logs)
    argv = ["replay", str(d / "run"), "--out", str(d / "out")]
    try:
        import rosbags  # noqa: F401

        argv += ["--out-bag", str(d / "bag")]
    except ImportError:
        pass
    return d, logs, argv


@pytest.fixture(scope="module")
def replayed(run):
    import contextlib
    import io

    d, logs, argv = run
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(argv) == 0
    return d, logs, json.loads((d / "out" / "summary.json").read_text()), out.getvalue()


def test_event_stamps_are_the_input_stamps_exactly(replayed):
    d, logs, _, _ = replayed
    stamps = {format_stamp(s) for g in logs for s in g.stamps_ns}
    rows = list(csv.DictReader((d / "out" / "events.csv").open()))
    assert any(r["kind"] == "robot_joined" for r in rows)
    for r in rows:
        assert r["stamp"] in stamps, r


def test_the_bag_holds_one_transform_per_robot_and_stamp(replayed):
    pytest.importorskip("rosbags")
    from sgloc.io.rosbag import read_fleet_bag

    d, _, summary, _ = replayed
    msgs = read_fleet_bag(d / "bag")
    keys = [(ns, r) for ns, r, _ in msgs]
    assert len(keys) == len(set(keys))
    assert {r for _, r in keys} == {r for r, v in summary["robots"].items() if v["placed"]}


def test_fleet_bag_writer_keeps_the_last_of_repeated_transforms(tmp_path):
    pytest.importorskip("rosbags")
    from sgloc.io.rosbag import read_fleet_bag, write_fleet_bag

    a, b = np.eye(4), np.eye(4)
    b[0, 3] = 5.0
    write_fleet_bag(tmp_path / "b", [(7, "r", a), (3, "s", a), (7, "r", b), (7, "s", a)])
    back = read_fleet_bag(tmp_path / "b")
    assert [(ns, r) for ns, r, _ in back] == [(3, "s"), (7, "r"), (7, "s")]
    np.testing.assert_array_equal(back[1][2], b)


@pytest.fixture(scope="module")
def replayed_robots(run):
    """The same replay with the back-end "robots" (one rigid frame per robot)."""
    d, logs, argv = run
    out = d / "out_robots"
    assert main([*argv[:3], str(out), "--backend", "robots", "--quiet"]) == 0
    return out, logs, json.loads((out / "summary.json").read_text())


def _keyframe_table(folder, summary):
    """[(vertex, robot, keyframe, stamp)] of the g2o_keyframes.csv summary.json names."""
    with (folder / summary["g2o_keyframes"]).open() as f:
        return [(int(r["vertex"]), r["robot"], int(r["keyframe"]), r["stamp"])
                for r in csv.DictReader(f)]


def test_g2o_vertex_ids_are_named_in_the_summary(replayed):
    """Back-end keyframes: a vertex per keyframe of a placed robot, named in g2o_keyframes,
    at that keyframe's pose in fleet/<robot>.tum; odometry and link edges between them."""
    d, logs, summary, _ = replayed
    assert list(summary["robots"]) == sorted(g.name for g in logs)  # the layout's order
    assert summary["backend"] == "keyframes"
    vertices, edges = read_g2o(d / "out" / "links.g2o")
    placed = {r: v for r, v in summary["robots"].items() if v["placed"]}
    table = _keyframe_table(d / "out", summary)
    named = {vid: (r, k) for vid, r, k, _ in table}
    assert sorted(vertices) == sorted(named) and {r for r, _ in named.values()} == set(placed)
    by_name = {g.name: g for g in logs}
    assert all(st == format_stamp(by_name[r].stamps_ns[k]) for _, r, k, st in table)
    assert all(v["g2o_vertex"] is None for v in placed.values())
    tum = {r: read_tum(d / "out" / v["file"]) for r, v in placed.items()}
    for vid, (r, k) in named.items():
        _, xyz, quat = tum[r]
        T = dataclasses.replace(by_name[r], xyz=xyz, quat=quat).poses[k]
        np.testing.assert_allclose(vertices[vid], T, atol=1e-6)
    assert edges and all(a in named and b in named for a, b, _, _ in edges)
    robots_linked = {(named[a][0], named[b][0]) for a, b, _, _ in edges}
    assert any(ra != rb for ra, rb in robots_linked)  # a link between two robots


def test_g2o_vertex_ids_are_named_in_the_summary_with_one_frame_per_robot(replayed_robots):
    d, logs, summary = replayed_robots
    assert summary["backend"] == "robots" and summary["g2o_keyframes"] is None
    assert not (d / outputs.KEYFRAMES).exists()
    vertices, edges = read_g2o(d / "links.g2o")
    placed = {r: v for r, v in summary["robots"].items() if v["placed"]}
    assert sorted(vertices) == sorted(v["g2o_vertex"] for v in placed.values())
    by_name = {g.name: g for g in logs}
    for name, v in placed.items():
        _, xyz, quat = read_tum(d / v["file"])
        T_fleet_sensor = dataclasses.replace(by_name[name], xyz=xyz, quat=quat).poses[0]
        T_fleet_odom = T_fleet_sensor @ invert(by_name[name].poses[0])
        np.testing.assert_allclose(vertices[v["g2o_vertex"]], T_fleet_odom, atol=1e-6)
    ids = {v["g2o_vertex"] for v in placed.values()}
    assert edges and all(a in ids and b in ids for a, b, _, _ in edges)


def test_an_unplaced_robot_gets_its_reason_everywhere(replayed):
    d, _, summary, stdout = replayed
    lost = summary["robots"]["lost"]
    assert not lost["placed"] and "attempts passed the acceptance test" in lost["unplaced_reason"]
    assert summary["robots"]["alpha"]["unplaced_reason"] is None
    assert f"lost not placed: {lost['unplaced_reason']}" in " ".join(stdout.split())
    rows = list(csv.DictReader((d / "out" / "events.csv").open()))
    mine = [r for r in rows if r["kind"] == "robot_not_placed"]
    assert [(r["robots"], r["detail"]) for r in mine] == [("lost", lost["unplaced_reason"])]


def test_summary_is_versioned_and_counts_revocations_from_the_events():
    s = OnlineSession(online=OnlineConfig(backend="robots"))
    rng = np.random.default_rng(0)
    for r in ("a", "b"):
        s.add_keyframe(r, 1.0, np.eye(4), rng.uniform(-20, 20, (20, 3)), rng.integers(0, 4, 20))
    T2 = np.eye(4)
    T2[0, 3] = 40.0
    s.add_link("a", "b", np.eye(4), np.eye(6) * 1e-4, 0.9, 2.0)
    s.add_link("a", "b", T2, np.eye(6) * 1e-4, 0.9, 3.0)  # disagrees: the first is revoked
    assert [e.kind for e in s.events].count("link_revoked") == 1
    assert all(lk.active for lk in s.links)
    logs = [make_robot_log(r, [1], [[0, 0, 0]], [[0, 0, 0, 1.0]], [], np.zeros((0, 3)), [])
            for r in ("a", "b")]
    rec = ReplayRecord({"a": np.ones(1), "b": np.ones(1)}, {"a": 1, "b": 3})
    summary = outputs.replay_summary(logs, s, rec, {"a": "a", "b": "b"})
    assert summary["schema"] == "sgloc.replay/2"
    assert summary["links_revoked"] == summary["events"]["link_revoked"] == 1
    assert summary["links_active"] == 1 and summary["links_inactive"] == 0


def test_every_summary_key_is_documented(replayed):
    import re
    from pathlib import Path

    _, _, summary, _ = replayed
    doc = (Path(__file__).resolve().parents[1] / "docs" / "fleet_outputs.md").read_text()
    documented = {k for c in re.findall(r"^\| ([^|]+) \|", doc, flags=re.M)
                  for k in re.findall(r"`([a-z_0-9]+)`", c)}
    keys = set(summary) | {k for r in summary["robots"].values() for k in r}
    assert keys <= documented, keys - documented


def test_keyframe_backend_writes_corrected_keyframes_and_the_whole_graph(tmp_path):
    """--backend keyframes: fleet/<robot>.tum holds the pose graph's keyframes (not the odometry
    moved by one frame) and links.g2o the whole graph, odometry edges included, its vertices
    named in summary.json."""
    import contextlib
    import io

    logs = world_scenario().logs
    write_plain_layout(tmp_path / "run", logs)
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["replay", str(tmp_path / "run"), "--out", str(tmp_path / "out"),
                     "--backend", "keyframes"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["backend"] == "keyframes" and summary["placed"] == len(logs)
    ids = _keyframe_table(tmp_path / "out", summary)
    assert len(ids) == sum(len(g) for g in logs)
    vertices, edges = read_g2o(tmp_path / "out" / "links.g2o")
    assert sorted(vertices) == sorted(v for v, _, _, _ in ids)
    assert len(edges) >= len(ids) - 1  # an odometry edge per consecutive keyframe pair at least
    for g in logs:  # the written poses are the session's keyframes, one line each
        stamps, xyz, quat = read_tum(tmp_path / "out" / "fleet" / f"{g.name}.tum")
        assert len(stamps) == len(g) and np.isfinite(xyz).all()
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["replay", str(tmp_path / "run"), "--out", str(tmp_path / "bad"),
                     "--backend", "rigid"]) == 2


def _true_objects():
    """The object world of `world_scenario()` (positions (n,3) m, labels), in its world frame."""
    from sgloc.sim.object_world import make_object_world

    return make_object_world(np.random.default_rng([0, 23]), length=360.0)


def _nearest_same_class(pos, lab, ref_pos, ref_lab):
    """(n,) metres from each object to the nearest reference object of its class."""
    d = np.linalg.norm(pos[:, None] - ref_pos[None], axis=-1)
    return np.where(lab[:, None] == ref_lab[None], d, np.inf).min(axis=1)


@pytest.mark.parametrize("which", ["replayed", "replayed_robots"])
def test_corrected_maps_and_the_merged_map_lie_on_the_true_objects(which, request):
    """maps/<robot>.json holds each placed robot's objects in the fleet frame (the root's
    odometry frame), merged.json those of all placed robots fused: mapped into the world by the
    root's true frame, they lie on the world's objects; the unplaced robot has no map and none
    of its objects enter the merged map."""
    got = request.getfixturevalue(which)
    out, summary = (got[0] / "out", got[2]) if which == "replayed" else (got[0], got[2])
    truth = {"zulu": "world0", "alpha": "world1"}
    T_world_fleet = world_scenario().T_gt_odom[truth[summary["root"]]]
    ref_pos, ref_lab = _true_objects()
    maps = {}
    for name, r in summary["robots"].items():
        assert (r["map"] is None) == (not r["placed"])
        if r["placed"]:
            g = SemanticGraph.load(out / r["map"])
            maps[name] = g
            err = _nearest_same_class(apply(T_world_fleet, g.positions), g.labels, ref_pos,
                                      ref_lab)
            assert len(g) > 20 and np.median(err) < 0.5, (name, np.median(err))
    assert set(maps) == {"zulu", "alpha"} and not (out / "maps" / "lost.json").exists()
    merged = SemanticGraph.load(out / summary["merged"])
    assert len(merged) == summary["merged_objects"]
    # the two robots' shared stretch is fused: fewer objects than the two maps together, and
    # every object of either map has a merged object of its class within the fusion radius
    assert len(merged) < sum(len(g) for g in maps.values())
    for g in maps.values():
        assert _nearest_same_class(g.positions, g.labels, merged.positions,
                                   merged.labels).max() <= OnlineConfig().fuse_radius
    err = _nearest_same_class(apply(T_world_fleet, merged.positions), merged.labels, ref_pos,
                              ref_lab)
    assert np.median(err) < 0.5


def test_fleet_maps_are_the_session_maps_moved_by_the_fleet_frames():
    """fleet_maps: each placed robot's confirmed objects moved by T_fleet_robot; none for an
    unplaced robot; merged_map fuses same-class objects of different robots only."""
    s = OnlineSession(online=OnlineConfig(backend="robots", max_attempts=0))  # links given
    rng = np.random.default_rng(1)
    pts, lab = rng.uniform(-20, 20, (20, 3)), rng.integers(0, 4, 20)
    T = np.eye(4)
    T[:3, 3] = [30.0, -5.0, 0.0]
    for r in ("a", "b", "c"):
        for t in (1.0, 2.0):  # two sightings each: the objects are confirmed
            s.add_keyframe(r, t, np.eye(4), pts, lab)
    s.add_link("a", "b", invert(T), np.eye(6) * 1e-4, 0.9, 2.0)
    maps = outputs.fleet_maps(s, ["a", "b", "c"])
    assert set(maps) == {"a", "b"}
    np.testing.assert_allclose(maps["a"].positions, s.map("a").positions)
    T_b = s.T_fleet_robot("b")
    assert np.linalg.norm(T_b[:3, 3]) > 25.0  # robot b's frame is 30 m from the fleet frame
    np.testing.assert_allclose(maps["b"].positions, apply(T_b, s.map("b").positions))
    merged = outputs.merged_map(maps, fuse_radius=1.0)
    assert len(merged) == len(maps["a"]) + len(maps["b"])  # 30 m apart: nothing fused
    same = outputs.merged_map({"a": maps["a"], "a2": maps["a"]}, fuse_radius=1.0)
    np.testing.assert_allclose(same.positions, maps["a"].positions)
