"""OnlineSession at scale: the vectorised scheduler and the memoised link selection give the
same answers as the plain loops they replace; the joint refinement runs on a growth budget;
a revoked link comes back only with new evidence."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sgloc.geometry import invert, make_transform
from sgloc.online import OnlineConfig, OnlineSession
from sgloc.online.loops import loop_error, loop_tolerance
from sgloc.online.records import Attempt
from sgloc.online.robots import backend as robots_backend
from sgloc.online.robots.link_selection import (
    Edge,
    select_consistent,
    spanning_forest,
    tree_poses,
)
from sgloc.online.schedule import PairSizes, due_pairs


def _yaw(deg: float, t) -> np.ndarray:
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return make_transform(R, np.asarray(t, float))


# -- the scheduler ---------------------------------------------------------------------------
def _due_loop(sizes, last, min_objects, ratio, objects):
    """The rule of `due_pairs`, one pair at a time (the reference)."""
    scored = []
    for j in range(len(sizes)):
        for i in range(j):
            if min(sizes[i], sizes[j]) < min_objects:
                continue
            prev = last.get((i, j))
            if prev is None:
                scored.append((math.inf, i, j))
                continue
            grow = max((sizes[i] - prev[0]) / max(prev[0], 1),
                       (sizes[j] - prev[1]) / max(prev[1], 1))
            if grow >= ratio or max(sizes[i] - prev[0], sizes[j] - prev[1]) >= objects:
                scored.append((grow, i, j))
    scored.sort(key=lambda s: (-s[0], s[1], s[2]))
    return [(i, j) for _, i, j in scored]


def test_due_pairs_equals_the_pairwise_rule():
    rng = np.random.default_rng(3)
    for t in range(300):
        n = int(rng.integers(0, 25))
        sizes = [int(x) for x in rng.integers(0, 60, n)]
        last = {(i, j): (int(rng.integers(0, sizes[i] + 1)), int(rng.integers(0, sizes[j] + 1)))
                for i in range(n) for j in range(i + 1, n) if rng.uniform() < 0.6}
        ratio, objects = [(0.1, 10), (0.0, 1), (math.inf, 0), (0.5, 3)][t % 4]
        want = _due_loop(sizes, last, 6, ratio, objects)
        stored = PairSizes(last)
        assert due_pairs(sizes, last, 6, ratio, objects) == want
        assert due_pairs(sizes, stored, 6, ratio, objects) == want
        if n:
            r = int(rng.integers(0, n))
            assert due_pairs(sizes, stored, 6, ratio, objects, r) == [p for p in want if r in p]


def test_pair_sizes_keeps_its_arrays_in_step_with_the_dict():
    p = PairSizes({(0, 1): (5, 6)})
    p[(2, 40)] = (7, 8)  # grows the arrays
    assert p == {(0, 1): (5, 6), (2, 40): (7, 8)}
    A, B = p.arrays(41)
    assert (A[0, 1], B[0, 1], A[2, 40], B[2, 40]) == (5, 6, 7, 8)
    assert p.pop((0, 1)) == (5, 6) and p.pop((0, 1), None) is None
    A, B = p.arrays(41)
    assert A[0, 1] == -1 and B[0, 1] == -1 and (A >= 0).sum() == 1
    assert due_pairs([10, 10, 10], p, 6, 0.1, 10) == [(0, 1), (0, 2), (1, 2)]


# -- link selection --------------------------------------------------------------------------
def _select_loop(n, edges, points, tol_m, tol_deg):
    """`select_consistent` as first written: every loop's error recomputed in every round,
    each fundamental cycle's closing pose from `tree_poses` (the reference)."""
    ids, dropped = list(range(len(edges))), {}

    def vote(T, robot, loop, bad, good):
        err, lim = loop_error(T, points(robot)), loop_tolerance(tol_m, tol_deg, len(loop))
        votes = bad if err[0] > lim[0] or err[1] > lim[1] else good
        for k in loop:
            votes[k] = votes.get(k, 0) + 1

    def rel(e, frm):
        return e.T_a_b if frm == e.a else invert(e.T_a_b)

    while ids:
        bad, good = {}, {}
        by_pair = {(min(edges[k].a, edges[k].b), max(edges[k].a, edges[k].b)): k for k in ids}
        for (a, b), kab in by_pair.items():
            for c in range(b + 1, n):
                if (a, c) in by_pair and (b, c) in by_pair:
                    kbc, kac = by_pair[(b, c)], by_pair[(a, c)]
                    T = rel(edges[kab], a) @ rel(edges[kbc], b) @ rel(edges[kac], c)
                    vote(T, a, (kab, kbc, kac), bad, good)
        if not bad:  # the cycles vote afresh
            good, tree = {}, spanning_forest(n, edges, ids)
            for k in ids:
                if k not in tree:
                    poses, paths = tree_poses(n, edges, tree, edges[k].a)
                    T = rel(edges[k], edges[k].a) @ invert(poses[edges[k].b])
                    vote(T, edges[k].a, (k, *paths[edges[k].b]), bad, good)
        if not bad:
            break
        worst = max(bad, key=lambda k: (bad[k], -good.get(k, 0), -edges[k].confidence,
                                        edges[k].stamp, k))
        dropped[worst] = (
            f"contradicted: disagrees around {bad[worst]} loop(s) of links by more than "
            f"{tol_m:g} m / {tol_deg:g} deg per link (agrees around {good.get(worst, 0)})"
        )
        ids.remove(worst)
    return ids, dropped


def test_select_consistent_equals_the_plain_loops():
    rng = np.random.default_rng(5)
    dropped_any = 0
    for _ in range(150):
        n = int(rng.integers(3, 12))
        truth = [_yaw(rng.uniform(-180, 180), rng.uniform(-100, 100, 3)) for _ in range(n)]
        pts = [rng.normal(size=(15, 3)) * 30 for _ in range(n)]
        edges = []
        for i in range(n):
            for j in range(i + 1, n):
                if rng.uniform() < 0.5:
                    wrong = rng.uniform() < 0.25
                    off = _yaw(rng.normal() * (8 if wrong else 0.5),
                               rng.normal(size=3) * (5 if wrong else 0.4))
                    edges.append(Edge(i, j, invert(truth[i]) @ truth[j] @ off,
                                      float(rng.uniform(0.5, 1)), float(len(edges))))
        want = _select_loop(n, edges, pts.__getitem__, 3.0, 3.0)
        assert select_consistent(n, edges, pts.__getitem__, 3.0, 3.0) == want
        dropped_any += bool(want[1])
    assert dropped_any > 20  # the comparison covers rounds that drop links


# -- the joint refinement's budget ------------------------------------------------------------
@pytest.fixture
def counted(monkeypatch):
    calls = []
    real = robots_backend.refine_fleet

    def counting(*args, **kwargs):
        calls.append(len(args[0]))
        return real(*args, **kwargs)

    monkeypatch.setattr(robots_backend, "refine_fleet", counting)
    return calls


def _fleet(growth: float, maps: int = 3):
    """Three robots seeing one scattered layout, linked exactly; returns the session."""
    rng = np.random.default_rng(2)
    pts = rng.uniform(-30, 30, (40, 3))
    lab = rng.integers(0, 4, 40)
    s = OnlineSession(online=OnlineConfig(min_observations=1, max_attempts=0,
                                          refine_fleet_growth=growth, backend="robots"))
    for r in ["a", "b", "c"][:maps]:
        s.add_keyframe(r, 0.0, np.eye(4), pts[:20], lab[:20])
    return s, pts, lab


def test_joint_refinement_reruns_only_after_growth(counted):
    s, pts, lab = _fleet(0.10)
    cov = np.eye(6) * 1e-4
    s.add_link("a", "b", _yaw(0.2, [0.1, 0, 0]), cov)  # first run: 2 robots
    s.add_link("a", "c", _yaw(-0.2, [0, 0.1, 0]), cov)  # c's 20 objects: 40 -> 60
    assert counted == [2, 3]
    T_b = s.T_fleet_robot("b")
    # A link change that moves b's pose-graph frame: no growth, so no rerun; b keeps its
    # correction, applied to the new pose-graph frame.
    fix = invert(_yaw(0.2, [0.1, 0, 0])) @ T_b
    s.add_link("a", "b", _yaw(0.3, [0.2, 0, 0]), cov)
    assert counted == [2, 3]
    np.testing.assert_allclose(s.T_fleet_robot("b"), _yaw(0.3, [0.2, 0, 0]) @ fix, atol=1e-12)
    # 6 new objects of a (60 -> 66, 10 %): due again.
    s.add_keyframe("a", 1.0, np.eye(4), pts[20:26], lab[20:26])
    s.add_link("a", "b", _yaw(0.1, [0.1, 0, 0]), cov)
    assert counted == [2, 3, 3]


def test_joint_refinement_with_growth_zero_runs_at_every_change(counted):
    s, _, _ = _fleet(0.0)
    cov = np.eye(6) * 1e-4
    for k in range(3):
        s.add_link("a", "b", _yaw(0.1 * k, [0.1, 0, 0]), cov)
    assert counted == [2, 2, 2]


# -- re-acceptance needs new evidence ----------------------------------------------------------
def _attempt(s, T, matches, stamp):
    """Store an accepted attempt of the pair (a, b) with `matches` inliers and re-solve."""
    sizes = [s._state.maps[r].n_confirmed for r in s.robots]
    r = Attempt("", "", 0.0, True, T, confidence=1.0, n_matches=matches, reason="", seconds=0.0,
                sizes=(0, 0), covariance=np.eye(6) * 1e-4)  # as a worker returns it
    n = len(s.events)
    s._backend.record(0, 1, sizes, r, stamp)
    s._refresh(stamp)
    return [e.kind for e in s.events[n:]]


def test_a_revoked_link_comes_back_only_with_more_matches():
    # New evidence: at least growth_objects (10) more matches than a revoked link of the pair
    # had, or growth_ratio (10 %) more, whichever is more.
    s, _, _ = _fleet(0.1, maps=2)
    one, other = _yaw(0, [0, 0, 0]), _yaw(20, [30, 0, 0])
    assert _attempt(s, one, 20, 1.0) == ["link_accepted", "robot_joined"]
    # A later attempt disagrees: the first link is revoked; with 29 matches (< 20 + 10) the
    # new answer is held back too, with 30 it is taken.
    assert _attempt(s, other, 29, 2.0) == ["link_revoked"]
    assert s.T_fleet_robot("b") is None and "held back" in s.links[0].reason
    assert _attempt(s, other, 30, 2.5) == ["link_accepted", "robot_joined"]
    # The first answer again, on too little new evidence: the second link is revoked (it
    # disagrees) and the first answer stays out until it has 40 matches (30 + 10).
    assert _attempt(s, one, 35, 3.0) == ["link_revoked"]
    assert not s.links[0].active and "held back" in s.links[0].reason
    assert _attempt(s, one, 39, 4.0) == []
    assert _attempt(s, one, 40, 5.0) == ["link_accepted", "robot_joined"]
    np.testing.assert_allclose(s.T_fleet_robot("b"), one, atol=1e-9)
    # A bigger revoked link raises the margin to 10 % of its matches.
    s._backend.revoked[(0, 1)] = 200
    s.links[0].active = False
    assert _attempt(s, one, 219, 6.0) == [] and "220 matches" in s.links[0].reason


def test_the_hold_survives_save_and_resume(tmp_path):
    s, _, _ = _fleet(0.1, maps=2)
    _attempt(s, _yaw(0, [0, 0, 0]), 20, 1.0)
    _attempt(s, _yaw(20, [30, 0, 0]), 30, 2.0)
    _attempt(s, _yaw(0, [0, 0, 0]), 35, 3.0)
    resumed = OnlineSession.load(s.save(tmp_path / "s.npz"))
    for x in (s, resumed):
        assert _attempt(x, _yaw(0, [0, 0, 0]), 39, 4.0) == []
    np.testing.assert_array_equal(s.T_fleet_robot("a"), resumed.T_fleet_robot("a"))


def test_the_joint_refinement_runs_on_the_final_maps_once_every_robot_finished(counted):
    s, pts, lab = _fleet(0.10)
    cov = np.eye(6) * 1e-4
    s.add_link("a", "b", _yaw(0.2, [0.1, 0, 0]), cov)
    s.add_link("a", "c", _yaw(-0.2, [0, 0.1, 0]), cov)
    s.add_keyframe("a", 1.0, np.eye(4), pts[20:22], lab[20:22])  # 60 -> 62: not due
    s.add_link("a", "b", _yaw(0.3, [0.1, 0, 0]), cov)
    assert counted == [2, 3]
    s.finish("a")
    s.finish("b")
    assert counted == [2, 3]  # c is still running
    s.finish("c")
    assert counted == [2, 3, 3]
    s.finish("c")
    assert counted == [2, 3, 3]  # nothing changed since
    s.add_keyframe("b", 2.0, np.eye(4), pts[22:24], lab[22:24])  # b runs again
    s.finish("a")
    assert counted == [2, 3, 3]
    s.finish("b")
    assert counted == [2, 3, 3, 3]
