"""OnlineSession: association of repeated sightings, scheduling, revocation, save/resume,
pose graph solvers, g2o export. The link and frame tests run the back-end "robots" (one rigid
frame per robot, `ROBOTS`); the keyframe back-end's are in test_keyframe_session.py."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.errors import SglocError
from sgloc.evaluation.fleet_scenes import fleet_errors, world_fleet
from sgloc.geometry import apply, invert, make_transform, random_rigid_transform
from sgloc.io.g2o import read_g2o
from sgloc.online import Event, Link, OnlineConfig, OnlineSession
from sgloc.online.loops import invert_with_covariance
from sgloc.online.robots.link_selection import Edge
from sgloc.online.robots.solve import solve_pose_graph
from sgloc.online.schedule import due_pairs

ROBOTS = {"backend": "robots"}


def _yaw(deg: float, t) -> np.ndarray:
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return make_transform(R, np.asarray(t, float))


def test_two_noisy_sightings_become_one_object_at_their_mean():
    s = OnlineSession(online=OnlineConfig(association_radius=1.5, min_observations=2))
    obj = np.array([[10.0, 5.0, 1.0], [30.0, -4.0, 0.5]])
    lab = np.array([3, 3])
    noise = np.array([[0.4, -0.3, 0.1], [-0.2, 0.5, 0.0]])
    poses = [_yaw(0, [0, 0, 0]), _yaw(30, [5, 2, 0])]
    seen = []
    for k, T in enumerate(poses):
        seen.append(obj + (noise if k == 0 else -0.5 * noise))
        s.add_keyframe("r", float(k), T, apply(invert(T), seen[-1]), lab)
        if k == 0:
            assert len(s.map("r")) == 0  # seen once: held back until confirmed
    m = s.map("r")
    assert len(m) == 2
    np.testing.assert_allclose(m.positions, 0.5 * (seen[0] + seen[1]), atol=1e-9)
    # Another class at the same place is another object; a far sighting is a new one.
    s.add_keyframe("r", 2.0, np.eye(4), np.array([[10.0, 5.0, 1.0], [60.0, 0, 0]]),
                   np.array([4, 3]))
    assert len(s.map("r")) == 2
    s.add_keyframe("r", 3.0, np.eye(4), np.array([[10.2, 5.0, 1.0], [60.0, 0.5, 0]]),
                   np.array([4, 3]))
    assert len(s.map("r")) == 4


def test_scheduler_retries_a_pair_only_after_growth():
    assert due_pairs([20, 20], {}, 6, 0.1, 10) == [(0, 1)]
    assert due_pairs([20, 21], {(0, 1): (20, 20)}, 6, 0.1, 10) == []
    assert due_pairs([20, 22], {(0, 1): (20, 20)}, 6, 0.1, 10) == [(0, 1)]
    assert due_pairs([5, 22], {}, 6, 0.1, 10) == []


def _session(names=("a", "b", "c", "d")):
    s = OnlineSession(online=OnlineConfig(min_observations=1, max_attempts=0, **ROBOTS))
    pts = np.random.default_rng(1).uniform(-20, 20, (10, 3))
    for r in names:
        s.add_keyframe(r, 0.0, np.eye(4), pts, np.zeros(10, np.int64))
    return s


def test_a_wrong_link_is_revoked_when_consistent_links_outvote_it():
    G = {r: _yaw(20 * k, [50.0 * k, 10.0 * k, 0]) for k, r in enumerate("abcd")}
    cov = np.diag([1e-4] * 3 + [0.01] * 3)

    def rel(a, b):
        return invert(G[a]) @ G[b]

    s = _session()
    wrong = _yaw(10, [25, 0, 0]) @ rel("a", "b")
    ev = s.add_link("a", "b", wrong, cov, confidence=1.0, stamp=1.0)
    assert [e.kind for e in ev] == ["link_accepted", "robot_joined"]
    assert np.allclose(s.T_fleet_robot("b"), wrong)
    s.add_link("b", "c", rel("b", "c"), cov, 0.99, 2.0)
    s.add_link("a", "c", rel("a", "c"), cov, 0.99, 3.0)  # one bad loop: not yet outvoted
    assert {(lk.robot_a, lk.robot_b) for lk in s.links if lk.active} >= {("a", "b")}
    assert not [e for e in s.events if e.kind == "link_revoked"]
    s.add_link("a", "d", rel("a", "d"), cov, 0.99, 4.0)
    # Now a-b disagrees around two loops (a-b-c, a-b-d), every other link around one.
    ev = s.add_link("b", "d", rel("b", "d"), cov, 0.99, 5.0)
    assert [(e.kind, e.robots) for e in ev][0] == ("link_revoked", ("a", "b"))
    s.add_link("c", "d", rel("c", "d"), cov, 0.99, 6.0)
    revoked = [e for e in s.events if e.kind == "link_revoked"]
    assert [e.robots for e in revoked] == [("a", "b")] and revoked[0].stamp == 5.0
    assert "loop" in revoked[0].detail
    ab = next(lk for lk in s.links if (lk.robot_a, lk.robot_b) == ("a", "b"))
    assert not ab.active and all(lk.active for lk in s.links if lk is not ab)
    for r in "abcd":
        np.testing.assert_allclose(s.T_fleet_robot(r), rel("a", r), atol=1e-6)
    assert isinstance(ev[0], Event)


def test_root_choice_and_unknown_robot():
    s = _session(("a", "b"))
    T = _yaw(40, [3, 4, 0])
    s.add_link("a", "b", T, np.eye(6) * 0.01)
    np.testing.assert_allclose(s.T_fleet_robot("b"), T)
    s.set_root("b")
    np.testing.assert_allclose(s.T_fleet_robot("b"), np.eye(4))
    np.testing.assert_allclose(s.T_fleet_robot("a"), invert(T), atol=1e-12)
    with pytest.raises(SglocError, match="unknown robot"):
        s.T_fleet_robot("z")
    with pytest.raises(SglocError):
        s.add_keyframe("a", float("nan"), np.eye(4), np.zeros((1, 3)), np.zeros(1, int))


def test_link_inversion_keeps_the_covariance_convention(rng):
    # T_a_b Exp(xi) with xi ~ N(0, cov) in b's frame; its inverse's spread must match.
    T = random_rigid_transform(rng, 30.0, 180.0)
    L = rng.normal(size=(6, 6)) * 0.05
    cov = L @ L.T
    from scipy.linalg import expm, logm

    def hat(xi):
        r, t = xi[:3], xi[3:]
        M = np.zeros((4, 4))
        M[:3, :3] = [[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]]
        M[:3, 3] = t
        return M

    T_inv, cov_inv = invert_with_covariance(T, cov)
    xs = rng.multivariate_normal(np.zeros(6), cov, 400)
    ys = []
    for xi in xs:
        E = invert(T_inv) @ invert(T @ expm(hat(xi)))  # = Exp(eta), eta in a's frame
        M = np.real(logm(E))
        ys.append([M[2, 1], M[0, 2], M[1, 0], *M[:3, 3]])
    emp = np.cov(np.array(ys).T)
    assert np.allclose(emp, cov_inv, atol=0.15 * np.abs(cov_inv).max())


def _loopy_problem(rng, n=5, noise=0.05):
    G = [np.eye(4)] + [random_rigid_transform(rng, 60.0, 180.0) for _ in range(n - 1)]
    edges, covs = [], []
    for i in range(n):
        for j in range(i + 1, n):
            xi = rng.normal(0, noise, 6)
            from scipy.spatial.transform import Rotation

            E = make_transform(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:])
            edges.append(Edge(i, j, invert(G[i]) @ G[j] @ E, 1.0, 0.0))
            covs.append(np.diag([noise**2] * 6))
    initial = {0: np.eye(4)}
    for j in range(1, n):
        initial[j] = edges[j - 1].T_a_b  # the star from robot 0
    return G, edges, covs, initial


def test_gtsam_and_scipy_solvers_agree(rng):
    G, edges, covs, initial = _loopy_problem(rng)
    a = solve_pose_graph(initial, edges, covs, 0, "gtsam")
    b = solve_pose_graph(initial, edges, covs, 0, "scipy")
    for k in initial:
        np.testing.assert_allclose(a[k], b[k], atol=1e-4)

    def rms(P):
        return np.sqrt(np.mean([np.sum((P[k][:3, 3] - G[k][:3, 3]) ** 2) for k in P]))

    # Least squares over all 10 links beats the star of 4 it started from.
    assert rms(a) < rms(initial)


def _keyframes(scene, robots, per_robot=3):
    """Each robot's map cut into `per_robot` keyframes along x (its own frame, sensor = odom),
    interleaved by stamp."""
    out = []
    for r in robots:
        g = scene.graphs[r]
        order = np.argsort(g.positions[:, 0], kind="stable")
        for k, part in enumerate(np.array_split(order, per_robot)):
            out.append((float(k) + 0.1 * r, g.name, g.positions[part], g.labels[part]))
    return sorted(out)


@pytest.fixture(scope="module")
def stream():
    scene = world_fleet(0)
    return scene, _keyframes(scene, [0, 1, 2])


def test_save_and_resume_give_the_same_frames(tmp_path, stream):
    scene, frames = stream
    cfg = OnlineConfig(min_observations=1, max_attempts=None, min_objects=10, **ROBOTS)
    s = OnlineSession(online=cfg)
    half = len(frames) // 2
    for stamp, r, p, lab in frames[:half]:
        s.add_keyframe(r, stamp, np.eye(4), p, lab)
    path = s.save(tmp_path / "session.npz")
    resumed = OnlineSession.load(path)
    assert resumed.robots == s.robots and len(resumed.links) == len(s.links)
    for stamp, r, p, lab in frames[half:]:
        a = s.add_keyframe(r, stamp, np.eye(4), p, lab)
        b = resumed.add_keyframe(r, stamp, np.eye(4), p, lab)
        assert a == b
    assert s.events == resumed.events
    placed = [r for r in s.robots if s.T_fleet_robot(r) is not None]
    assert len(placed) == 3
    for r in s.robots:
        np.testing.assert_array_equal(s.T_fleet_robot(r), resumed.T_fleet_robot(r))
        np.testing.assert_array_equal(s.map(r).positions, resumed.map(r).positions)
    T = {k: s.T_fleet_robot(r) for k, r in enumerate(s.robots)}
    for dt, dr in fleet_errors(T, scene.T_gt_robot, 0, scene.graphs).values():
        assert dt < 3.0 and dr < 3.0
    stamps, T_traj = resumed.trajectory("world1")
    assert stamps.tolist() == [f[0] for f in frames if f[1] == "world1"]
    np.testing.assert_array_equal(T_traj, np.broadcast_to(s.T_fleet_robot("world1"), T_traj.shape))
    joined = [e.robots[0] for e in s.events if e.kind == "robot_joined"]
    assert joined == ["world0", "world1", "world2"]
    # g2o: every placed robot a vertex, every active link an edge.
    vertices, edges = read_g2o(s.write_g2o(tmp_path / "links.g2o"))
    assert sorted(vertices) == [0, 1, 2]
    assert len(edges) == sum(lk.active for lk in s.links)
    assert all(isinstance(lk, Link) and lk.covariance.shape == (6, 6) for lk in s.links)


def test_budget_limits_attempts_per_keyframe(stream):
    _, frames = stream
    s = OnlineSession(online=OnlineConfig(min_observations=1, max_attempts=1, min_objects=10))
    for stamp, r, p, lab in frames:
        before = len(s.attempts)
        s.add_keyframe(r, stamp, np.eye(4), p, lab)
        assert len(s.attempts) - before <= 1
    assert len(s.attempts) >= 3


@pytest.mark.data
def test_online_map_equals_the_offline_map_on_kitti_scans():
    # The same scans streamed keyframe by keyframe give the map build_graph makes offline.
    from sgloc.datasets import make_dataset
    from sgloc.evaluation.pairs_kitti import kitti_graph, kitti_root

    root = kitti_root()
    offline = kitti_graph(root, 100, 260)
    s = OnlineSession(online=OnlineConfig(association_radius=3.0, min_observations=2,
                                          max_attempts=0))
    for f in make_dataset("kitti_objects", root, scans=(100, 260), start_frame=True):
        pts, lab = f.detections
        s.add_keyframe("car", float(f.index), f.T_map_sensor, pts, lab)
    online = s.map("car")
    assert len(online) == len(offline) > 50
    np.testing.assert_allclose(online.positions, offline.positions, atol=1e-9)
    np.testing.assert_array_equal(online.labels, offline.labels)


def test_a_newer_link_of_the_same_pair_that_disagrees_revokes_the_old_one():
    s = _session(("a", "b", "c"))
    cov = np.eye(6) * 0.01
    T1, T2 = _yaw(0, [10, 0, 0]), _yaw(0, [10.5, 0, 0])
    s.add_link("a", "b", T1, cov, stamp=1.0)
    assert s.add_link("a", "b", T2, cov, stamp=2.0) == []  # agrees: an update, no event
    ev = s.add_link("a", "b", _yaw(20, [40, 0, 0]), cov, stamp=3.0)
    assert [e.kind for e in ev] == ["link_revoked", "link_accepted"]
    assert "later attempt" in ev[0].detail
    np.testing.assert_allclose(s.T_fleet_robot("b"), _yaw(20, [40, 0, 0]))
    # A link given the other way round is inverted, covariance included.
    s.add_link("c", "a", invert(_yaw(5, [0, 7, 0])), cov, stamp=4.0)
    np.testing.assert_allclose(s.T_fleet_robot("c"), _yaw(5, [0, 7, 0]), atol=1e-12)


def test_confirmations_hold_a_link_back_until_attempts_agree():
    s = OnlineSession(online=OnlineConfig(min_observations=1, max_attempts=0, confirmations=2,
                                          **ROBOTS))
    pts = np.random.default_rng(2).uniform(-20, 20, (10, 3))
    for r in ("a", "b"):
        s.add_keyframe(r, 0.0, np.eye(4), pts, np.zeros(10, np.int64))
    cov = np.eye(6) * 0.01
    assert s.add_link("a", "b", _yaw(0, [10, 0, 0]), cov, stamp=1.0) == []
    assert s.T_fleet_robot("b") is None and "awaiting confirmation" in s.links[0].reason
    assert s.add_link("a", "b", _yaw(30, [60, 0, 0]), cov, stamp=2.0) == []  # disagrees
    assert s.links[0].agreed == 1 and s.T_fleet_robot("b") is None
    ev = s.add_link("a", "b", _yaw(30.5, [60.5, 0, 0]), cov, stamp=3.0)
    assert [e.kind for e in ev] == ["link_accepted", "robot_joined"]
    np.testing.assert_allclose(s.T_fleet_robot("b"), _yaw(30.5, [60.5, 0, 0]))


def test_loading_something_else_is_a_clear_error(tmp_path):
    bad = tmp_path / "x.npz"
    np.savez(bad, a=np.zeros(3))
    with pytest.raises(SglocError, match="not a saved online session"):
        OnlineSession.load(bad)
    with pytest.raises(SglocError, match="not a saved online session"):
        OnlineSession.load(tmp_path / "missing.npz")


def test_finish_tries_once_more_every_pair_whose_maps_changed(stream):
    # Growth thresholds never reached again: after the first attempts (small maps, rejected)
    # no pair is retried while keyframes come in; finish() tries the pairs of the finished
    # robot whose maps changed since, once, and the robots join.
    _, frames = stream
    cfg = OnlineConfig(min_observations=1, max_attempts=None, min_objects=10,
                       growth_ratio=100.0, growth_objects=100_000, **ROBOTS)
    s = OnlineSession(online=cfg)
    for stamp, r, p, lab in frames:
        s.add_keyframe(r, stamp, np.eye(4), p, lab)
    assert len(s.attempts) == 3 and not any(a.accepted for a in s.attempts)
    assert [s.T_fleet_robot(r) is not None for r in s.robots] == [True, False, False]
    events = s.finish("world1", stamp=9.0)
    new = s.attempts[3:]
    assert sorted((a.query, a.target) for a in new) == [("world1", "world0"),
                                                         ("world2", "world1")]
    assert all(a.stamp == 9.0 for a in new)
    joined = [e.robots[0] for e in events if e.kind == "robot_joined"]
    assert joined == ["world1", "world2"] and all(e.stamp == 9.0 for e in events)
    # Nothing changed since: a second finish tries nothing; another robot's finish only
    # what changed for it (world0-world2, untried since the first attempt).
    assert s.finish("world1") == [] and len(s.attempts) == 5
    s.finish("world0")
    assert [(a.query, a.target) for a in s.attempts[5:]] == [("world2", "world0")]
    with pytest.raises(SglocError, match="unknown robot"):
        s.finish("nobody")
