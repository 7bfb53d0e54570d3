"""The odometry drift model (sgloc.sim.drift) and the fleet metrics on constructed cases:
encounter error, placement error, one-alignment RMSE, loop closures and the oracle."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.errors import SglocError
from sgloc.evaluation.fleet_metrics import (
    closure_pairs,
    encounter_errors,
    error_stats,
    fleet_keyframe_poses,
    keyframe_pairs,
    placement_error,
    rigid_rmse,
)
from sgloc.geometry import make_transform
from sgloc.io.keyframes import make_robot_log
from sgloc.sim.drift import drift_log, drift_poses


def _rz(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def _line(x: np.ndarray, y: float = 0.0, deg: float = 0.0) -> np.ndarray:
    """(k,4,4) poses at (x, y, 0) heading `deg`."""
    T = np.tile(np.eye(4), (len(x), 1, 1))
    T[:, :3, :3] = _rz(deg)
    T[:, 0, 3], T[:, 1, 3] = x, y
    return T


def _loop(n: int = 400) -> np.ndarray:
    """A 1 km square drive (poses every 2.5 m)."""
    s = np.arange(n) * 2.5
    side, along = np.divmod(s, 250.0)
    corners = np.array([[0, 0], [250, 0], [250, 250], [0, 250]], float)
    dirs = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], float)
    k = side.astype(int) % 4
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :2, 3] = corners[k] + dirs[k] * along[:, None]
    for d in range(4):
        T[k == d, :3, :3] = _rz(90.0 * d)
    return T


def _end_error(level: float, seed: int) -> float:
    true = _loop()
    out = drift_poses(true, level, np.random.default_rng(seed))
    return float(np.linalg.norm(out[-1, :3, 3] - true[-1, :3, 3]))


def test_drift_level_zero_is_the_identity() -> None:
    true = _loop()
    assert np.array_equal(drift_poses(true, 0.0, np.random.default_rng(3)), true)
    log = make_robot_log("r", np.arange(len(true)) * 10**8, true[:, :3, 3],
                         np.tile([0.0, 0.0, np.sin(0.3), np.cos(0.3)], (len(true), 1)),
                         np.arange(len(true)), np.ones((len(true), 3)), np.zeros(len(true)))
    same = drift_log(log, 0.0, np.random.default_rng(3))
    assert np.array_equal(same.xyz, log.xyz) and np.array_equal(same.quat, log.quat)


def test_drift_grows_with_the_level_and_keeps_the_first_pose() -> None:
    ends = [np.mean([_end_error(level, s) for s in range(5)]) for level in (1, 2, 4)]
    assert 1.0 < ends[0] < ends[1] < ends[2]
    true = _loop()
    out = drift_poses(true, 2.0, np.random.default_rng(0))
    assert np.array_equal(out[0], true[0])
    # rotations stay rotations, turned about the up axis only
    R = out[:, :3, :3]
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-12)
    assert np.allclose(R[:, :, 2], [0, 0, 1], atol=1e-12)


def test_drift_of_a_log_matches_the_poses_and_keeps_the_sightings() -> None:
    true = _loop(50)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (50, 1))
    log = make_robot_log("r", np.arange(50) * 10**8, true[:, :3, 3], q, np.arange(50),
                         np.arange(150.0).reshape(50, 3), np.arange(50))
    out = drift_log(log, 4.0, np.random.default_rng(7))
    T = drift_poses(log.poses, 4.0, np.random.default_rng(7))
    assert np.allclose(out.poses, T, atol=1e-9)
    assert np.array_equal(out.positions, log.positions) and np.array_equal(out.stamps_ns,
                                                                          log.stamps_ns)


def test_drift_same_seed_same_output_and_bad_level() -> None:
    true = _loop()
    a = drift_poses(true, 1.0, np.random.default_rng(11))
    assert np.array_equal(a, drift_poses(true, 1.0, np.random.default_rng(11)))
    assert not np.array_equal(a, drift_poses(true, 1.0, np.random.default_rng(12)))
    with pytest.raises(SglocError, match="level"):
        drift_poses(true, -1.0, np.random.default_rng(0))


def test_encounter_error_known_answer() -> None:
    x = np.arange(0.0, 100.0, 5.0)
    gt = [_line(x), _line(x, y=10.0)]  # two robots side by side, 10 m apart
    # robot b placed 2 m too far along x: every pair within 20 m is off by exactly 2 m
    est = [gt[0].copy(), gt[1].copy()]
    est[1][:, 0, 3] += 2.0
    err = encounter_errors(est, gt, np.eye(4))
    a, i, b, j = keyframe_pairs([g[:, :3, 3] for g in gt], 20.0)
    assert len(err) == len(a) > 0 and np.all(a == 0) and np.all(b == 1)
    assert np.all(np.hypot(x[i] - x[j], 10.0) <= 20.0)
    assert np.allclose(err, 2.0)
    # a rigid move of the whole fleet is not an error; the truth in another frame is turned in
    G = make_transform(_rz(40.0), np.array([5.0, -3.0, 1.0]))
    moved = [G @ e for e in est]
    assert np.allclose(encounter_errors(moved, gt, G), 2.0)
    s = error_stats(err)
    assert s["median"] == pytest.approx(2.0) and s["n"] == len(err)
    assert encounter_errors([est[0], None], gt, np.eye(4)).size == 0


def test_placement_error_and_its_fallback() -> None:
    x = np.arange(0.0, 50.0, 5.0)
    a, b = _line(x), _line(x, y=5.0)
    off = make_transform(_rz(0.0), np.array([0.0, 4.0, 0.0])) @ b
    m, deg = placement_error(off, b, a, a, np.eye(3))
    assert m == pytest.approx(4.0) and deg == pytest.approx(0.0, abs=1e-9)
    far = _line(x + 500.0)  # no pair within 20 m: judged at the closest pair
    m, _ = placement_error(far, far, a, a, np.eye(3))
    assert m == pytest.approx(0.0, abs=1e-9)
    assert placement_error(a[:0], a[:0], a, a, np.eye(3)) is None


def test_rigid_rmse_ignores_one_rigid_move() -> None:
    rng = np.random.default_rng(0)
    gt = [rng.uniform(-50, 50, (30, 3)), rng.uniform(-50, 50, (20, 3))]
    R, t = _rz(25.0), np.array([3.0, 1.0, -2.0])
    est = [g @ R.T + t for g in gt]
    assert rigid_rmse(est, gt) == pytest.approx(0.0, abs=1e-9)
    est[1] = est[1] + np.array([0.0, 0.0, 1.0])  # one robot 1 m up: rmse under 1 m, > 0
    assert 0.3 < rigid_rmse(est, gt) < 1.0
    assert rigid_rmse([], []) is None


def test_closure_pairs_other_robots_and_returns_only() -> None:
    x = np.arange(0.0, 60.0, 2.0)
    out_and_back = _line(np.concatenate([x, x[::-1]]))
    other = _line(np.array([0.0, 1.0]), y=200.0)  # far from everything
    c = closure_pairs([out_and_back, other, _line(np.array([30.0]), y=3.0)])
    assert len(c) and set(c[:, 0]) | set(c[:, 2]) <= {0, 2}
    own = c[(c[:, 0] == 0) & (c[:, 2] == 0)]
    travel = 2.0 * np.abs(own[:, 3] - own[:, 1])
    assert len(own) and np.all(travel > 30.0)
    assert len(c[(c[:, 0] == 0) & (c[:, 2] == 2)]) > 0


def test_oracle_recovers_the_truth_from_drifting_odometry() -> None:
    pytest.importorskip("gtsam")
    from sgloc.evaluation.fleet_oracle import oracle_fleet

    true = _loop()
    gt = [true[:200], true[150:]]  # two robots sharing the stretch 150-199
    # each robot's odometry in its first keyframe's frame, drifting
    odo = [drift_poses(np.linalg.inv(g[0]) @ g, 2.0, np.random.default_rng(k))
           for k, g in enumerate(gt)]
    T_fleet_gt = np.linalg.inv(gt[0][0])
    est = oracle_fleet(odo, gt, 0, 2.0)
    assert est is not None and all(e is not None for e in est)
    assert np.allclose(est[0][0], odo[0][0], atol=1e-4)  # the fleet frame: the root's odometry
    rigid = [odo[0], T_fleet_gt @ gt[1][0] @ odo[1]]  # each robot placed at its start
    before = rigid_rmse([r[:, :3, 3] for r in rigid], [g[:, :3, 3] for g in gt])
    after = rigid_rmse([e[:, :3, 3] for e in est], [g[:, :3, 3] for g in gt])
    assert before > 1.0 and after < 0.5 * before
    # where the robots meet, the perfect closures leave them in near agreement
    assert error_stats(encounter_errors(est, gt, T_fleet_gt))["p95"] < 0.5
    # without drift the oracle is the truth
    exact = [np.linalg.inv(g[0]) @ g for g in gt]
    est = oracle_fleet(exact, gt, 0, 0.0)
    assert max(np.abs(e - T_fleet_gt @ g).max() for e, g in zip(est, gt, strict=True)) < 1e-3


def test_fleet_keyframe_poses_are_the_sessions_trajectory() -> None:
    poses = _line(np.arange(3.0))

    class Session:
        def trajectory(self, robot):
            return (np.arange(3.0), poses) if robot == "a" else None

    assert np.array_equal(fleet_keyframe_poses(Session(), "a"), poses)
    assert fleet_keyframe_poses(Session(), "b") is None
