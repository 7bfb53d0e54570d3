"""Fleets with ground truth for `localize_fleet`: N robots cut from one object world, from
KITTI 00 scan ranges, or from a rendered city run (maps from the pair sources' builders); each
robot's graph is in its own frame, and `T_gt_robot` places it in a common ground-truth frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.evaluation.pairs_kitti import kitti_graph, kitti_root, kitti_sequence
from sgloc.evaluation.pairs_sim import city_graphs
from sgloc.geometry import apply, invert, random_rigid_transform, transform_error
from sgloc.maps.graph import SemanticGraph


@dataclass
class FleetScene:
    """graphs (each in its own frame), T_gt_robot (p_gt = T @ p_robot), and notes per robot."""

    graphs: list[SemanticGraph]
    T_gt_robot: list[np.ndarray]
    notes: list[str]


#: Default object-world fleet: stretches of the main street (m); a chain of four overlapping by
#: 100 m per neighbour, and two that see parts of the street nobody else does.
WORLD_FLEET = ((0, 250), (150, 400), (300, 550), (450, 700), (1000, 1250), (1500, 1700))


def world_fleet(
    seed: int = 0,
    stretches: tuple[tuple[float, float], ...] = WORLD_FLEET,
    view_radius: float = 40.0,
    noise: float = 0.5,
    keep_probability: float = 0.85,
) -> FleetScene:
    """Robots driving stretches [x0, x1] (metres) of the main street of one object world
    (`sgloc.sim.object_world`; robots observe the street as in the `object-world` pairs)."""
    from sgloc.sim.object_world import make_object_world, observe_street

    rng = np.random.default_rng([seed, 61])
    length = max(b for _, b in stretches) + 2 * view_radius
    pos, lab = make_object_world(rng, length=length)
    graphs, Ts, notes = [], [], []
    for r, (x0, x1) in enumerate(stretches):
        a, b = x0 + view_radius, x1 + view_radius
        seen = observe_street(pos, lab, a, b, rng, view_radius, keep_probability, noise)
        T_gt_r = random_rigid_transform(rng, 100.0, 3.0)
        graphs.append(seen.transformed(invert(T_gt_r), name=f"world{r}"))
        Ts.append(T_gt_r)
        notes.append(f"street x {x0:g}-{x1:g} m")
    return FleetScene(graphs, Ts, notes)


#: Default KITTI 00 fleet: scan ranges (inclusive). 0-800 and 3900-4540 revisit the same
#: streets; 600-1200 shares scans with 0-800; 1000-1500 with 600-1200; 2100-2500 and 2900-3300
#: drive streets the others do not see.
KITTI_FLEET = ((0, 800), (600, 1200), (1000, 1500), (3900, 4540), (2100, 2500), (2900, 3300))


def kitti_fleet(ranges: tuple[tuple[int, int], ...] = KITTI_FLEET) -> FleetScene:
    """Robots = KITTI 00 scan ranges, each graph in its own start (LiDAR) frame (`kitti_graph`);
    ground truth from the KITTI poses (sequence frame)."""
    root = kitti_root()
    L = kitti_sequence(root)[0]
    graphs = [kitti_graph(root, a, b) for a, b in ranges]
    return FleetScene(graphs, [L[a] for a, _ in ranges], [f"scans {a}-{b}" for a, b in ranges])


def city_fleet(seed: int = 0, overlap: float = 0.5, pieces: int = 3) -> FleetScene:
    """Robots cut from a rendered synthetic city run (`city_graphs`, the newest cached run):
    each of the two robots' maps is split into `pieces` chunks along its principal direction,
    neighbouring chunks sharing 15 % of the map's length, each chunk in its own random frame."""
    q, t, T_t_q = city_graphs(seed, overlap, any_code_version=True)
    rng = np.random.default_rng([seed, 62])
    graphs, Ts, notes = [], [], []
    for name, g, T_gt in (("A", t, np.eye(4)), ("B", q, T_t_q)):
        # Progress along the route: arc position of each object on the map's main axis.
        c = g.positions - g.positions.mean(axis=0)
        axis = np.linalg.svd(c, full_matrices=False)[2][0]
        s = c @ axis
        edges = np.quantile(s, np.linspace(0, 1, pieces + 1))
        margin = 0.15 * (edges[-1] - edges[0])
        for k in range(pieces):
            sel = np.flatnonzero((s >= edges[k] - margin) & (s <= edges[k + 1] + margin))
            T_gt_r = T_gt @ random_rigid_transform(rng, 100.0, 3.0)
            # Chunk positions in its own frame r: p_r = inv(T_map_r) p_map.
            T_map_r = invert(T_gt) @ T_gt_r
            pos = apply(invert(T_map_r), g.positions[sel])
            graphs.append(SemanticGraph(pos, g.labels[sel], name=f"city{name}{k}"))
            Ts.append(T_gt_r)
            notes.append(f"robot {name} piece {k}")
    return FleetScene(graphs, Ts, notes)


def fleet_errors(
    T_fleet_robot: dict[int, np.ndarray],
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
    for i, T in sorted(T_fleet_robot.items()):
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
            same = scene.graphs[i].labels[ok] == scene.graphs[j].labels[k[ok]]
            out[i, j] = out[j, i] = same.sum() >= min_shared
    return out
