"""The fleet groups of benchmarks/online.py: drifted scenarios keep their truth, settings are
checked before any run, goals are judged on the stored runs, and the page's part is replaced."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.errors import SglocError
from sgloc.evaluation.fleet_cases import Case, case_scenario, split_settings
from sgloc.evaluation.replay_scenarios import drifted, world_scenario
from sgloc.online import OdometryNoise


@pytest.fixture(scope="module")
def bench(benchmark_module):
    return benchmark_module("online", "online_benchmark")


def test_drifted_scenario_keeps_the_truth() -> None:
    base = world_scenario()
    d = drifted(base, 2.0, 5)
    assert d.truth is base.logs and d.true_logs is base.logs
    for g, h in zip(base.logs, d.logs, strict=True):
        assert np.array_equal(g.positions, h.positions) and not np.allclose(g.xyz, h.xyz)
        assert np.allclose(d.gt_poses()[g.name], base.T_gt_odom[g.name] @ g.poses)
    again = drifted(base, 2.0, 5)
    assert all(np.array_equal(a.xyz, b.xyz) for a, b in zip(d.logs, again.logs, strict=True))


def test_case_kind_is_checked() -> None:
    with pytest.raises(SglocError, match="kind"):
        case_scenario(Case("x", "g", "x", "house", 2))


def _run(robots: int, wrong: list[str], level: float = 1.0, **over) -> dict:
    r = {"case": {"title": "t", "robots": robots, "level": level, "kind": "city",
                  "group": "drift", "length": 400.0},
         "status": "done", "settings": {}, "placed": robots, "joined": robots - 1,
         "overlapping": robots - 1, "mean_delay": 0.05, "wrong_joins": wrong,
         "accepted": 3, "wrong_accepted": len(wrong), "attempts": 9,
         "encounter": {"median": 0.1, "p95": 0.4, "max": 1.0, "n": 10}, "rmse": 0.3,
         "oracle": {"rmse": 0.2, "encounter": {"median": 0.05, "p95": 0.1}},
         "revocations": 0, "reacceptances": 0, "most_reaccepted": 0,
         "latency": {"median_ms": 1.0, "p99_ms": 20.0, "max_ms": 50.0},
         "seconds": 10.0, "peak_mb": 300.0}
    r.update(over)
    return r


def test_goals_on_stored_runs(bench) -> None:
    ok = bench.fleet_goals({"a": _run(4, [])})
    assert any(line.startswith("- met: 0 wrong joins") for line in ok)
    assert any(line.startswith("- met: drift 1 and 2: encounter") for line in ok)
    assert any(line.startswith("- not measured: 128 robots") for line in ok)
    bad = bench.fleet_goals({
        "a": _run(4, ["r1"]),
        "b": _run(4, [], encounter={"median": 1.0, "p95": 2.0}, peak_mb=2000.0),
        "c": _timed_out(),
    })
    text = "\n".join(bad)
    assert "**NOT met**: 0 wrong joins in every run (wrong: a: 1)" in text
    assert "**NOT met**: drift 1 and 2: encounter p95 <= max(0.5 m, 3 x the oracle's) " \
           "(not met: b 2.00 > 0.50 m)" in text
    assert "**NOT met**: 128 robots on the default city replayed in <= 3 minutes (c timed " \
           "out after 600 s)" in text
    assert "**NOT met**: memory under 1 GB" in text
    # the timed-out run is a row of its own
    assert "timed out after 600 s" in bench.fleet_section({"c": _timed_out()})
    # a run with other settings is a comparison: shown, not judged
    other = {"a": _run(4, []), "a [backend=robots]": _run(4, ["r1"], settings={
        "backend": "robots"})}
    assert any(line.startswith("- met: 0 wrong joins") for line in bench.fleet_goals(other))
    assert "| backend=robots |" in bench.fleet_section(other)
    # drift 0 on KITTI: against the same run with one rigid frame per robot
    kitti = {"case": {"title": "t", "robots": 4, "level": 0.0, "kind": "kitti",
                      "group": "drift", "length": 0.0}}
    worse = {"k": _run(4, [], level=0.0, **kitti, rmse=0.4),
             "k [backend=robots]": _run(4, [], level=0.0, **kitti, rmse=0.3,
                                        settings={"backend": "robots"})}
    text = "\n".join(bench.fleet_goals(worse))
    assert "**NOT met**: drift 0: KITTI no worse than one rigid frame per robot" in text
    worse["k"]["rmse"] = 0.3
    assert "- met: drift 0: KITTI no worse" in "\n".join(bench.fleet_goals(worse))


def _timed_out() -> dict:
    return {"case": {"title": "t", "robots": 128, "level": 0.0, "kind": "city",
                     "group": "many", "length": 400.0},
            "status": "timed out after 600 s", "settings": {}}


def test_settings_are_checked_and_the_part_replaced(bench) -> None:
    assert bench.parse_settings(["max_attempts=null", "confirmations=2", "solver=scipy"]) == {
        "max_attempts": None, "confirmations": 2, "solver": "scipy"}
    with pytest.raises(SystemExit, match="confirmations"):
        bench.parse_settings(["confirmations=0"])
    odo = bench.parse_settings(["odometry.translation_per_metre=0.001"])
    online, _ = split_settings(odo)
    assert online["odometry"].translation_per_metre == 0.001
    assert online["odometry"].rotation_per_metre == OdometryNoise().rotation_per_metre
    with pytest.raises(SystemExit, match="odometry"):
        bench.parse_settings(["odometry.no_such_term=1"])
    with pytest.raises(SystemExit):
        bench.parse_settings(["confirmations"])
    with pytest.raises(SystemExit, match="OnlineConfig"):
        bench.parse_settings(["no_such_setting=1"])
    sec = bench.fleet_section({"c": _timed_out()})
    page = "# t\n\nabove\n"
    once = bench.splice(page, sec)
    assert once.startswith(page.rstrip("\n")) and once.endswith(sec)
    again = bench.splice(once + "below\n", sec.replace("600", "700"))
    assert "700" in again and "600 s" not in again and again.endswith("below\n")
