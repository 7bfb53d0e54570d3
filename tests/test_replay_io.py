"""Replay inputs: the plain layout and ROS 2 bags read back exactly what was written; bad files
give one clear error naming the file, the line and the fix."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from sgloc.errors import DatasetError, OutputPathError, SglocError
from sgloc.io.keyframes import format_stamp, make_robot_log, parse_stamp
from sgloc.io.plain_layout import read_plain_layout, write_plain_layout
from sgloc.optional import MissingExtraError

FIELDS = ("name", "stamps_ns", "xyz", "quat", "keyframe", "positions", "labels")
NAMES = ("car", "tree", "pole")


def random_logs(seed: int = 0, names=("alpha", "beta")) -> list:
    rng = np.random.default_rng(seed)
    logs = []
    for name in names:
        n, m = 6, 25
        q = rng.normal(size=(n, 4))
        stamps = 1_700_000_000_123_456_789 + np.cumsum(rng.integers(1, 10**9, n))
        logs.append(make_robot_log(name, stamps, rng.normal(0, 50, (n, 3)), q,
                                   rng.integers(0, n - 1, m), rng.normal(0, 20, (m, 3)),
                                   rng.integers(0, 3, m)))
    return logs


def assert_same(a: list, b: list) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        for f in FIELDS:
            assert np.array_equal(getattr(x, f), getattr(y, f)), f


def test_stamps_are_exact_nanoseconds():
    assert parse_stamp("1403636579.763555527") == 1403636579763555527
    assert parse_stamp("1.5e3") == 1_500_000_000_000
    assert format_stamp(1403636579000000005) == "1403636579.000000005"
    with pytest.raises(ValueError):
        parse_stamp("nan")


@pytest.mark.parametrize("names", [None, NAMES])
def test_plain_layout_round_trip(tmp_path, names):
    logs = random_logs()
    write_plain_layout(tmp_path / "run", logs, names)
    assert_same(read_plain_layout(tmp_path / "run"), logs)
    if names:
        assert "tree" in (tmp_path / "run" / "alpha" / "objects.csv").read_text()


def test_bag_round_trip_equals_plain_layout(tmp_path):
    pytest.importorskip("rosbags", reason="rosbags (extra sgloc[ros]) is not installed")
    from sgloc.io.rosbag import read_bag, write_bag

    write_plain_layout(tmp_path / "run", random_logs(), NAMES)
    plain = read_plain_layout(tmp_path / "run")
    write_bag(tmp_path / "bag", plain, NAMES)
    table = {n: k for k, n in enumerate(NAMES)}
    assert_same(read_bag(tmp_path / "bag", classes=table), plain)
    mcap = next((tmp_path / "bag").glob("*.mcap"))
    assert_same(read_bag(mcap, classes=table), plain)  # a bare .mcap file reads the same


def test_fleet_bag_round_trip(tmp_path):
    pytest.importorskip("rosbags", reason="rosbags (extra sgloc[ros]) is not installed")
    from sgloc.geometry import random_rigid_transform
    from sgloc.io.rosbag import read_fleet_bag, write_fleet_bag

    rng = np.random.default_rng(3)
    msgs = [(10**9 * k, f"r{k % 2}", random_rigid_transform(rng)) for k in range(4)]
    write_fleet_bag(tmp_path / "fleet", msgs)
    back = read_fleet_bag(tmp_path / "fleet")
    assert [(s, r) for s, r, _ in back] == [(s, r) for s, r, _ in msgs]
    for (_, _, T), (_, _, U) in zip(msgs, back, strict=True):
        np.testing.assert_allclose(U, T, atol=1e-12)
    write_fleet_bag(tmp_path / "fleet", msgs[:2])  # an earlier bag of sgloc: replaced
    assert len(read_fleet_bag(tmp_path / "fleet")) == 2
    (tmp_path / "fleet" / "mine.txt").write_text("x")
    with pytest.raises(OutputPathError, match="mine.txt"):
        write_fleet_bag(tmp_path / "fleet", msgs)


def test_bag_topic_errors_name_the_fix(tmp_path):
    pytest.importorskip("rosbags", reason="rosbags (extra sgloc[ros]) is not installed")
    from sgloc.io.rosbag import read_bag, write_bag

    write_bag(tmp_path / "bag", random_logs())
    with pytest.raises(DatasetError, match="--odom-topic"):
        read_bag(tmp_path / "bag", odom_topic="/{robot}/odometry")
    with pytest.raises(DatasetError, match="--objects-topic"):
        read_bag(tmp_path / "bag", objects_topic="/{robot}/detections")
    write_bag(tmp_path / "named", random_logs(), NAMES)
    msg = r"objects message 1 marker 0: class '\w+' is neither an integer.*--class-table"
    with pytest.raises(DatasetError, match=msg):
        read_bag(tmp_path / "named")


def test_missing_rosbags_is_one_clear_line(monkeypatch):
    from sgloc.io.rosbag import read_bag

    monkeypatch.setitem(sys.modules, "rosbags", None)
    with pytest.raises(MissingExtraError, match=r"pip install 'sgloc\[ros\]'"):
        read_bag("any.mcap")


def _odometry(d, text: str) -> None:
    (d / "odometry.tum").write_text(text)
    (d / "objects.csv").write_text("stamp,x,y,z,class\n")


def _repeat_second_stamp(d) -> None:
    """odometry.tum's third pose given the second's stamp (a comment line first); objects.csv
    still names the third stamp, so a reader that checks objects first blames objects.csv."""
    lines = (d / "odometry.tum").read_text().splitlines()
    lines[2] = lines[1].split()[0] + " " + lines[2].split(" ", 1)[1]
    (d / "odometry.tum").write_text("# poses\n" + "\n".join(lines) + "\n")


def _layout(tmp_path):
    write_plain_layout(tmp_path / "run", random_logs(), NAMES)
    return tmp_path / "run", tmp_path / "run" / "alpha"


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda d: (d / "objects.csv").write_text("stamp,x,y,z\n"), r"objects.csv:1: header"),
        (lambda d: (d / "objects.csv").write_text("stamp,x,y,z,class\n5.0,1,2,3,0\n"),
         r"objects.csv:2: stamp 5.0 is not a keyframe stamp"),
        (lambda d: (d / "objects.csv").write_text(
            "stamp,x,y,z,class\n" + (d / "odometry.tum").read_text().split()[0] + ",1,2,3,bus\n"),
         r"objects.csv:2: class 'bus' .*known: car, pole, tree"),
        (lambda d: (d / "objects.csv").write_text(
            "stamp,x,y,z,class\n" + (d / "odometry.tum").read_text().split()[0] + ",1,x,3,0\n"),
         r"objects.csv:2: stamp, x, y, z must be numbers"),
        (lambda d: _odometry(d, "1 2 3\n"), r"odometry.tum:1: expected 8 values"),
        (lambda d: _odometry(d, "2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n"),
         r"alpha/odometry.tum:2: stamp 1 comes before the stamp of line 1"),
        (_repeat_second_stamp, r"alpha/odometry.tum:4: stamp \S+ repeats the stamp of line 3"),
        (lambda d: _odometry(d, "1 0 0 0 0 0 0 0\n"), r"alpha: a zero quaternion"),
        (lambda d: (d / "objects.csv").unlink(), r"no objects.csv; write one"),
    ],
)
def test_bad_layout_files_give_one_clear_error(tmp_path, edit, match):
    root, robot = _layout(tmp_path)
    edit(robot)
    with pytest.raises(DatasetError, match=match):
        read_plain_layout(root)


def test_class_names_need_a_table(tmp_path):
    root, _ = _layout(tmp_path)
    (root / "classes.txt").unlink()
    with pytest.raises(DatasetError, match="--class-table FILE; a replay layout .* classes.txt"):
        read_plain_layout(root)


def test_robot_names_that_cannot_be_folders_are_refused(tmp_path):
    logs = random_logs(names=("team/r1",))
    with pytest.raises(SglocError, match="cannot be a folder name"):
        write_plain_layout(tmp_path / "run", logs)


def test_a_robot_file_given_as_the_source_is_named_a_file(tmp_path):
    from sgloc.replay.inputs import read_logs

    root, robot = _layout(tmp_path)
    with pytest.raises(DatasetError, match=r"odometry.tum: is a file, not a source; .* its folder"):
        read_logs(robot / "odometry.tum")
    with pytest.raises(DatasetError, match=r"is a file, not a folder"):
        read_plain_layout(robot / "odometry.tum")
