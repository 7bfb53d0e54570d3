"""`sgloc replay`: a small two-robot world streamed through the online session, from the plain
layout and from a bag; every output file; robots never overwrite each other's files."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from sgloc.cli import main
from sgloc.evaluation.online_oracle import oracle_join_stamps, robot_error
from sgloc.evaluation.replay_scenarios import world_scenario
from sgloc.io.names import robot_file_stems
from sgloc.io.plain_layout import write_plain_layout
from sgloc.io.poses import read_tum
from sgloc.replay.stream import check_names, keyframe_order

OUTPUTS = ("events.csv", "links.g2o", "summary.json", "timeline.png", "fleet.png")


@pytest.fixture(scope="module")
def world():
    return world_scenario()


@pytest.fixture(scope="module")
def replayed(world, tmp_path_factory):
    d = tmp_path_factory.mktemp("replay")
    write_plain_layout(d / "run", world.logs)
    assert main(["replay", str(d / "run"), "--out", str(d / "out"), "--quiet"]) == 0
    return d


def test_replay_writes_every_output(replayed, world):
    out = replayed / "out"
    for name in OUTPUTS:
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["root"] == "world0" and summary["placed"] == 2
    for g in world.logs:
        r = summary["robots"][g.name]
        assert r["keyframes"] == len(g) and r["file"] == f"fleet/{g.name}.tum"
        assert r["latency"]["max_ms"] >= r["latency"]["p99_ms"] >= r["latency"]["median_ms"] > 0
        stamps, _, _ = read_tum(out / r["file"])
        assert np.array_equal(stamps, g.stamps_ns)  # real stamps, every keyframe
    joined = float(summary["robots"]["world1"]["joined_stamp"])
    assert 0 < joined < world.logs[1].stamps[-1]
    events = (out / "events.csv").read_text().splitlines()
    assert events[0] == "stamp,kind,robots,detail"
    assert any(",link_accepted,world0;world1," in e for e in events)
    joined_at = summary["robots"]["world1"]["joined_stamp"]
    assert any(e.startswith(f"{joined_at},robot_joined,world1,") for e in events)
    assert sorted(os.listdir(replayed)) == ["out", "run"]  # no staging folder, no lock file


def test_replayed_fleet_frame_is_right(replayed, world):
    """world1's fleet trajectory lands on the ground truth (relative to the root)."""
    _, xyz0, _ = read_tum(replayed / "out" / "fleet" / "world0.tum")
    _, xyz1, _ = read_tum(replayed / "out" / "fleet" / "world1.tum")
    G0, G1 = world.T_gt_odom["world0"], world.T_gt_odom["world1"]
    gt1 = np.linalg.inv(G0) @ G1 @ world.logs[1].poses
    assert np.abs(xyz1 - gt1[:, :3, 3]).max() < 1.0
    # the root's odometry frame is the fleet frame: its first keyframe stays where its odometry
    # put it, the rest moves only as much as the pose graph corrects (exact odometry here)
    assert np.allclose(xyz0[0], world.logs[0].xyz[0])
    assert np.abs(xyz0 - world.logs[0].xyz).max() < 0.2


def test_bag_replay_equals_plain_replay(replayed, world, tmp_path):
    pytest.importorskip("rosbags", reason="rosbags (extra sgloc[ros]) is not installed")
    from sgloc.io.rosbag import read_fleet_bag, write_bag

    write_bag(tmp_path / "bag", world.logs)
    rc = main(["replay", str(tmp_path / "bag"), "--out", str(tmp_path / "out"), "--quiet",
               "--out-bag", str(tmp_path / "fleet_bag")])
    assert rc == 0
    for g in world.logs:
        a = (replayed / "out" / "fleet" / f"{g.name}.tum").read_bytes()
        assert (tmp_path / "out" / "fleet" / f"{g.name}.tum").read_bytes() == a
    g2o = (replayed / "out" / "links.g2o").read_text()
    assert (tmp_path / "out" / "links.g2o").read_text() == g2o
    # the bag's storage file carries the bag's name, not the name of its staging folder
    assert sorted(p.name for p in (tmp_path / "fleet_bag").iterdir()) == [
        ".sgloc-results.json", "fleet_bag.mcap", "metadata.yaml"]
    msgs = read_fleet_bag(tmp_path / "fleet_bag")
    last = {r: T for _, r, T in msgs}
    assert set(last) == {"world0", "world1"}
    _, xyz1, _ = read_tum(tmp_path / "out" / "fleet" / "world1.tum")
    T1 = last["world1"]
    # the last message is T_fleet_odom at the robot's latest keyframe
    np.testing.assert_allclose(xyz1[-1], T1[:3, :3] @ world.logs[1].xyz[-1] + T1[:3, 3],
                               atol=1e-6)


def test_a_results_folder_inside_a_layout_is_no_robot(replayed, tmp_path):
    """An sgloc results folder (its manifest inside) moved into a run folder is not read as a
    robot; the run still reads as its two robots."""
    import shutil

    from sgloc.io.plain_layout import read_plain_layout

    shutil.copytree(replayed / "run", tmp_path / "run")
    shutil.copytree(replayed / "out", tmp_path / "run" / "results")
    assert [g.name for g in read_plain_layout(tmp_path / "run")] == ["world0", "world1"]


def test_a_one_robot_replay_is_not_localized(replayed, tmp_path, capsys):
    """docs/replay.md: exit 0 only when at least two robots share the fleet frame."""
    from sgloc.cli.app import EXIT_NOT_LOCALIZED

    argv = ["replay", str(replayed / "run" / "world0"), "--out", str(tmp_path / "one"), "--quiet"]
    assert main(argv) == EXIT_NOT_LOCALIZED
    assert "holds one robot" in capsys.readouterr().err
    assert (tmp_path / "one" / "summary.json").is_file()  # the outputs still written


def test_robot_file_names_never_collide():
    names = ["team/r1", "team-r1", "Team-R1", "team-r1-2", ".hidden", "a b", "a/b", ""]
    stems = robot_file_stems(names)
    assert len({s.lower() for s in stems.values()}) == len(names)
    assert all("/" not in s and not s.startswith(".") and s for s in stems.values())
    with pytest.raises(ValueError, match="two robots are named"):
        check_names([type("L", (), {"name": "x"})(), type("L", (), {"name": "x"})()])


def test_same_named_files_do_not_overwrite(world, tmp_path):
    """Bag robots `team/r1` and `team r1` would both become fleet/team-r1.tum naively."""
    pytest.importorskip("rosbags", reason="rosbags (extra sgloc[ros]) is not installed")
    from dataclasses import replace

    from sgloc.io.rosbag import write_bag

    logs = [replace(world.logs[0], name="team/r1"), replace(world.logs[1], name="team r1")]
    write_bag(tmp_path / "bag", logs)
    assert main(["replay", str(tmp_path / "bag"), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    files = [summary["robots"][r]["file"] for r in ("team/r1", "team r1")]
    assert len(set(files)) == 2 and all((tmp_path / "out" / f).is_file() for f in files)


def test_keyframes_interleave_by_stamp(world):
    order = keyframe_order(world.logs)
    stamps = np.array([world.logs[r].stamps_ns[k] for r, k in order])
    assert np.all(np.diff(stamps) >= 0) and len(order) == sum(len(g) for g in world.logs)
    assert set(order[:2, 0]) == {0, 1}  # both robots start at 0 s


def test_bad_input_is_one_line_exit_2(tmp_path, capsys):
    (tmp_path / "run" / "r1").mkdir(parents=True)
    assert main(["replay", str(tmp_path / "run"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "odometry.tum" in err[0]
    assert main(["replay", "--kitti00", "--city"]) == 2
    capsys.readouterr()
    assert main(["replay", "--kitti00", "--poses", "truth"]) == 2
    assert main(["replay", "--city", "--poses", "refined"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(e.startswith("error: --poses") for e in err)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("x")
    write_plain_layout(tmp_path / "ok", world_scenario().logs)
    assert main(["replay", str(tmp_path / "ok"), "--out", str(tmp_path / "mine")]) == 2
    assert (tmp_path / "mine" / "notes.txt").is_file()  # a foreign folder is never replaced


def test_oracle_join_stamps(world):
    """Overlapping stretches: robot 1 can join once it shares 15 objects; disjoint: never."""
    j = oracle_join_stamps(world.logs, world.T_gt_odom, "world0")
    assert j["world0"] == 0.0 and 0 < j["world1"] < world.logs[1].stamps[-1]
    apart = world_scenario(((0.0, 100.0), (300.0, 400.0)))
    j = oracle_join_stamps(apart.logs, apart.T_gt_odom, "world0")
    assert np.isinf(j["world1"])
    G = world.T_gt_odom
    right = np.linalg.inv(G["world0"]) @ G["world1"]
    assert robot_error(right, G["world0"], G["world1"], np.ones((3, 3))) == pytest.approx((0, 0))


def test_out_bag_over_the_users_files_is_refused(replayed, tmp_path, capsys):
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "mine.txt").write_text("x")
    rc = main(["replay", str(replayed / "run"), "--out", str(tmp_path / "o"), "--out-bag",
               str(tmp_path / "taken")])
    assert rc == 2 and "sgloc did not write" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # refused before replaying
    assert os.listdir(tmp_path / "taken") == ["mine.txt"]


def test_a_join_is_judged_at_the_objects_the_robot_had_when_it_joined(world, tmp_path):
    from sgloc.evaluation.online_replay import run_scenario
    from sgloc.online import OnlineConfig, OnlineSession
    from sgloc.replay import replay_logs

    s = OnlineSession(online=OnlineConfig())
    rec = replay_logs(world.logs, s)
    joined = [r for r in s.robots if rec.joined_ns[r] is not None and r != s.root]
    assert joined
    for r in joined:  # fewer objects then than at the end: the map kept growing
        assert 3 <= len(rec.join_objects[r]) < len(s.map(r))
    rows = run_scenario(world, tmp_path / "out")["robots"]
    for row in rows:
        if row["join_error"] is not None and not row["root"]:
            assert row["join_error_final"] is not None
            assert row["join_error"] != row["join_error_final"]


def test_oracle_refit_recovers_the_transform_the_maps_agree_on():
    # Robot a's objects are robot b's moved by the ground truth AND a 0.5 deg yaw (the maps
    # disagree with the ground truth): the fit on the true pairs finds the maps' transform.
    from scipy.spatial.transform import Rotation

    from sgloc.estimation import MotionModel
    from sgloc.evaluation.online_oracle import oracle_refit
    from sgloc.geometry import apply, make_transform

    rng = np.random.default_rng(3)
    pos_b = rng.uniform(-80, 80, (60, 3)) * [1, 1, 0.05]
    lab = rng.integers(0, 4, 60)
    T_gt = make_transform(Rotation.from_euler("z", 30, degrees=True).as_matrix(), [5, -2, 0])
    T_maps = T_gt @ make_transform(Rotation.from_euler("z", 0.5, degrees=True).as_matrix(),
                                   [0.3, 0, 0])
    T = oracle_refit(pos_b, lab, apply(T_maps, pos_b), lab, T_gt, 2.0, MotionModel())
    np.testing.assert_allclose(T, T_maps, atol=1e-6)
    assert oracle_refit(pos_b[:2], lab[:2], apply(T_maps, pos_b[:2]), lab[:2], T_gt, 2.0,
                        MotionModel()) is None


def test_replay_finishes_each_robot_after_its_last_keyframe(world):
    # With finish (the default) every robot's last update tried each of its pairs whose maps
    # changed since their last attempt: a further finish of the robot that ended last tries
    # nothing. Without it, some pair of that robot is still untried on its final map.
    from sgloc.online import OnlineConfig, OnlineSession
    from sgloc.replay import replay_logs

    last = world.logs[int(keyframe_order(world.logs)[-1, 0])].name
    runs = {}
    for finish in (True, False):
        s = OnlineSession(online=OnlineConfig(growth_ratio=100.0, growth_objects=100_000))
        replay_logs(world.logs, s, finish=finish)
        n = len(s.attempts)
        s.finish(last)
        runs[finish] = len(s.attempts) - n
    assert runs[True] == 0 and runs[False] > 0
