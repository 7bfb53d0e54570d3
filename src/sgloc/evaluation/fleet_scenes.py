"""Fleets with ground truth for `localize_fleet`: N robots cut from one object world, or from
KITTI 00 scan ranges; each robot's graph is in its own frame, and `T_gt_robot` places it in a
common ground-truth frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.geometry import apply, invert, random_rigid_transform, transform_error
from sgloc.graph import SemanticGraph


@dataclass
class FleetScene:
    """graphs (each in its own frame), T_gt_robot (p_gt = T @ p_robot), and notes per robot."""

    graphs: list[SemanticGraph]
    T_gt_robot: list[np.ndarray]
    notes: list[str]


def world_fleet(
    seed: int = 0,
    stretches: tuple[tuple[float, float], ...] = (
        (0, 250),
        (150, 400),
        (300, 550),
        (450, 700),
        (1000, 1250),
        (1500, 1700),
    ),
    view_radius: float = 40.0,
    noise: float = 0.5,
    keep_probability: float = 0.85,
) -> FleetScene:
    """Robots driving stretches [x0, x1] (metres) of the main street of one object world
    (`sgloc.sim.object_world.make_object_world`); the default chain overlaps by 100 m per
    neighbour for the first four, and the last two see parts of the street nobody else does."""
    from sgloc.sim.object_world import make_object_world

    rng = np.random.default_rng([seed, 61])
    length = max(b for _, b in stretches) + 2 * view_radius
    pos, lab = make_object_world(rng, length=length)
    graphs, Ts, notes = [], [], []
    for r, (x0, x1) in enumerate(stretches):
        x0, x1 = x0 + view_radius, x1 + view_radius
        d = np.hypot(np.clip(pos[:, 0], x0, x1) - pos[:, 0], pos[:, 1])
        seen = (d < view_radius) & (rng.random(len(pos)) < keep_probability)
        p = pos[seen] + rng.normal(0, noise, (int(seen.sum()), 3))
        T_gt_r = random_rigid_transform(rng, 100.0, 3.0)
        graphs.append(SemanticGraph(apply(invert(T_gt_r), p), lab[seen], name=f"world{r}"))
        Ts.append(T_gt_r)
        notes.append(f"street x {x0 - view_radius:g}-{x1 - view_radius:g} m")
    return FleetScene(graphs, Ts, notes)


#: Default KITTI 00 fleet: scan ranges (inclusive). 0-800 and 3900-4540 revisit the same
#: streets; 600-1200 shares scans with 0-800; 1000-1500 with 600-1200; 2100-2500 and 2900-3300
#: drive streets the others do not see.
KITTI_FLEET = ((0, 800), (600, 1200), (1000, 1500), (3900, 4540), (2100, 2500), (2900, 3300))


def kitti_fleet(ranges: tuple[tuple[int, int], ...] = KITTI_FLEET) -> FleetScene:
    """Robots = KITTI 00 scan ranges, each graph in its own start (LiDAR) frame; ground truth
    from the KITTI poses (sequence frame)."""
    from sgloc.evaluation.acceptance_pairs import _kitti_poses, kitti_graph

    P = _kitti_poses()
    graphs = [kitti_graph(a, b) for a, b in ranges]
    return FleetScene(graphs, [P[a] for a, _ in ranges], [f"scans {a}-{b}" for a, b in ranges])


def fleet_errors(
    T_world_robot: dict[int, np.ndarray],
    T_gt_robot: list[np.ndarray],
    root: int,
    graphs: list[SemanticGraph],
) -> dict[int, tuple[float, float]]:
    """(translation m, rotation deg) error of each placed robot's pose relative to the root,
    against the ground truth T_root_robot = inv(T_gt_root) @ T_gt_robot. The translation error
    is measured where the robot's map is (at the centroid of its objects), so it does not grow
    with the distance of the root's frame origin."""
    G_root = invert(T_gt_robot[root])
    out = {}
    for i, T in sorted(T_world_robot.items()):
        G = G_root @ T_gt_robot[i]
        c = graphs[i].positions.mean(axis=0)
        dt = float(np.linalg.norm(apply(T, c[None]) - apply(G, c[None])))
        out[i] = (dt, transform_error(T, G)[1])
    return out


def expected_placeable(
    scene: FleetScene, link_radius: float = 3.0, min_shared: int = 15
) -> np.ndarray:
    """(N,N) bool: robot pairs sharing at least `min_shared` same-class objects within
    `link_radius` m under ground truth (a rough "should localize" oracle, for reporting)."""
    from scipy.spatial import cKDTree

    n = len(scene.graphs)
    world = [apply(T, g.positions) for T, g in zip(scene.T_gt_robot, scene.graphs, strict=True)]
    out = np.zeros((n, n), dtype=bool)
    for i in range(n):
        for j in range(i + 1, n):
            d, k = cKDTree(world[j]).query(world[i], distance_upper_bound=link_radius)
            ok = np.isfinite(d)
            same = ok.copy()
            same[ok] = scene.graphs[i].labels[ok] == scene.graphs[j].labels[k[ok]]
            out[i, j] = out[j, i] = same.sum() >= min_shared
    return out
