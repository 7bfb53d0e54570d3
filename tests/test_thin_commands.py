"""The library functions behind the commands: each checks its options as the command does (same
messages, same order) and gives what the command prints."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.errors import SglocError, UnknownNameError


def test_graph_job_routes_loader_options_and_settings():
    from sgloc.extraction.graph_job import graph_job

    job = graph_job("kitti_objects", loader={"frames": "0-3", "start_frame": True, "robot": None})
    assert job.options == {"scans": "0-3", "start_frame": True}  # a loader that counts scans
    assert graph_job("airsim", loader={"frames": "0-3"}).options == {"frames": "0-3"}
    job = graph_job("airsim", association_radius=1.5, position=None)
    assert job.config.association_radius == 1.5
    with pytest.raises(SglocError, match="dataset 'kitti' has no option --robot"):
        graph_job("kitti", loader={"robot": "x"})
    with pytest.raises(UnknownNameError):
        graph_job("airsim", preset="no-such-preset")
    with pytest.raises(UnknownNameError):
        graph_job("no-such-loader")


def test_replay_job_checks_the_input_before_reading_it():
    import sgloc.evaluation.replay_scenarios  # noqa: F401  (adds kitti00 and city)
    from sgloc.replay.job import replay_job
    from sgloc.replay.scenarios import REPLAY_SCENARIOS

    assert list(REPLAY_SCENARIOS) == ["kitti00", "city"]
    with pytest.raises(SglocError, match="give exactly one input"):
        replay_job()
    with pytest.raises(SglocError, match="give exactly one input"):
        replay_job(scenarios=["kitti00", "city"])
    with pytest.raises(SglocError, match="--poses 'x': choose raw or refined"):
        replay_job(scenarios=["city"], poses="x")
    with pytest.raises(SglocError, match="only for --kitti00"):
        replay_job(scenarios=["city"], poses="refined")
    with pytest.raises(SglocError, match="--scans 'x': give first-last"):
        replay_job(scenarios=["kitti00"], scans="x")
    with pytest.raises(SglocError, match="--scans '5-2': the last scan comes before the first"):
        replay_job(scenarios=["kitti00"], scans="5-2")
    with pytest.raises(SglocError, match="--robot 'bad': give NAME=PATH"):
        replay_job(named=["bad"])


@pytest.mark.parametrize("option, value", [("--class-table", "missing.txt"),
                                           ("--odom-topic", "/odom"),
                                           ("--objects-topic", "/objects")])
def test_an_option_only_recorded_inputs_take_is_refused_with_a_scenario(tmp_path, capsys,
                                                                       monkeypatch, option,
                                                                       value):
    """A cut data set brings its own classes and has no topics: --class-table (even a file
    that does not exist), --odom-topic and --objects-topic are refused, not ignored."""
    import sgloc.evaluation.replay_scenarios  # noqa: F401  (adds kitti00 and city)
    from sgloc.cli import main
    from sgloc.replay.job import replay_job

    name = option.lstrip("-").replace("-", "_").replace("class_table", "classes")
    with pytest.raises(SglocError, match=f"{option}: only for recorded inputs"):
        replay_job(scenarios=["city"], **{name: value})
    monkeypatch.chdir(tmp_path)
    assert main(["replay", "--city", "--robots", "2", "--out", "r", option, value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {option}: only for recorded"), err
    assert list(tmp_path.iterdir()) == []


def test_experiment_job_parses_the_options_and_reads_settings_after_its_checks(tmp_path):
    from sgloc.experiments import experiment_job

    def never() -> dict:
        raise AssertionError("settings read before the options were checked")

    with pytest.raises(SglocError, match="unknown experiment 'nope'"):
        experiment_job("nope", "object-world", settings=never)
    with pytest.raises(SglocError, match="--clock must be cpu or wall"):
        experiment_job("table", "object-world", clock="x", settings=never)
    with pytest.raises(SglocError, match="expected comma-separated numbers"):
        experiment_job("threshold", "object-world", thresholds="a,b", settings=never)
    job = experiment_job(
        "threshold", "object-world", thresholds="3, 5", descriptors="fast", repeats=0,
        settings=lambda: {"tau": 3}, params=["overlap=0.5"], out=tmp_path / "x",
    )
    opt = job.options
    assert opt.thresholds == (3.0, 5.0) and opt.descriptors == ("fast",)
    assert opt.settings == {"tau": 3} and opt.dataset_params == {"overlap": 0.5}
    assert opt.repeats == 1 and job.out == tmp_path / "x"
    assert experiment_job("table", "a/b").out.name.startswith("table-b-")


def test_parse_assignments_reads_yaml_values():
    from sgloc.io.settings_file import parse_assignments

    assert parse_assignments(["a=3", "b=None", "c=x,y", "d={0: 0.1}"]) == {
        "a": 3, "b": None, "c": "x,y", "d": {0: 0.1}}  # fmt: skip
    with pytest.raises(SglocError, match="NAME=VALUE"):
        parse_assignments(["a"])


def test_localize_files_is_the_localizer_on_the_files(airsim_dir, tmp_path):
    from sgloc.io.inputs import read_graph_file
    from sgloc.pipeline.config import LocalizerConfig
    from sgloc.pipeline.localizer import Localizer
    from sgloc.pipeline.on_files import localize_files

    q, t = airsim_dir / "cloud1.pcd", airsim_dir / "cloud2.pcd"
    done = localize_files(q, t, seed=3, out=tmp_path / "out", truth=np.eye(4))
    direct = Localizer(LocalizerConfig())(read_graph_file(q), read_graph_file(t), 3)
    assert done.result.accepted == direct.accepted
    assert np.array_equal(done.result.transform, direct.transform)
    assert done.info == {"query": str(q), "target": str(t), "seed": 3}
    assert {p.name for p in done.files.values()} >= {"result.json", "aligned_maps.png"}


def test_objects_demo_localizes_the_object_world(tmp_path):
    from sgloc.pipeline.config import LocalizerConfig
    from sgloc.pipeline.localizer import localize
    from sgloc.sim import make_two_robot_scene
    from sgloc.sim.demo import objects_demo

    done = objects_demo(1, 0.5, LocalizerConfig(), out=tmp_path / "o.png")
    scene = make_two_robot_scene(seed=1, overlap=0.5)
    direct = localize(scene.query, scene.target, "distance_histogram", "neighbor", seed=1,
                      config=LocalizerConfig())
    assert np.array_equal(done.result.transform, direct.transform)
    assert np.array_equal(done.truth, scene.T_target_query) and done.run_dir is None
    assert (tmp_path / "o.png").read_bytes()[:4] == b"\x89PNG"


def test_a_named_scenario_without_the_evaluation_loaded_says_what_to_import():
    """The replay keeps only the registry; the evaluation adds kitti00 and city to it."""
    import subprocess
    import sys

    code = ("from sgloc.errors import SglocError\nfrom sgloc.replay.job import replay_job\n"
            "try:\n    replay_job(scenarios=['city'])\nexcept SglocError as e:\n    print(e)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "import sgloc.evaluation.replay_scenarios first" in out.stdout
