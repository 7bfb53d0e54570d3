"""Real data, online: KITTI 00 scans 0-2999 cut into 4 robots (every 5th scan a keyframe),
replayed keyframe by keyframe through the default back-end (keyframes) and judged against the
KITTI poses. The full-rate run's figures are in docs/online.md (worst end error 2.64 m /
0.38 deg, trajectory APE 0.852 m; the goal: 3 m / 3 deg)."""

from __future__ import annotations

import pytest

#: Measured on this cut (the same on every run): every robot placed; worst end error
#: 2.83 m / 0.58 deg; trajectory APE RMSE 1.13 m; 28 links, all active, the worst 2.98 m /
#: 1.32 deg (KITTI's raw poses, the truth here, are themselves off by 1-2 m at some revisits;
#: with the odometry held to the drift its links show, OnlineConfig.odometry_scale, the ends
#: of kitti0 and kitti3 came closer and kitti1's went from 2.12 to 2.83 m). The limits: a
#: small margin above, and a link never beyond the documented 3 m / 3 deg of a wrong one.
END_M, END_DEG, APE_M, LINK_DEG = 3.0, 0.7, 1.25, 1.5


@pytest.fixture(scope="module")
def score(kitti_dir, tmp_path_factory):
    from sgloc.evaluation.online_replay import run_scenario
    from sgloc.evaluation.replay_scenarios import kitti_scenario
    from sgloc.pipeline.presets import localizer_preset

    scenario = kitti_scenario(4, 0, 2999, every=5)
    return run_scenario(scenario, tmp_path_factory.mktemp("kitti") / "replay",
                        localizer_preset("kitti-objects"))


def test_every_robot_joins_and_ends_near_the_truth(score):
    rows = score["robots"]
    assert len(rows) == 4 and sum(r["root"] for r in rows) == 1
    for r in rows:
        assert r["end_error"] is not None, f"{r['robot']} was not placed"
        m, deg = r["end_error"]
        assert m < END_M and deg < END_DEG, (r["robot"], m, deg)
    assert score["ape"]["rmse"] < APE_M, score["ape"]


def test_every_active_link_is_near_the_truth(score):
    active = [lk for lk in score["links"] if lk["active"]]
    assert len(active) >= 24  # measured 28
    for lk in score["links"]:
        assert not lk["wrong"] and lk["error_deg"] < LINK_DEG, lk
