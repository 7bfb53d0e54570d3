"""Inputs users write that sgloc once refused, took wrongly or met with a traceback: header-only
tables, integer-nanosecond and out-of-range stamps, w-first quaternions, byte-order marks,
class tables, config files, bag topics, robot names, one bag per robot."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sgloc.cli import main
from sgloc.errors import DatasetError, GraphFileError, SglocError
from sgloc.io.keyframes import make_robot_log, parse_stamp
from sgloc.io.plain_layout import read_plain_layout, write_plain_layout
from sgloc.io.table import write_table
from sgloc.maps.graph import SemanticGraph

BOM = "\ufeff".encode()
NAMES = ("car", "tree", "pole")
FIELDS = ("name", "stamps_ns", "xyz", "quat", "keyframe", "positions", "labels")


def random_logs(seed: int = 0) -> list:
    """Two robots' random logs with nanosecond stamps (as tests/test_replay_io.py makes them)."""
    rng = np.random.default_rng(seed)
    logs = []
    for name in ("alpha", "beta"):
        n, m = 6, 25
        stamps = 1_700_000_000_123_456_789 + np.cumsum(rng.integers(1, 10**9, n))
        logs.append(make_robot_log(name, stamps, rng.normal(0, 50, (n, 3)), rng.normal(size=(n, 4)),
                                   rng.integers(0, n - 1, m), rng.normal(0, 20, (m, 3)),
                                   rng.integers(0, 3, m)))
    return logs


def assert_same(a: list, b: list) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        for f in FIELDS:
            assert np.array_equal(getattr(x, f), getattr(y, f)), f


def _err(capsys) -> list[str]:
    return [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]


def _one_error(capsys, *words: str) -> None:
    err = _err(capsys)
    assert len(err) == 1 and err[0].startswith("error: "), err
    for w in words:
        assert w in err[0], (w, err[0])


# -- header-only map tables ------------------------------------------------------------------
def test_header_only_table_is_a_clear_error(tmp_path, airsim_graphs, capsys):
    empty = tmp_path / "empty.csv"
    empty.write_text("x,y,z,label\n")
    with pytest.raises(GraphFileError, match=r"empty.csv: a header but no object rows"):
        SemanticGraph.load(empty)
    good = tmp_path / "good.csv"
    write_table(good, airsim_graphs[0].positions, airsim_graphs[0].labels)
    assert main(["localize", str(empty), str(good)]) == 2
    _one_error(capsys, "empty.csv", "no object rows")
    assert main(["fleet", str(good), str(empty), "--workers", "0",
                 "--out", str(tmp_path / "f")]) == 2
    _one_error(capsys, "empty.csv", "no object rows")


# -- stamps ----------------------------------------------------------------------------------
def test_integer_nanosecond_stamps_read_exactly():
    assert parse_stamp("1700000043750000000") == 1_700_000_043_750_000_000
    assert parse_stamp("1700000043.750000000") == 1_700_000_043_750_000_000
    assert parse_stamp("12") == 12_000_000_000  # a small integer is seconds
    assert parse_stamp("-3") == -3_000_000_000


def _log_files(tmp_path):
    logs = random_logs()
    write_plain_layout(tmp_path / "run", logs, NAMES)
    return logs, tmp_path / "run"


def _to_integer_ns(path) -> None:
    """Rewrite every `seconds.nanoseconds` stamp of a file as integer nanoseconds."""
    import re

    text = path.read_text()
    path.write_text(re.sub(r"\b(\d{10})\.(\d{9})\b", r"\1\2", text))


def test_layout_with_integer_nanosecond_stamps_equals_the_seconds_one(tmp_path):
    logs, run = _log_files(tmp_path)
    for robot in ("alpha", "beta"):
        for f in ("odometry.tum", "objects.csv"):
            _to_integer_ns(run / robot / f)
    assert "." not in (run / "alpha" / "odometry.tum").read_text().split()[0]
    assert_same(read_plain_layout(run), logs)


@pytest.mark.parametrize(
    "stamp, match",
    [
        ("1e30", r"odometry.tum:1: stamp 1e30 is beyond the range of stamps"),
        ("1700000043750000000.0", r"odometry.tum:1: stamp .* beyond the range.*integer nano"),
        ("-1e30", r"odometry.tum:1: stamp -1e30 is beyond"),
        ("1700000043750", r"odometry.tum:1: stamp 1700000043750 .*milliseconds or micro"),
        ("1" + "0" * 400, r"odometry.tum:1: stamp 1000.* beyond the range"),
        ("1e999999999", r"odometry.tum:1: stamp 1e999999999 is beyond"),
    ],
)
def test_out_of_range_stamps_are_refused_naming_the_line(tmp_path, stamp, match):
    _, run = _log_files(tmp_path)
    (run / "alpha" / "odometry.tum").write_text(f"{stamp} 0 0 0 0 0 0 1\n")
    with pytest.raises(DatasetError, match=match):
        read_plain_layout(run)


def test_huge_stamp_is_one_line_exit_2(tmp_path, capsys):
    _, run = _log_files(tmp_path)
    (run / "alpha" / "odometry.tum").write_text("1e30 0 0 0 0 0 0 1\n")
    assert main(["replay", str(run), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    _one_error(capsys, "odometry.tum:1", "integer nanoseconds")


def test_huge_object_stamp_is_refused(tmp_path):
    _, run = _log_files(tmp_path)
    with (run / "alpha" / "objects.csv").open("a") as f:
        f.write("1e30,1,2,3,car\n")
    with pytest.raises(DatasetError, match=r"objects.csv:\d+: stamp 1e30 is beyond"):
        read_plain_layout(run)


# -- quaternion order ------------------------------------------------------------------------
def test_w_first_quaternions_are_named_as_the_likely_mistake(tmp_path):
    _, run = _log_files(tmp_path)
    (run / "alpha" / "odometry.tum").write_text(
        "1.0 0 0 0 1 0 0 0\n2.0 1 0 0 0.9950042 0 0 0.0998334\n"
    )
    (run / "alpha" / "objects.csv").write_text("stamp,x,y,z,class\n")
    with pytest.raises(DatasetError, match=r"odometry.tum:1: .*`qw qx qy qz`.*qw last"):
        read_plain_layout(run)
    # the same poses x-first (qw last) are read
    (run / "alpha" / "odometry.tum").write_text(
        "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0.0998334 0.9950042\n"
    )
    assert len(read_plain_layout(run)[0]) == 2


# -- byte-order marks ------------------------------------------------------------------------
def test_byte_order_marks_are_ignored_by_every_text_reader(tmp_path, airsim_graphs):
    from sgloc.cli.options import read_settings_file
    from sgloc.io.class_table import read_class_table
    from sgloc.io.colour_table import read_colour_table

    g = airsim_graphs[0]
    plain, marked = tmp_path / "plain.csv", tmp_path / "marked.csv"
    write_table(plain, g.positions, g.labels)
    marked.write_bytes(BOM + plain.read_bytes())
    a, b = SemanticGraph.load(plain), SemanticGraph.load(marked)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.labels, b.labels)
    headless = tmp_path / "headless.txt"
    headless.write_bytes(BOM + b"1 2 3 0\n4 5 6 1\n7 8 9 2\n")
    assert len(SemanticGraph.load(headless)) == 3
    logs, run = _log_files(tmp_path)
    for f in (run / "classes.txt", run / "alpha" / "odometry.tum", run / "alpha" / "objects.csv"):
        f.write_bytes(BOM + f.read_bytes())
    assert_same(read_plain_layout(run), logs)
    assert read_class_table(run / "classes.txt")["car"] == 0
    cfg = tmp_path / "c.yaml"
    cfg.write_bytes(BOM + b"tau: 3\n")
    assert read_settings_file(cfg) == {"tau": 3}
    cfg = tmp_path / "c.json"
    cfg.write_bytes(BOM + b'{"tau": 3}')
    assert read_settings_file(cfg) == {"tau": 3}
    g.save(tmp_path / "g.json")
    (tmp_path / "m.json").write_bytes(BOM + (tmp_path / "g.json").read_bytes())
    assert np.array_equal(SemanticGraph.load(tmp_path / "m.json").positions, g.positions)
    colours = tmp_path / "colours.txt"
    colours.write_bytes(BOM + b"0 255 0 0 car\n1 0 255 0 tree\n")
    assert read_colour_table(colours)[1] == ["car", "tree"]


# -- class tables ----------------------------------------------------------------------------
def test_one_class_table_reader_one_rule_for_case(tmp_path, airsim_graphs):
    import importlib

    from sgloc.io.inputs import read_graph_with

    with pytest.raises(ImportError):
        importlib.import_module("sgloc.io.class_names")
    logs, run = _log_files(tmp_path)
    (run / "classes.txt").write_text("0 Car\n1 TREE\n2 pole\n")
    for robot in ("alpha", "beta"):
        f = run / robot / "objects.csv"
        f.write_text(f.read_text().replace(",car", ",CAR").replace(",tree", ",Tree"))
    got = read_plain_layout(run)
    assert [np.array_equal(a.labels, b.labels) for a, b in zip(got, logs, strict=True)] == [
        True, True]
    csv = tmp_path / "g.csv"
    csv.write_text("x,y,z,class\n0,0,0,car\n10,0,0,Tree\n0,10,0,POLE\n")
    assert read_graph_with(csv, class_table=run / "classes.txt")[1].tolist() == [0, 1, 2]


def test_fleet_takes_a_class_table(tmp_path, airsim_graphs, capsys):
    names = [f"c{i}" for i in range(11)]
    (tmp_path / "classes.txt").write_text("".join(f"{i} {n}\n" for i, n in enumerate(names)))
    files = []
    for k, g in enumerate(airsim_graphs):
        rows = "".join(
            f"{x},{y},{z},{names[c]}\n" for (x, y, z), c in zip(g.positions, g.labels, strict=True)
        )
        files.append(tmp_path / f"g{k}.csv")
        files[-1].write_text("x,y,z,label\n" + rows)
    argv = ["fleet", *map(str, files), "--class-table", str(tmp_path / "classes.txt"),
            "--workers", "0", "--out", str(tmp_path / "out")]
    assert main(argv) == 0
    placed = json.loads((tmp_path / "out" / "fleet.json").read_text())["placed"]
    assert set(placed) == {"g0", "g1"}


# -- config files ----------------------------------------------------------------------------
def test_unknown_setting_of_a_config_file_names_the_file(tmp_path, capsys):
    from sgloc.cli.options import localizer_config

    cfg = tmp_path / "mine.yaml"
    cfg.write_text("tau: 3\nbogus_knob: 1\n")
    with pytest.raises(SglocError, match=r"mine.yaml: unknown setting 'bogus_knob'"):
        localizer_config(config_file=cfg)
    with pytest.raises(SglocError, match=r"^unknown setting 'other'"):  # not the file's
        localizer_config(settings=["other=1"])
    good = tmp_path / "ok.yaml"
    good.write_text("n_walks: 20\n")  # a random-walk setting, with that descriptor chosen later
    assert localizer_config(config_file=good, settings=["descriptor=random_walk"])


# -- hints from the settings used ------------------------------------------------------------
def test_not_localized_hint_follows_the_settings_used(airsim_graphs):
    from sgloc import localize

    q, t = airsim_graphs
    far = SemanticGraph(t.positions[:40] + [5000.0, 0.0, 0.0], t.labels[:40])
    few = SemanticGraph(q.positions[:5], q.labels[:5])
    r = localize(few, far)  # the default min_similarity, 0.5: suggest a lower one
    assert "candidate match" in r.reason and "min_similarity 0.5 now" in r.reason
    assert "min_similarity=0.5;" not in r.reason and "--set min_similarity=0.25;" in r.reason
    r = localize(few, far, min_similarity=0.99)
    assert not r.accepted and "--set min_similarity=0.5;" in r.reason
    some = SemanticGraph(q.positions[:20], q.labels[:20])
    for used, hint in ((0.9999, "0.999"), (0.999, "0.99")):
        r = localize(some, far, min_confidence=used)
        assert f"< min_confidence {used}" in r.reason, r.reason
        assert f"--set min_confidence={hint})" in r.reason


# -- robot names -----------------------------------------------------------------------------
def test_localize_fleet_names_robots_by_file_stem(tmp_path, airsim_graphs):
    from sgloc.online.fleet import localize_fleet

    paths = []
    for name, g in zip(("alpha", "beta"), airsim_graphs, strict=True):
        paths.append(tmp_path / f"{name}.csv")
        write_table(paths[-1], g.positions, g.labels)
    res = localize_fleet([SemanticGraph.load(p) for p in paths], workers=0)
    assert res.names == ["alpha", "beta"]  # as `sgloc fleet alpha.csv beta.csv` names them
    kept = [SemanticGraph(g.positions, g.labels, name=n)
            for g, n in zip(airsim_graphs, ("run.v2", "run.v3"), strict=True)]
    assert localize_fleet(kept, workers=0).names == ["run.v2", "run.v3"]


# -- bags ------------------------------------------------------------------------------------
def test_wrong_object_topic_lists_the_bags_topics(tmp_path):
    pytest.importorskip("rosbags", reason="rosbags (extra sgloc[ros]) is not installed")
    from sgloc.io.rosbag import read_bag, write_bag

    write_bag(tmp_path / "bag", random_logs())
    with pytest.raises(DatasetError, match=r"topics in the bag: .*/alpha/objects.*--objects-top"):
        read_bag(tmp_path / "bag", objects_topic="/{robot}/detections")


@pytest.fixture(scope="module")
def world():
    from sgloc.evaluation.replay_scenarios import world_scenario

    return world_scenario()


@pytest.fixture(scope="module")
def one_bag_run(world, tmp_path_factory):
    pytest.importorskip("rosbags", reason="rosbags (extra sgloc[ros]) is not installed")
    from sgloc.io.rosbag import write_bag

    d = tmp_path_factory.mktemp("onebag")
    write_bag(d / "bag", world.logs)
    assert main(["replay", str(d / "bag"), "--out", str(d / "out"), "--quiet"]) == 0
    return d / "out"


def _same_outputs(a, b) -> None:
    for f in ("events.csv", "links.g2o", "fleet/world0.tum", "fleet/world1.tum"):
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    sa, sb = (json.loads((x / "summary.json").read_text()) for x in (a, b))
    for s in (sa, sb):
        s.pop("latency")
        for r in s["robots"].values():
            r.pop("latency")
    assert sa == sb


def test_one_bag_per_robot_replays_as_one_bag(world, one_bag_run, tmp_path):
    from sgloc.io.rosbag import write_bag

    for g in world.logs:  # each robot's own bag, its topics without the robot name
        write_bag(tmp_path / g.name, [g], odom_topic="/odom", objects_topic="/objects")
    out = tmp_path / "out"
    argv = ["replay", str(tmp_path / "world1"), str(tmp_path / "world0"), "--odom-topic",
            "/odom", "--objects-topic", "/objects", "--out", str(out), "--quiet"]
    assert main(argv) == 0
    _same_outputs(one_bag_run, out)


def test_robots_named_on_the_command_line(world, one_bag_run, tmp_path, capsys):
    from sgloc.io.rosbag import write_bag

    for k, g in enumerate(world.logs):  # bags named a, b; topics /world0/odom, ...
        write_bag(tmp_path / "ab"[k], [g])
    mcap = [next((tmp_path / x).glob("*.mcap")) for x in "ab"]
    out = tmp_path / "out"
    argv = ["replay", "--robot", f"world0={mcap[0]}", "--robot", f"world1={mcap[1]}",
            "--out", str(out), "--quiet"]
    assert main(argv) == 0
    _same_outputs(one_bag_run, out)
    # named by the stems (a, b) the template's topics /a/odom do not exist: the bag's topics
    assert main(["replay", str(tmp_path / "a"), str(tmp_path / "b"), "--out",
                 str(tmp_path / "o2"), "--quiet"]) == 2
    _one_error(capsys, "no nav_msgs/msg/Odometry topic '/a/odom'", "/world0/odom", "--odom-topic")
    assert main(["replay", str(tmp_path / "a"), str(tmp_path / "a"), "--out",
                 str(tmp_path / "o3"), "--quiet"]) == 2
    _one_error(capsys, "both name robot 'a'", "--robot NAME=PATH")
    assert main(["replay", "--robot", "nameless", "--out", str(tmp_path / "o4")]) == 2
    _one_error(capsys, "--robot 'nameless'", "NAME=PATH")


def test_robot_folders_of_the_plain_layout_are_sources_too(world, one_bag_run, tmp_path):
    write_plain_layout(tmp_path / "run", world.logs)
    argv = ["replay", str(tmp_path / "run" / "world0"), str(tmp_path / "run" / "world1"),
            "--out", str(tmp_path / "out"), "--quiet"]
    assert main(argv) == 0
    _same_outputs(one_bag_run, tmp_path / "out")
