"""The ray-casting renderer against analytic ray-box / ray-cylinder distances, and semantic ids
on a hand-placed scene."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.geometry import invert
from sgloc.sim.city import BOX, CYLINDER, Primitives
from sgloc.sim.render import T_BODY_OPTICAL, Camera, Renderer, render_frames
from sgloc.sim.trajectory import body_poses


def scene(rows: list[tuple]) -> Primitives:
    """rows: (kind, center (3,), half (3,), yaw, label)."""
    return Primitives(
        kind=np.array([r[0] for r in rows], np.int8),
        center=np.array([r[1] for r in rows], float),
        half=np.array([r[2] for r in rows], float),
        yaw=np.array([r[3] for r in rows], float),
        label=np.array([r[4] for r in rows], np.int64),
        instance=np.arange(len(rows)),
    )


def camera_pose(x: float, y: float, z: float, heading_deg: float, pitch_deg: float = 0.0):
    """T_world_optical of a camera at (x, y, z) looking along heading (deg from +x)."""
    h = np.deg2rad(heading_deg)
    T_body = body_poses(np.array([[x, y]]), np.array([[np.cos(h), np.sin(h)]]), z, pitch_deg)[0]
    return T_body @ T_BODY_OPTICAL


def world_rays(cam: Camera, T: np.ndarray) -> np.ndarray:
    return cam.rays() @ T[:3, :3].T


def box_reference(o, dirs, center, half, yaw):
    """Planar depth of each ray's first hit on the box's six faces (independent of the slab
    method: intersect each face plane and test the hit lies inside the face)."""
    c, s = np.cos(yaw), np.sin(yaw)
    axes = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # box axes in the world
    best = np.full(len(dirs), np.inf)
    for k in range(3):
        n = axes[k]
        for sign in (-1, 1):
            p0 = center + sign * half[k] * n
            denom = dirs @ n
            with np.errstate(divide="ignore", invalid="ignore"):  # rays parallel to the face
                t = ((p0 - o) @ n) / denom
                hit = o + t[:, None] * dirs
                local = (hit - center) @ axes.T
            others = [j for j in range(3) if j != k]
            inside = np.all(np.abs(local[:, others]) <= half[others] + 1e-9, axis=1)
            ok = inside & (t > 0) & np.isfinite(t)
            best = np.where(ok & (t < best), t, best)
    return best


@pytest.mark.parametrize("yaw_deg", [0.0, 30.0, 77.0])
def test_box_depth_matches_analytic_face_intersections(yaw_deg):
    cam = Camera(96, 64, max_range=100.0)
    center, half, yaw = np.array([12.0, 1.5, 2.6]), np.array([3.0, 2.0, 2.5]), np.deg2rad(yaw_deg)
    prims = scene([(BOX, center, half, yaw, 4)])
    T = camera_pose(0.0, 0.0, 1.6, heading_deg=5.0)
    r = Renderer(prims, cam).render(T)
    ref = box_reference(T[:3, 3], world_rays(cam, T), center, half, yaw).reshape(r.depth.shape)
    on_box = r.semantic == 4
    assert on_box.sum() > 300  # the box fills a good part of the view
    hit_ref = np.isfinite(ref)
    # hit masks agree except possibly for a few rays grazing an edge
    assert np.count_nonzero(on_box != hit_ref) <= 0.01 * hit_ref.sum()
    both = on_box & hit_ref
    np.testing.assert_allclose(r.depth[both], ref[both], rtol=1e-4, atol=1e-4)


def test_box_face_facing_camera_has_constant_planar_depth():
    cam = Camera(80, 60)
    # the face x = 10 is perpendicular to the optical axis: planar depth 10 m everywhere on it
    prims = scene([(BOX, (11.0, 0.0, 1.6), (1.0, 3.0, 1.0), 0.0, 0)])
    r = Renderer(prims, cam).render(camera_pose(0.0, 0.0, 1.6, 0.0))
    on = r.semantic == 0
    assert on.sum() > 200
    np.testing.assert_allclose(r.depth[on], 10.0, atol=1e-4)
    assert r.depth[int(cam.cy), int(cam.cx)] == pytest.approx(10.0, abs=1e-4)


def test_cylinder_side_depth_matches_quadratic_solution():
    cam = Camera(120, 40)
    radius = 1.5
    prims = scene([(CYLINDER, (10.0, 0.0, 1.5), (radius, radius, 1.5), 0.0, 2)])
    r = Renderer(prims, cam).render(camera_pose(0.0, 0.0, 1.6, 0.0))
    v = int(cam.cy)  # the horizon row: rays (1, a, 0) in the world
    a = (np.arange(cam.width) - cam.cx) / cam.fx  # lateral slope (world -y to the right)
    A, B, C = 1 + a**2, -20.0, 100.0 - radius**2
    disc = B**2 - 4 * A * C
    hit = disc >= 0
    t = (-B - np.sqrt(np.where(hit, disc, 0))) / (2 * A)
    row_hit = r.semantic[v] == 2
    assert row_hit.sum() >= 10
    inner = disc > 0.02 * B**2  # rays well inside the silhouette (not grazing)
    assert np.all(row_hit[inner])
    np.testing.assert_allclose(r.depth[v][row_hit & hit], t[row_hit & hit], rtol=1e-4)
    assert r.depth[v, int(cam.cx)] == pytest.approx(10.0 - radius, abs=1e-4)
    # nothing of class 2 above the cylinder's top (3 m; nearest at 8.5 m ahead)
    top_row = cam.cy - cam.fy * (3.0 - 1.6) / (10.0 - radius)
    assert 2 < top_row < v
    assert not np.any(r.semantic[: int(np.floor(top_row))] == 2)
    assert np.any(r.semantic[int(np.ceil(top_row)) + 1] == 2)


def test_cylinder_top_cap_seen_from_above():
    cam = Camera(64, 64)
    # camera 3 m up, pitched 60 deg down, a short wide cylinder (a "bin") 4 m ahead
    prims = scene([(CYLINDER, (4.0, 0.0, 0.5), (1.2, 1.2, 0.5), 0.0, 9)])
    T = camera_pose(0.0, 0.0, 3.0, 0.0, pitch_deg=60.0)
    r = Renderer(prims, cam).render(T)
    dirs = world_rays(cam, T).reshape(cam.height, cam.width, 3)
    o = T[:3, 3]
    t_cap = (1.0 - o[2]) / dirs[..., 2]  # the plane z = 1
    p = o + t_cap[..., None] * dirs
    on_cap = (np.hypot(p[..., 0] - 4.0, p[..., 1]) < 1.2 - 0.05) & (t_cap > 0)
    assert on_cap.sum() > 50
    assert np.all(r.semantic[on_cap] == 9)
    np.testing.assert_allclose(r.depth[on_cap], t_cap[on_cap], rtol=1e-4)


def test_semantic_ids_and_occlusion_on_hand_placed_scene():
    cam = Camera(160, 90)
    prims = scene(
        [
            (BOX, (30.0, 0.0, 5.0), (1.0, 10.0, 5.0), 0.0, 0),  # a wall far ahead
            (BOX, (15.0, -2.0, 0.75), (2.2, 0.9, 0.75), 0.0, 3),  # a car in front of it
            (CYLINDER, (12.0, 4.0, 3.5), (0.4, 0.4, 3.5), 0.0, 2),  # a pole on the left
        ]
    )
    T = camera_pose(0.0, 0.0, 1.6, 0.0)
    r = Renderer(prims, cam).render(T)

    def pixel(p):  # project a world point
        q = invert(T) @ np.append(p, 1.0)
        return int(round(cam.fy * q[1] / q[2] + cam.cy)), int(round(cam.fx * q[0] / q[2] + cam.cx))

    assert r.semantic[pixel((14.0, -2.0, 1.0))] == 3  # the car occludes the wall
    assert r.depth[pixel((14.0, -2.0, 1.0))] == pytest.approx(15.0 - 2.2, abs=1e-3)
    assert r.semantic[pixel((12.0, 4.0, 3.0))] == 2
    assert r.semantic[pixel((29.0, 6.0, 6.0))] == 0
    assert r.depth[pixel((29.0, 6.0, 6.0))] == pytest.approx(29.0, abs=1e-3)
    # sky: no class and infinite depth; ground: no class, depth = h * fy / (v - cy)
    assert r.semantic[0, 2] == -1 and np.isinf(r.depth[0, 2])
    v = cam.height - 1
    assert r.semantic[v, 2] == -1
    assert r.depth[v, 2] == pytest.approx(1.6 * cam.fy / (v - cam.cy), rel=1e-5)
    assert r.instance[pixel((12.0, 4.0, 3.0))] == 2


def test_primitives_beyond_max_range_are_not_drawn():
    cam = Camera(64, 36, max_range=20.0)
    prims = scene([(BOX, (25.0, 0.0, 2.0), (1.0, 5.0, 2.0), 0.0, 0)])
    r = Renderer(prims, cam).render(camera_pose(0.0, 0.0, 1.6, 0.0))
    assert not np.any(r.semantic == 0)
    assert np.all(r.depth[np.isfinite(r.depth)] <= 20.0 + 1e-6)


def test_chunking_does_not_change_the_image():
    rng = np.random.default_rng(3)
    rows = []
    for k in range(40):
        c = (rng.uniform(5, 40), rng.uniform(-15, 15), 1.0)
        if k % 2:
            rows.append(
                (BOX, c, (rng.uniform(0.5, 2), rng.uniform(0.5, 2), 1.0), rng.uniform(0, 3), k % 11)
            )
        else:
            rows.append((CYLINDER, c, (0.6, 0.6, 1.0), 0.0, k % 11))
    prims = scene(rows)
    cam = Camera(100, 60)
    T = camera_pose(0.0, 0.0, 1.6, 0.0)
    a = Renderer(prims, cam, chunk_pairs=10_000_000).render(T)
    b = Renderer(prims, cam, chunk_pairs=500).render(T)
    np.testing.assert_array_equal(a.semantic, b.semantic)
    np.testing.assert_array_equal(a.depth, b.depth)


def test_render_frames_back_projects_onto_the_object_in_the_start_frame():
    """A pixel's back-projection with the frame's K and T_map_sensor lands on the box surface
    (expressed in the robot's start frame): the convention the extraction relies on."""
    center, half = np.array([20.0, 3.0, 2.0]), np.array([2.0, 1.0, 2.0])
    prims = scene([(BOX, center, half, 0.3, 5)])
    cam = Camera(80, 45)
    xy = np.array([[0.0, 0.0], [4.0, 0.5]])
    heading = np.array([[1.0, 0.0], [np.cos(0.1), np.sin(0.1)]])
    T_world_body = body_poses(xy, heading, 1.6)
    frames = list(render_frames(prims, T_world_body, cam))
    np.testing.assert_allclose(frames[0].T_map_sensor, T_BODY_OPTICAL, atol=1e-12)
    f = frames[1]
    vs, us = np.nonzero(f.semantic == 5)
    assert len(us) > 20
    D = f.depth[vs, us]
    K = f.K
    pts = np.stack([(us - K[0, 2]) / K[0, 0] * D, (vs - K[1, 2]) / K[1, 1] * D, D], axis=1)
    in_map = pts @ f.T_map_sensor[:3, :3].T + f.T_map_sensor[:3, 3]
    in_world = in_map @ T_world_body[0][:3, :3].T + T_world_body[0][:3, 3]
    c, s = np.cos(0.3), np.sin(0.3)
    local = (in_world - center) @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]).T
    # every point is on the surface: inside the box and on at least one face
    assert np.all(np.abs(local) <= half + 1e-3)
    assert np.all(np.min(half - np.abs(local), axis=1) < 1e-3)
