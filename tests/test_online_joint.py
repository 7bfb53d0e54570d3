"""The fleet frame refined together on every object pair the placed robots' maps co-locate
(sgloc.online.joint)."""

from __future__ import annotations

import numpy as np

from sgloc.geometry import apply, invert, make_transform, rotation_angle_deg
from sgloc.online.joint import co_located_pairs, largest_shift, refine_fleet


def _pose(deg: float, t, roll: float = 0.0) -> np.ndarray:
    a, r = np.radians(deg), np.radians(roll)
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    return make_transform(Rz @ Rx, np.asarray(t, float))


def _street(rng, x0, x1, n):
    pos = np.column_stack([rng.uniform(x0, x1, n), rng.uniform(-12, 12, n), rng.uniform(0, 3, n)])
    return pos, rng.integers(0, 4, n)


def _chain(rng, noise=0.0):
    """Three robots along a 400 m street (fleet frame = robot 0's): robot 1 meets robot 0 only
    at x 0-40 and drives to x 400; robot 2 starts at x 360 (where robot 1 ends) and drives back
    to x 0, where robot 0 also was. World objects: (positions, labels); each robot's objects in
    its own frame; the true frames."""
    world, lab = _street(rng, 0, 400, 800)
    true = {0: np.eye(4), 1: _pose(30.0, [5, 2, 0.3]), 2: _pose(-70.0, [-20, 8, -0.2])}
    seen = {0: (world[:, 0] < 40) | (world[:, 0] > 370), 1: world[:, 0] >= 0,
            2: (world[:, 0] > 360) | (world[:, 0] < 40)}
    objects = {}
    for r, mask in seen.items():
        p = world[mask] + rng.normal(0, noise, (int(mask.sum()), 3))
        objects[r] = (apply(invert(true[r]), p), lab[mask])
    return objects, true


def _start(true):
    """The true frames rotated about the first robot's origin and shifted a little."""
    return {0: true[0], 1: _pose(0.2, [0.3, -0.2, 0]) @ true[1],
            2: _pose(0.25, [0.4, 0.3, 0]) @ true[2]}


def _off(T, T_true, pts):
    """(metres at the centroid of the robot's objects pts (its frame), degrees)."""
    c = pts.mean(axis=0, keepdims=True)
    return float(np.linalg.norm(apply(T, c) - apply(T_true, c))), rotation_angle_deg(
        T[:3, :3] @ T_true[:3, :3].T)


def test_exact_maps_give_the_true_frames_back_from_a_rotated_chain(rng):
    objects, true = _chain(rng)
    # As a chain of links would place them: robot 1 off by 0.2 deg (~1.4 m at its far end),
    # robot 2 (placed through robot 1) by 0.25 deg.
    start = _start(true)
    assert _off(start[1], true[1], objects[1][0])[0] > 0.5
    out, n_pairs = refine_fleet(start, objects, 0, 2.0, dof=6)
    assert n_pairs > 200
    np.testing.assert_array_equal(out[0], true[0])  # the root stays where it is
    for r in (1, 2):
        m, deg = _off(out[r], true[r], objects[r][0])
        assert m < 1e-6 and deg < 1e-6
    again, _ = refine_fleet(start, objects, 0, 2.0, dof=6)
    for r in out:
        np.testing.assert_array_equal(out[r], again[r])


def test_noisy_maps_beat_the_chain_and_dof_4_keeps_roll_and_pitch(rng):
    objects, true = _chain(rng, noise=0.25)
    tilt = {1: _pose(0, [0, 0, 0], roll=0.4), 2: _pose(0, [0, 0, 0], roll=-0.3)}
    true = {0: true[0], 1: true[1] @ tilt[1], 2: true[2] @ tilt[2]}
    objects = {r: (apply(invert(tilt[r]), p) if r in tilt else p, lab)
               for r, (p, lab) in objects.items()}
    start = _start(true)
    out, _ = refine_fleet(start, objects, 0, 2.0, dof=4)
    for r in (1, 2):
        before, after = _off(start[r], true[r], objects[r][0]), _off(out[r], true[r],
                                                                      objects[r][0])
        assert after[0] < 0.3 * before[0] and after[1] < 0.3 * before[1]
        # Only yaw (about the fleet frame's z) and translation moved: the robot's axes keep
        # their heights, so its roll and pitch are the start's.
        np.testing.assert_allclose(out[r][2, :3], start[r][2, :3], atol=1e-12)


def test_robots_apart_from_the_root_keep_their_frames_and_pairs_need_three(rng):
    objects, true = _chain(rng)
    far = {**objects, 3: (objects[1][0][:2] + 1000.0, objects[1][1][:2])}
    start = {**true, 3: np.eye(4)}
    out, _ = refine_fleet(start, far, 0, 2.0)
    np.testing.assert_array_equal(out[3], start[3])
    # Two co-located objects are not an overlap (three fix a rigid motion).
    pos, lab = objects[0][0][:3], objects[0][1][:3]
    for n, expected in ((2, 0), (3, 3)):
        moved = np.concatenate([pos[:n], pos[:n] + 0.1])
        i, j = co_located_pairs(moved, np.concatenate([lab[:n], lab[:n]]),
                                np.repeat([0, 1], n), 2.0)
        assert len(i) == expected
    np.testing.assert_array_equal(i, [0, 1, 2])
    np.testing.assert_array_equal(j, [3, 4, 5])


def test_co_located_pairs_are_mutual_nearest_between_each_robot_pair():
    # Robot 0: two objects 1 m apart; robot 1: one object between them, nearer the first;
    # robot 2: a copy of robot 0's objects. Only mutual nearest pairs of each robot pair count.
    moved = np.array([[0.0, 0, 0], [1.0, 0, 0], [4.0, 0, 0],
                      [0.3, 0, 0], [4.2, 0, 0], [9.0, 0, 0],
                      [0.05, 0, 0], [1.05, 0, 0], [4.1, 0, 0], [9.1, 0, 0]])
    labels = np.zeros(10, int)
    robot_of = np.array([0, 0, 0, 1, 1, 1, 2, 2, 2, 2])
    i, j = co_located_pairs(moved, labels, robot_of, 0.5)
    got = sorted(zip(i.tolist(), j.tolist(), strict=True))
    # Robots 0-1: (0,3) and (2,4) are mutual (object 1 is within reach of 3, but 0 is
    # nearer): 2 pairs, dropped.
    # Robots 0-2: (0,6), (1,7), (2,8). Robots 1-2: (3,6), (4,8), (5,9).
    assert got == [(0, 6), (1, 7), (2, 8), (3, 6), (4, 8), (5, 9)]


def test_largest_shift_is_measured_at_each_robots_objects():
    pts = {0: np.array([[100.0, 0, 0], [102.0, 0, 0]])}
    before = {0: np.eye(4)}
    after = {0: _pose(1.0, [0, 0, 0])}  # 1 deg about the origin: ~1.78 m at x = 101
    m, deg = largest_shift(before, after, pts)
    assert abs(deg - 1.0) < 1e-9 and abs(m - 2 * 101 * np.sin(np.radians(0.5))) < 1e-9


def test_the_session_refines_a_chain_placed_robot_on_objects_it_shares_off_its_links(rng):
    """Robots linked in a chain 0-1-2 (each link a little rotated), robot 2 also passing
    robot 0's objects: with refine_fleet the session places robot 2 close to the truth; off,
    where the chain of links puts it."""
    from sgloc.online import OnlineConfig, OnlineSession

    objects, true = _chain(rng, noise=0.05)
    frames = {}
    for refine in (False, True):
        s = OnlineSession(online=OnlineConfig(
            association_radius=0.0, min_observations=1, min_objects=3, max_attempts=0,
            refine_links=False, refine_fleet=refine, backend="robots"))
        for r in (0, 1, 2):
            s.add_keyframe(f"r{r}", 0.0, np.eye(4), *objects[r])
        cov = np.diag([1e-4] * 3 + [1e-2] * 3)
        s.add_link("r0", "r1", invert(true[0]) @ _pose(0.2, [0.3, -0.2, 0]) @ true[1], cov)
        s.add_link("r1", "r2", invert(true[1]) @ _pose(0.1, [0.2, 0.2, 0]) @ true[2], cov)
        frames[refine] = s.T_fleet_robot("r2")
    chain = invert(true[0]) @ _pose(0.2, [0.3, -0.2, 0]) @ _pose(0.1, [0.2, 0.2, 0]) @ true[2]
    np.testing.assert_allclose(frames[False], chain, atol=1e-9)
    before, after = (_off(frames[k], true[2], objects[2][0]) for k in (False, True))
    assert before[0] > 0.5 and after[0] < 0.2 * before[0] and after[1] < 0.2 * before[1]
