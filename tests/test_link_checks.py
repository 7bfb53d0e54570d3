"""Links checked against the odometry: pairwise consistency (a street-grid offset between two
robots with exact odometry is held, and says why), consistent links all enter, the bend check
takes out a link that would bend exact odometry, determinism."""

import numpy as np

from sgloc import lie
from sgloc.online import Link, OnlineConfig, OnlineSession
from sgloc.online.config import OdometryNoise
from sgloc.online.keyframes.consistency import (
    Chains,
    bend_chi2,
    consistent_sets,
    max_clique,
    stretch_covariance,
)
from sgloc.online.keyframes.links import select_links
from sgloc.online.keyframes.state import KeyframeState
from sgloc.online.records import LINK_HELD
from sgloc.online.robot_map import RobotMap

COV = np.diag([1e-4] * 3 + [1e-2] * 3)  # 0.6 deg, 0.1 m
LATTICE = lie.se3_exp([0, 0, 0, 80.0, 0, 0])  # one street-grid step
#: What a user tells the session of a good odometry (0.1 % of the distance, 0.0005 deg/m).
GOOD = OdometryNoise(translation_per_metre=0.001, rotation_per_metre=0.0005,
                     rotation_per_sqrt_metre=0.0005)


def _maps(n_robots, n_keyframes=30, step=4.0):
    """Robots driving a gentle curve in their own odometry frames (exact odometry)."""
    maps = []
    for r in range(n_robots):
        m = RobotMap(f"r{r}", 1.0, 1, 20.0)
        for k in range(n_keyframes):
            m.add(float(k), lie.se3_exp([0, 0, 0.01 * k, step * k, 0.02 * k * k, 0]),
                  np.array([[0.0, 5.0, 0.0]]), np.array([1]))
        maps.append(m)
    return maps


def _world(n):
    rng = np.random.default_rng(3)
    return {r: lie.se3_exp(np.r_[0, 0, rng.uniform(-1, 1), rng.uniform(-50, 50, 2), 0])
            for r in range(n)}


def _link(world, maps, a, ka, b, kb, n, stamp, off=None, cov=COV):
    """The link `world` (robot -> T_world_odom) implies between (a, ka) and (b, kb), moved by
    `off` (4,4, in kb's frame) when given; covariance `cov`."""
    T = lie.between(world[a] @ maps[a].poses[ka], world[b] @ maps[b].poses[kb])
    if off is not None:
        T = T @ off
    return Link(f"r{a}", f"r{b}", T, cov.copy(), 0.99, stamp, active=False, n_matches=n,
                keyframe_a=ka, keyframe_b=kb)


def _fleet(maps, noise=None):
    f = KeyframeState(OnlineConfig(backend="keyframes", solver="scipy",
                                   odometry=noise or OdometryNoise()))
    for r, m in enumerate(maps):
        for T in m.poses:
            f.graph.add_keyframe(r, T)
    return f


def _chains(maps, noise=None):
    return Chains({m.name: r for r, m in enumerate(maps)},
                  {r: m.trajectory()[1] for r, m in enumerate(maps)},
                  {r: m.travelled() for r, m in enumerate(maps)}, noise or OdometryNoise())


def _names(maps):
    return [m.name for m in maps]


def test_a_street_grid_offset_between_two_robots_is_held_and_says_why():
    maps, truth = _maps(2), _world(2)
    false = {0: truth[0], 1: LATTICE @ truth[1]}
    f = _fleet(maps)
    # Two true links, and a false one a street-grid step off with more matches than either
    # (fewer than both): the greedy selection alone would take it first.
    f.links = [_link(truth, maps, 0, 5, 1, 6, 30, 1.0), _link(truth, maps, 0, 20, 1, 22, 25, 2.0),
               _link(false, maps, 0, 12, 1, 12, 40, 3.0)]
    taken, _ = select_links(f.links, [0, 1, 2], {"r0": 0, "r1": 1},
                            {r: m.trajectory()[1] for r, m in enumerate(maps)},
                            {r: m.travelled() for r, m in enumerate(maps)}, OdometryNoise(),
                            3.0, 3.0)
    assert taken == [2]  # what the graph would have held without the checks
    assert f.update(maps, _names(maps)) == ([0, 1], [])
    assert f.newly_held == [2] and not f.links[2].active and not f.links[2].revoked
    assert "inconsistent with 2 link(s)" in f.links[2].reason
    assert "55 matches" in f.links[2].reason and "chi-square" in f.links[2].reason
    X = f.graph.poses(1)
    expected = np.linalg.inv(truth[0]) @ truth[1] @ maps[1].trajectory()[1]
    np.testing.assert_allclose(X[:, :3, 3], expected[:, :3, 3], atol=1e-6)
    # held once: a later update with nothing new holds it still, without a new notice
    assert f.update(maps, _names(maps)) == ([], []) and f.newly_held == []


def test_the_session_emits_link_held_with_the_reason():
    s = OnlineSession(online=OnlineConfig(backend="keyframes", min_observations=1,
                                          max_attempts=0, solver="scipy", refine_fleet=False))
    pts = np.random.default_rng(2).uniform(-20, 20, (10, 3))
    T_ab = lie.se3_exp([0, 0, 0.4, 30.0, -5.0, 0.0])
    events = []
    for k in range(30):
        T = lie.se3_exp([0, 0, 0.01 * k, 4.0 * k, 0, 0])
        for r in ("a", "b"):
            s.add_keyframe(r, float(k), T, pts, np.zeros(10, np.int64))
        if k in (5, 15):
            events += s.add_link("a", "b", T_ab, COV)
        if k == 25:  # the same pair a street-grid step off
            events += s.add_link("a", "b", T_ab @ LATTICE, COV)
    held = [e for e in events if e.kind == LINK_HELD]
    assert len(held) == 1 and held[0].robots == ("a", "b")
    assert "inconsistent" in held[0].detail and "keyframes 25 and 25" in held[0].detail
    np.testing.assert_allclose(s.T_fleet_robot("b"), T_ab, atol=1e-6)
    assert [lk.active for lk in s.links] == [True, True, False]


def test_consistent_links_all_enter_and_bend_nothing():
    maps, truth = _maps(3), _world(3)
    rng = np.random.default_rng(0)
    f = _fleet(maps)
    ends = [(0, 3, 1, 4), (0, 20, 1, 18), (1, 10, 2, 12), (1, 25, 2, 27), (0, 28, 2, 1),
            (2, 2, 0, 27), (1, 2, 1, 28)]
    for n, (a, ka, b, kb) in enumerate(ends):  # each off by what its covariance allows
        off = lie.se3_exp(rng.multivariate_normal(np.zeros(6), COV) * 0.5)
        f.links.append(_link(truth, maps, a, ka, b, kb, 20 + n, float(n), off))
    kept, held = consistent_sets(f.links, range(len(ends)), _chains(maps))
    assert kept == list(range(len(ends))) and held == {}
    entered, left = f.update(maps, _names(maps))
    assert entered == list(range(len(ends))) and left == [] and f.newly_held == []
    assert all(lk.active and lk.reason == "" for lk in f.links)
    *_, chi = bend_chi2(f.graph, _chains(maps))
    assert len(chi) and chi.max() < 16.81


def test_the_bend_check_takes_out_a_link_that_would_bend_exact_odometry():
    maps, truth = _maps(3), _world(3)
    f = _fleet(maps, GOOD)
    off = lie.se3_exp([0, 0, 0, 0, 2.0, 0])  # 2 m sideways: within the loop tolerance
    tight = np.diag([1e-6] * 3 + [1e-4] * 3)  # links surer than the odometry: it bends
    f.links = [_link(truth, maps, 0, 10, 1, 10, 40, 1.0, cov=tight),
               _link(truth, maps, 1, 20, 2, 20, 40, 2.0, cov=tight),
               _link(truth, maps, 0, 25, 2, 5, 15, 3.0, off, tight)]
    # One link per pair: no pairwise check applies, and the loop selection takes all three.
    chains = _chains(maps, GOOD)
    assert consistent_sets(f.links, [0, 1, 2], chains)[0] == [0, 1, 2]
    taken, _ = select_links(f.links, [0, 1, 2], chains.index, chains.odom, chains.travelled,
                            GOOD, 3.0, 3.0)
    assert taken == [0, 1, 2]
    # With all three the solution bends the robots' exact odometry beyond its noise.
    g = _fleet(maps, GOOD)
    g.links = f.links
    g._move([0, 1, 2], chains.index)
    assert bend_chi2(g.graph, chains)[3].max() > 16.81
    assert f.update(maps, _names(maps)) == ([0, 1], [])
    lk = f.links[2]
    assert f.newly_held == [2] and not lk.active and lk.revoked
    assert lk.reason.startswith("bent odometry") and "beyond its noise" in lk.reason
    assert bend_chi2(f.graph, chains)[3].max() < 1e-6  # the true links bend nothing
    # It does not come back: the next update leaves it out without a new notice.
    assert f.update(maps, _names(maps)) == ([], []) and f.newly_held == []


def test_a_loop_closure_is_checked_against_its_robots_odometry():
    maps, truth = _maps(1), _world(1)
    links = [_link(truth, maps, 0, 2, 0, 27, 20, 1.0),
             _link(truth, maps, 0, 3, 0, 26, 20, 2.0, lie.se3_exp([0, 0, 0, 0, 30.0, 0]))]
    kept, held = consistent_sets(links, [0, 1], _chains(maps))
    assert kept == [0] and "loop closure disagrees with its robot's odometry" in held[1]


def test_max_clique_exact_and_greedy():
    ok = np.zeros((5, 5), bool)
    for i, j in ((0, 1), (2, 3), (2, 4), (3, 4)):
        ok[i, j] = ok[j, i] = True
    w = np.array([5.0, 4.0, 3.0, 3.0, 2.0])
    assert max_clique(ok, w).tolist() == [True, True, False, False, False]  # 9 > 8
    w2 = np.array([5.0, 2.0, 3.0, 3.0, 3.0])
    assert max_clique(ok, w2).tolist() == [False, False, True, True, True]  # 9 > 7
    # ties: the set holding the first (preferred) item
    assert max_clique(np.zeros((3, 3), bool), np.ones(3)).tolist() == [True, False, False]
    # beyond the exact size: the greedy set is consistent and holds the heaviest group
    n = 20
    big = np.zeros((n, n), bool)
    big[:12, :12] = True
    big[12:, 12:] = True
    keep = max_clique(big, np.ones(n))
    assert keep[:12].all() and not keep[12:].any()
    C = stretch_covariance(OdometryNoise(), np.array([0.0, 100.0]))
    assert C.shape == (2, 6, 6) and C[1, 3, 3] > C[0, 3, 3] > 0


def test_checks_are_deterministic():
    out = []
    for _ in range(2):
        maps, truth = _maps(3), _world(3)
        false = {**truth, 2: LATTICE @ truth[2]}
        f = _fleet(maps)
        f.links = [_link(truth, maps, 0, 5, 1, 6, 30, 1.0), _link(truth, maps, 1, 9, 2, 9, 20, 2.0),
                   _link(false, maps, 1, 20, 2, 21, 25, 3.0),
                   _link(truth, maps, 0, 25, 2, 3, 12, 4.0, lie.se3_exp([0, 0, 0, 1.5, 1.5, 0]))]
        f.update(maps, _names(maps))
        out.append(([lk.reason for lk in f.links], [lk.active for lk in f.links],
                    np.concatenate([f.graph.poses(r) for r in f.graph.placed])))
    assert out[0][0] == out[1][0] and out[0][1] == out[1][1]
    assert np.array_equal(out[0][2], out[1][2])
