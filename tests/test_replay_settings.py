"""`sgloc replay --set`: the online session's settings (online.NAME) and the odometry noise
model's (odometry.NAME) beside the localizer's, each checked before any input is read."""

import json

import pytest

import sgloc.evaluation.replay_scenarios  # noqa: F401  (adds the city scenario)
from sgloc.cli import main
from sgloc.errors import SglocError, UnknownNameError
from sgloc.online import OnlineConfig
from sgloc.replay.job import replay_job


def test_online_and_odometry_settings_reach_the_session():
    job = replay_job(scenarios=["city"], robots=2, seed=3, backend="keyframes",
                     online={"odometry.translation_per_metre": 0.002, "submap_length": 55.0})
    cfg = job.online_config()
    assert cfg.odometry.translation_per_metre == 0.002 and cfg.submap_length == 55.0
    assert cfg.seed == 3 and cfg.odometry.rotation_per_metre == OnlineConfig().odometry \
        .rotation_per_metre


@pytest.mark.parametrize("online, match", [
    ({"odometry.translation_per_meter": 0.1}, "did you mean 'odometry.translation_per_metre'"),
    ({"submap_lenght": 3}, "did you mean 'submap_length'"),
    ({"odometry.translation_per_metre": -1}, r"translation_per_metre=-1: must be"),
    ({"seed": 1}, "give --seed instead"),
])
def test_a_bad_online_setting_is_refused_before_the_input_is_read(online, match, tmp_path):
    missing = tmp_path / "no_such_run"  # never read: the setting is refused first
    with pytest.raises(SglocError, match=match):
        replay_job([missing], online=online)


def test_unknown_names_are_unknown_name_errors():
    with pytest.raises(UnknownNameError):
        OnlineConfig().with_overrides(odometry=1)


def test_cli_set_online_changes_the_run(tmp_path, capsys):
    out = tmp_path / "r"
    rc = main(["replay", "--city", "--robots", "2", "--out", str(out), "--quiet",
               "--set", "online.min_objects=100000"])
    assert rc == 1  # no map ever has enough objects: nobody joins
    summary = json.loads((out / "summary.json").read_text())
    assert summary["placed"] <= 1 and summary["events"]["link_accepted"] == 0
    capsys.readouterr()
    rc = main(["replay", "--city", "--robots", "2", "--out", str(tmp_path / "b"),
               "--set", "odometry.rotation_floor=abc"])
    err = capsys.readouterr().err
    assert rc == 2 and "rotation_floor" in err and "Traceback" not in err
    assert not (tmp_path / "b").exists()
