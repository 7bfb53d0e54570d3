"""The procedural city and the two robots' routes (overlap, poses, ground truth)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from sgloc.errors import SglocError
from sgloc.geometry import invert
from sgloc.sim.city import BOX, CITY_CLASSES, CityConfig, make_city
from sgloc.sim.trajectory import ROBOT_NAMES, TrajectoryConfig, make_routes

A, B = ROBOT_NAMES


@pytest.fixture(scope="module")
def city():
    return make_city(7)


def test_city_has_many_repeated_classes_of_plausible_size(city):
    counts = np.bincount(city.object_labels, minlength=len(CITY_CLASSES))
    assert np.count_nonzero(counts) >= 8
    # the common classes repeat many times (ambiguous descriptors)
    for name in ("building", "tree", "pole", "car", "bush"):
        assert counts[CITY_CLASSES.index(name)] >= 50, name
    extent = city.config.size
    assert np.all(city.object_positions[:, :2] > -1) and np.all(
        city.object_positions[:, :2] < extent + 1
    )
    # plausible sizes: buildings tall, cars car-sized, poles thin
    p = city.primitives
    height = 2 * p.half[:, 2]
    assert np.all(height[p.label == 0] >= city.config.building_height[0] - 1e-9)
    car_boxes = (p.label == 3) & (p.kind == BOX)
    assert np.all(2 * p.half[car_boxes, 0] < 5.0)
    assert np.all(p.half[p.label == 2, 0] < 0.3)


def test_city_is_reproducible_and_seed_dependent():
    a, b, c = make_city(3), make_city(3), make_city(4)
    np.testing.assert_array_equal(a.primitives.center, b.primitives.center)
    assert a.primitives.center.shape != c.primitives.center.shape or not np.allclose(
        a.primitives.center, c.primitives.center
    )


def test_nothing_stands_in_the_driving_lanes(city):
    routes = make_routes(city, TrajectoryConfig(length=300.0, overlap=0.5), seed=1)
    p = city.primitives
    for robot in ROBOT_NAMES:
        xy = routes.T_world_body[robot][:, :2, 3]
        d, _ = cKDTree(p.center[:, :2]).query(xy, k=20)
        # closest primitive surface: bounding circle in the ground plane
        near = cKDTree(p.center[:, :2]).query_ball_point(xy, r=8.0)
        for i, idx in enumerate(near):
            if not idx:
                continue
            idx = np.asarray(idx)
            radius = np.hypot(p.half[idx, 0], p.half[idx, 1])
            gap = np.linalg.norm(p.center[idx, :2] - xy[i], axis=1) - radius
            # boxes' bounding circles are loose, so check the exact distance for boxes
            c, s = np.cos(p.yaw[idx]), np.sin(p.yaw[idx])
            rel = xy[i] - p.center[idx, :2]
            lx, ly = c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]
            box_gap = np.hypot(
                np.maximum(np.abs(lx) - p.half[idx, 0], 0),
                np.maximum(np.abs(ly) - p.half[idx, 1], 0),
            )
            gap = np.where(p.kind[idx] == BOX, box_gap, gap)
            assert gap.min() > 0.5, (robot, i)


def _near_fraction(routes, radius: float) -> float:
    a = routes.T_world_body[A][:, :2, 3]
    b = routes.T_world_body[B][:, :2, 3]
    d, _ = cKDTree(b).query(a)
    return float(np.mean(d < radius))


def test_overlap_zero_gives_disjoint_routes(city):
    cfg = TrajectoryConfig(length=300.0, overlap=0.0)
    r = make_routes(city, cfg, seed=2)
    assert r.shared_fraction == 0.0
    # the routes only touch where B's stretch begins after A's (one frame or two)
    assert _near_fraction(r, 5.0) < 0.03
    r_gap = make_routes(city, TrajectoryConfig(length=300.0, overlap=0.0, gap=60.0), seed=2)
    a = r_gap.T_world_body[A][:, :2, 3]
    b = r_gap.T_world_body[B][:, :2, 3]
    # the gap is along the path; through the grid the routes stay at least a street apart
    assert cKDTree(b).query(a)[0].min() > 10.0


def test_overlap_one_gives_the_same_route_driven_backwards(city):
    cfg = TrajectoryConfig(length=300.0, overlap=1.0)
    r = make_routes(city, cfg, seed=2)
    assert r.shared_fraction == pytest.approx(1.0)
    a = r.T_world_body[A][:, :2, 3]
    b = r.T_world_body[B][::-1, :2, 3]  # B's frames reversed: same places as A's
    # A and B keep to opposite lanes: 2 * lane_offset apart, facing opposite ways
    np.testing.assert_allclose(np.linalg.norm(a - b, axis=1), 2 * cfg.lane_offset, atol=0.3)
    fa = r.T_world_body[A][:, :3, 0]
    fb = r.T_world_body[B][::-1, :3, 0]
    assert np.all(np.sum(fa * fb, axis=1) < -0.95)


@pytest.mark.parametrize("overlap", [0.25, 0.5, 0.75])
def test_overlap_fraction_is_the_shared_part_of_the_route(city, overlap):
    r = make_routes(city, TrajectoryConfig(length=300.0, overlap=overlap), seed=5)
    assert r.shared_fraction == pytest.approx(overlap, abs=0.01)
    # geometrically: the fraction of A's frames within a few metres of B's route
    assert _near_fraction(r, 5.0) == pytest.approx(overlap, abs=0.05)


def test_one_seed_gives_the_same_streets_at_every_overlap(city):
    r0 = make_routes(city, TrajectoryConfig(length=200.0, overlap=0.0), seed=9)
    r1 = make_routes(city, TrajectoryConfig(length=200.0, overlap=0.8), seed=9)
    np.testing.assert_allclose(r0.T_world_body[A], r1.T_world_body[A])
    np.testing.assert_allclose(r0.centerline, r1.centerline)


def test_poses_are_airsim_body_frames_along_the_motion(city):
    cfg = TrajectoryConfig(length=200.0, step=2.0, camera_height=1.7)
    r = make_routes(city, cfg, seed=3)
    for robot in ROBOT_NAMES:
        T = r.T_world_body[robot]
        R = T[:, :3, :3]
        np.testing.assert_allclose(
            R @ R.transpose(0, 2, 1), np.tile(np.eye(3), (len(T), 1, 1)), atol=1e-9
        )
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
        np.testing.assert_allclose(T[:, 2, 3], 1.7)
        np.testing.assert_allclose(T[:, :3, 2], np.tile([0, 0, -1.0], (len(T), 1)), atol=1e-9)
        motion = np.diff(T[:, :3, 3], axis=0)
        # `step` is measured along the centre line: exact on straights, the outer lane of a
        # turn is a little longer and the inner one shorter
        spacing = np.linalg.norm(motion, axis=1)
        assert np.median(spacing) == pytest.approx(2.0, abs=1e-6)
        assert 1.0 < spacing.min() and spacing.max() < 3.0
        assert np.all(np.sum(motion * T[:-1, :3, 0], axis=1) > 0.9 * 2.0 * 0.9)
        P = r.poses_in_start_frame(robot)
        np.testing.assert_allclose(P[0], np.eye(4), atol=1e-12)


def test_ground_truth_maps_query_start_frame_into_target_start_frame(city):
    r = make_routes(city, TrajectoryConfig(length=200.0, overlap=0.5), seed=4)
    T_ab = r.ground_truth(A, B)
    # a world point seen in B's start frame, mapped by T_ab, equals it seen in A's start frame
    p_world = np.array([123.0, 45.0, 6.0, 1.0])
    p_a = invert(r.start_pose(A)) @ p_world
    p_b = invert(r.start_pose(B)) @ p_world
    np.testing.assert_allclose(T_ab @ p_b, p_a, atol=1e-9)
    # the two start frames differ (as in real use)
    assert np.linalg.norm(T_ab[:3, 3]) > 10.0


def test_bad_overlap_is_a_clear_error(city):
    with pytest.raises(SglocError, match="overlap"):
        make_routes(city, TrajectoryConfig(overlap=1.5))


def test_too_small_a_city_for_the_route_is_a_clear_error():
    small = make_city(0, CityConfig(blocks=3))
    with pytest.raises(SglocError, match="route"):
        make_routes(small, TrajectoryConfig(length=2000.0))
