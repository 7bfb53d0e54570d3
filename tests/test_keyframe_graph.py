"""The keyframe pose graph: odometry and link factors, ISAM2 and the sparse fallback agree,
a drifting loop closes, a removed factor leaves as if never added."""

import numpy as np
import pytest

from sgloc import lie
from sgloc.errors import SglocError
from sgloc.online.config import OdometryNoise
from sgloc.online.keyframes.graph import KeyframeGraph, keyframe_link, odometry_link
from sgloc.online.keyframes.solve import gtsam_available

needs_gtsam = pytest.mark.skipif(not gtsam_available(), reason="gtsam not installed")


def _walk(rng, n, step=2.0, turn=0.05):
    """(n,4,4) a planar-ish random walk: true keyframe poses."""
    T = [np.eye(4)]
    for _ in range(n - 1):
        xi = np.r_[rng.normal(0, 0.01, 2), rng.normal(0, turn), step, rng.normal(0, 0.1, 2)]
        T.append(T[-1] @ lie.se3_exp(xi))
    return np.array(T)


def _drifted(truth, rng, noise=(0.002, 0.02), bias_deg_per_m=0.0):
    """Odometry of `truth`: each step perturbed (rad, m sigmas) and turned by a heading bias."""
    steps = lie.between(truth[:-1], truth[1:])
    d = np.linalg.norm(steps[:, :3, 3], axis=1)
    xi = rng.normal(0, 1, (len(steps), 6)) * np.repeat(noise, 3)
    xi[:, 2] += np.radians(bias_deg_per_m) * d
    steps = steps @ lie.se3_exp(xi)
    out = [truth[0]]
    for S in steps:
        out.append(out[-1] @ S)
    return np.array(out)


def _random_graph(solver, seed=0):
    rng = np.random.default_rng(seed)
    g = KeyframeGraph(OdometryNoise(), solver=solver, root=0)
    truths = {r: _walk(rng, 40) for r in range(3)}
    offsets = {0: np.eye(4), 1: lie.se3_exp([0, 0, 0.5, 10, 5, 0]),
               2: lie.se3_exp([0, 0, -0.3, -5, 20, 0])}
    for r, truth in truths.items():
        for T in _drifted(truth, rng):
            g.add_keyframe(r, T)
    fleet = {r: offsets[r] @ truths[r] for r in truths}
    cov = np.diag([1e-4] * 3 + [1e-2] * 3)
    for ra, rb in ((0, 1), (1, 2), (0, 2), (0, 0), (1, 1), (2, 0)):
        for _ in range(3):
            ka, kb = rng.integers(0, 40, 2)
            if ra == rb and ka == kb:
                continue
            Z = lie.between(fleet[ra][ka], fleet[rb][kb]) @ lie.se3_exp(rng.normal(0, 0.01, 6))
            g.add_link(ra, ka, rb, kb, Z, cov)
    return g


@needs_gtsam
def test_isam2_and_the_sparse_fallback_agree_on_a_random_graph_with_loops():
    out = {}
    for solver in ("gtsam", "scipy"):
        g = _random_graph(solver)
        g.solve()
        assert sorted(g.placed) == [0, 1, 2]
        out[solver] = np.concatenate([g.poses(r) for r in range(3)])
    assert np.abs(out["gtsam"] - out["scipy"]).max() < 1e-6
    # The fixed keyframe: the root's first, at its odometry pose.
    np.testing.assert_allclose(out["scipy"][0], np.eye(4), atol=1e-12)


@pytest.mark.parametrize("solver", ["scipy", pytest.param("gtsam", marks=needs_gtsam)])
def test_a_drifting_loop_closes_with_one_loop_closure(solver):
    rng = np.random.default_rng(1)
    n = 200  # a circle of 400 m in 2 m steps
    truth = np.array([lie.se3_exp([0, 0, 2 * np.pi * k / n, 0, 0, 0])
                      @ lie.se3_exp([0, 0, 0, 400 / (2 * np.pi), 0, 0]) for k in range(n)])
    odom = _drifted(truth, rng, noise=(1e-4, 1e-3), bias_deg_per_m=0.02)
    g = KeyframeGraph(OdometryNoise(), solver=solver)
    for T in odom:
        g.add_keyframe(0, T)
    g.solve()
    before = np.linalg.norm(g.poses(0)[-1, :3, 3] - truth[-1, :3, 3])
    assert before > 5.0  # the heading bias bends the loop open
    fid = g.add_link(0, n - 1, 0, 0, lie.between(truth[-1], truth[0]),
                     np.diag([1e-6] * 3 + [1e-4] * 3))
    g.solve()
    after = g.poses(0)
    assert np.linalg.norm(after[-1, :3, 3] - truth[-1, :3, 3]) < 0.05
    assert np.linalg.norm(after[:, :3, 3] - truth[:, :3, 3], axis=1).max() < before / 4
    g.remove(fid)
    g.solve()
    np.testing.assert_allclose(g.poses(0)[:, :3, 3], odom[:, :3, 3], atol=1e-6)


@pytest.mark.parametrize("solver", ["scipy", pytest.param("gtsam", marks=needs_gtsam)])
def test_removing_a_link_restores_the_previous_solution_and_robots_leave_when_disconnected(
        solver):
    g = _random_graph(solver, seed=2)
    g.solve()
    before = {r: g.poses(r) for r in range(3)}
    cov = np.diag([1e-4] * 3 + [1e-2] * 3)
    wrong = g.add_link(0, 5, 1, 7, lie.se3_exp([0, 0, 0.2, 3, 0, 0]), cov)
    g.solve()
    assert np.abs(g.poses(1) - before[1]).max() > 0.1
    g.remove(wrong)
    g.solve()
    for r in range(3):
        np.testing.assert_allclose(g.poses(r), before[r], atol=1e-6)
    for fid, f in g.factors().items():  # cut robot 2 off: it is no longer placed
        if f.kind == "link" and 2 in (f.robot_a, f.robot_b) and f.robot_a != f.robot_b:
            g.remove(fid)
    g.solve()
    assert sorted(g.placed) == [0, 1] and g.poses(2) is None and g.T_fleet_odom(2) is None


def test_odometry_noise_grows_with_distance_and_a_link_moves_to_keyframes():
    n = OdometryNoise(translation_per_metre=0.01, rotation_per_metre=0.01,
                      rotation_per_sqrt_metre=0.0, translation_floor=1e-3, rotation_floor=1e-3)
    C = n.covariance(np.stack([np.eye(4), lie.se3_exp([0, 0, 0, 100, 0, 0])]))
    assert np.sqrt(C[1, 3, 3]) == pytest.approx(np.hypot(1.0, 1e-3))
    assert np.sqrt(C[1, 2, 2]) == pytest.approx(np.radians(np.hypot(1.0, 1e-3)))
    assert np.sqrt(C[0, 0, 0]) == pytest.approx(np.radians(1e-3))
    rng = np.random.default_rng(3)
    Ta, Tb, T_ab = lie.se3_exp(rng.normal(0, 1, (3, 6)))
    cov = np.diag(rng.uniform(0.1, 1, 6))
    T, C = keyframe_link(Ta, T_ab, cov, Tb)
    np.testing.assert_allclose(Ta @ T, T_ab @ Tb, atol=1e-12)
    xi = rng.normal(0, 1e-4, 6)  # a perturbation of T_ab in b's frame moves to Tb's frame
    T2, _ = keyframe_link(Ta, T_ab @ lie.se3_exp(xi), cov, Tb)
    Ad = lie.adjoint(np.linalg.inv(Tb))
    np.testing.assert_allclose(lie.se3_log(np.linalg.inv(T) @ T2), Ad @ xi, atol=1e-10)
    np.testing.assert_allclose(C, Ad @ cov @ Ad.T, atol=1e-12)
    T3, C3 = odometry_link(Ta, T, C, Tb)  # and back to the odometry frames
    np.testing.assert_allclose(T3, T_ab, atol=1e-10)
    np.testing.assert_allclose(C3, cov, atol=1e-10)
    g = KeyframeGraph()
    g.add_keyframe(0, np.eye(4))
    with pytest.raises(SglocError, match="no keyframe"):
        g.add_link(0, 0, 0, 3, np.eye(4), np.eye(6))


def test_without_gtsam_the_sparse_solver_is_used(monkeypatch):
    import sgloc.online.keyframes.solve as ks

    monkeypatch.setattr(ks, "gtsam_available", lambda: False)
    assert isinstance(ks.make_solver("auto", 0, np.eye(4)), ks.SparseSolver)
    g = _random_graph("auto", seed=4)
    g.solve()
    assert sorted(g.placed) == [0, 1, 2]
