"""Links refitted on every object pair two grown maps share (sgloc.online.refine)."""

from __future__ import annotations

import numpy as np

from sgloc.estimation import MotionModel
from sgloc.estimation.covariance import point_covariance
from sgloc.evaluation.fleet_scenes import world_fleet
from sgloc.geometry import apply, invert, make_transform, rotation_angle_deg
from sgloc.online import OnlineConfig, OnlineSession
from sgloc.online.refine import co_located, refit_link


def _yaw(deg: float, t) -> np.ndarray:
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return make_transform(R, np.asarray(t, float))


def _scene(rng, n=300, noise=0.3):
    """Robot a's objects (a's frame), robot b's sightings of the same objects (b's frame, noisy),
    and the true T_a_b."""
    pos_a = np.column_stack([rng.uniform(0, 300, n), rng.uniform(-15, 15, n), rng.uniform(0, 3, n)])
    lab = rng.integers(0, 5, n)
    T_a_b = _yaw(35.0, [12.0, -40.0, 0.5])
    pos_b = apply(invert(T_a_b), pos_a + rng.normal(0, noise, pos_a.shape))
    return pos_a, lab, pos_b, T_a_b


def _error(T, T_true, pts):
    c = pts.mean(axis=0, keepdims=True)
    return float(np.linalg.norm(apply(T, c) - apply(T_true, c))), rotation_angle_deg(
        T[:3, :3] @ T_true[:3, :3].T)


def test_refit_on_all_co_located_objects_is_more_precise_and_its_covariance_shrinks(rng):
    pos_a, lab, pos_b, T_true = _scene(rng)
    motion = MotionModel(4, 15.0)
    # An early link: fitted on the 12 objects of a small overlap at one end of the maps.
    few = np.argsort(pos_a[:, 0])[:12]
    early = refit_link(pos_b[few], lab[few], pos_a[few], lab[few], T_true, motion, 2.0)
    start = early.T_a_b @ _yaw(0.8, [0.6, -0.4, 0.0])  # and off by the imprecision of such a fit
    full = refit_link(pos_b, lab, pos_a, lab, start, motion, 2.0)
    assert full.n_pairs > 250
    e0, e1 = _error(start, T_true, pos_b), _error(full.T_a_b, T_true, pos_b)
    assert e1[0] < 0.25 * e0[0] and e1[1] < 0.25 * e0[1]
    # Where robot b's map is, the refit's covariance is far tighter than the early fit's.
    c = pos_b.mean(axis=0)
    var_early = np.trace(point_covariance(early.covariance, c))
    assert np.trace(point_covariance(full.covariance, c)) < 0.2 * var_early
    assert full.covariance[2, 2] < 0.5 * early.covariance[2, 2]  # yaw
    # Deterministic, and None when nothing is co-located.
    again = refit_link(pos_b, lab, pos_a, lab, start, motion, 2.0)
    np.testing.assert_array_equal(full.T_a_b, again.T_a_b)
    assert refit_link(pos_b, lab, pos_a + 500.0, lab, start, motion, 2.0) is None


def test_co_located_pairs_are_mutual_same_class_and_within_the_radius():
    dst = np.array([[0.0, 0, 0], [1.0, 0, 0], [10.0, 0, 0]])
    src = np.array([[0.1, 0, 0], [0.2, 0, 0], [10.5, 0, 0], [1.0, 0, 0]])
    i, j = co_located(src, np.array([0, 0, 0, 1]), dst, np.array([0, 0, 0]), np.eye(4), 1.0)
    # src 0 and 1 both nearest to dst 0: only the mutual one pairs; src 3 is another class.
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == [(0, 0), (2, 2)]


def _run(refine: bool):
    scene = world_fleet(0)
    frames = []
    for r in (0, 1):
        g = scene.graphs[r]
        order = np.argsort(g.positions[:, 0], kind="stable")
        for k, part in enumerate(np.array_split(order, 6)):
            frames.append((float(k) + 0.1 * r, g.name, g.positions[part], g.labels[part]))
    s = OnlineSession(online=OnlineConfig(min_observations=1, max_attempts=None, min_objects=10,
                                          refine_links=refine, backend="robots"))
    errors = []
    for stamp, r, p, lab in sorted(frames):
        s.add_keyframe(r, stamp, np.eye(4), p, lab)
        if s.links:
            lk = s.links[0]
            G = invert(scene.T_gt_robot[0]) @ scene.T_gt_robot[1]
            errors.append(_error(lk.T_a_b, G, s.map("world1").positions))
    return s, errors


def test_a_session_refits_its_link_as_the_maps_grow_and_that_is_more_precise():
    s, refined = _run(True)
    s_off, plain = _run(False)
    lk, lk_off = s.links[0], s_off.links[0]
    assert lk.active and lk.refined_pairs > lk.n_matches and lk_off.refined_pairs == 0
    # At the end the refitted link is closer to the truth than the localizations alone.
    assert refined[-1][0] < plain[-1][0] and refined[-1][0] < 0.5
    assert np.trace(lk.covariance[3:, 3:]) < np.trace(lk_off.covariance[3:, 3:])


def test_chain_covariance_matches_the_spread_of_composed_noisy_links():
    from sgloc.lie import se3_exp, se3_log
    from sgloc.online.robots.link_selection import Edge
    from sgloc.online.robots.precision import chain_covariance

    rng = np.random.default_rng(5)
    T01, T21 = _yaw(30, [40.0, 5.0, 0.0]), _yaw(-50, [10.0, -30.0, 1.0])  # the second one 2 -> 1
    A = rng.normal(size=(6, 6)) * 0.02
    C01, C21 = A @ A.T + np.eye(6) * 1e-4, np.diag([1e-4, 2e-4, 3e-4, 0.04, 0.01, 0.02])
    edges = [Edge(0, 1, T01, 1.0, 0.0), Edge(2, 1, T21, 1.0, 0.0)]
    C = chain_covariance(edges, [C01, C21], [0, 1], 0)  # robot 2's pose via 0 -> 1 -> 2
    T02 = T01 @ invert(T21)
    L01, L21 = np.linalg.cholesky(C01), np.linalg.cholesky(C21)
    xs = []
    for _ in range(4000):
        a, b = se3_exp(L01 @ rng.normal(size=6)), se3_exp(L21 @ rng.normal(size=6))
        xs.append(se3_log(np.linalg.solve(T02, (T01 @ a) @ invert(T21 @ b))))
    mc = np.cov(np.array(xs).T)
    np.testing.assert_allclose(np.sqrt(np.diag(C)), np.sqrt(np.diag(mc)), rtol=0.1)


def test_a_join_is_held_back_until_its_link_predicts_an_error_within_the_limits():
    pts = np.random.default_rng(3).uniform(-20, 20, (10, 3)) + [150.0, 0.0, 0.0]
    T = _yaw(10, [5.0, 2.0, 0.0])
    loose = np.diag(np.r_[[np.radians(2.0) ** 2] * 3, [0.5**2] * 3])  # 2 deg: far off at 150 m
    tight = np.diag(np.r_[[np.radians(0.2) ** 2] * 3, [0.2**2] * 3])
    for sigmas, joins_at_once in ((None, True), (2.0, False)):
        s = OnlineSession(online=OnlineConfig(min_observations=1, max_attempts=0,
                                              join_sigmas=sigmas, backend="robots"))
        for r in ("a", "b"):
            s.add_keyframe(r, 0.0, np.eye(4), pts, np.zeros(10, np.int64))
        ev = s.add_link("a", "b", T, loose, stamp=1.0)
        assert ("robot_joined" in [e.kind for e in ev]) == joins_at_once
        assert (s.T_fleet_robot("b") is not None) == joins_at_once
        if not joins_at_once:  # a tighter estimate of the same link lets it join
            ev = s.add_link("a", "b", T @ _yaw(0.1, [0.1, 0, 0]), tight, stamp=2.0)
            assert [e.kind for e in ev] == ["robot_joined"]
            np.testing.assert_allclose(s.T_fleet_robot("b"), T @ _yaw(0.1, [0.1, 0, 0]))
