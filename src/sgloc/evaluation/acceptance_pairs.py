"""Labelled map pairs for the acceptance test: positives (the maps overlap) and negatives (they
do not), from Guo's Airsim maps, KITTI 00 scan ranges, and the code-generated object world.

Every builder is a pure function of its arguments and seed. Negatives are made non-overlapping by
a *cut*: every query object within `cut` metres (ground truth) of any target object is removed,
so no true correspondence can exist.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from sgloc.geometry import apply, invert, random_rigid_transform
from sgloc.graph import SemanticGraph

#: Metres: a negative's query keeps only objects farther than this from every target object.
NEGATIVE_CUT = 25.0


@dataclass
class LabeledPair:
    """query/target graphs, ground truth T_target_query, `positive` (do the maps overlap)."""

    query: SemanticGraph
    target: SemanticGraph
    T_target_query: np.ndarray
    positive: bool
    source: str
    info: dict[str, Any] = field(default_factory=dict)


def cut_shared_area(
    query: SemanticGraph, target: SemanticGraph, T_target_query: np.ndarray, cut: float
) -> SemanticGraph:
    """`query` without the objects lying within `cut` metres of any target object (ground
    truth T_target_query), i.e. with the shared area cut out."""
    d, _ = cKDTree(target.positions).query(apply(T_target_query, query.positions))
    return query.subgraph(np.flatnonzero(d > cut), name=f"{query.name}-cut{cut:g}")


def _dropout(g: SemanticGraph, keep: float, rng: np.random.Generator) -> SemanticGraph:
    return g.subgraph(np.flatnonzero(rng.random(len(g)) < keep), name=g.name)


def _moved(pair_q, pair_t, T0, rng, positive, source, info) -> LabeledPair:
    """Move the target by a random rigid transform (any yaw, roll/pitch <= 5 deg, <= 200 m)."""
    T = random_rigid_transform(rng, 200.0, 5.0)
    return LabeledPair(pair_q, pair_t.transformed(T), T @ T0, positive, source, info)


# -- Airsim (Guo's maps; ground truth identity) ---------------------------------------------
@functools.lru_cache(maxsize=2)
def _airsim() -> tuple[SemanticGraph, SemanticGraph]:
    from sgloc.data import data_path

    d = data_path("airsim_guo")
    return SemanticGraph.load(d / "cloud1.pcd"), SemanticGraph.load(d / "cloud2.pcd")


def airsim_pairs(
    n: int, positive: bool, seed: int = 0, keep: float = 1.0, cut: float = NEGATIVE_CUT
) -> list[LabeledPair]:
    """Airsim trials: cloud1 (query) against cloud2 moved by a random rigid transform.

    Negatives alternate the direction (cloud1 with cloud2's area cut out, against cloud2; and
    cloud2 with cloud1's area cut out, against cloud1). `keep` < 1 drops each object with
    probability 1 - keep (a different detection run), so the n pairs differ."""
    c1, c2 = _airsim()
    out = []
    for i in range(n):
        rng = np.random.default_rng([seed, i, 6])
        q, t = (c1, c2) if (positive or i % 2 == 0) else (c2, c1)
        if not positive:
            q = cut_shared_area(q, t, np.eye(4), cut)
        if keep < 1.0:
            q, t = _dropout(q, keep, rng), _dropout(t, keep, rng)
        info = {"query": q.name, "keep": keep, "cut": None if positive else cut}
        out.append(_moved(q, t, np.eye(4), rng, positive, "airsim", info))
    return out


# -- Object world (sgloc.sim.object_world) ---------------------------------------------------
def world_pairs(
    n: int,
    positive: bool,
    seed: int = 0,
    overlaps: tuple[float, ...] = (0.2, 0.3, 0.5, 0.7),
    cut: float = NEGATIVE_CUT,
) -> list[LabeledPair]:
    """Two robots in the code-generated city. Positives: overlap cycling through `overlaps`.
    Negatives: overlap 0 with the shared fringe cut out (even pairs), or robot B of one world
    against robot A of another world of the same kind (odd pairs)."""
    from sgloc.sim.object_world import make_two_robot_scene

    out = []
    for i in range(n):
        s = seed * 100_000 + i
        if positive:
            ov = overlaps[i % len(overlaps)]
            sc = make_two_robot_scene(s, ov)
            out.append(
                LabeledPair(sc.query, sc.target, sc.T_target_query, True, "world", {"overlap": ov})
            )
        elif i % 2 == 0:
            sc = make_two_robot_scene(s, 0.0)
            q = cut_shared_area(sc.query, sc.target, sc.T_target_query, cut)
            out.append(
                LabeledPair(q, sc.target, sc.T_target_query, False, "world", {"overlap": 0.0})
            )
        else:
            a = make_two_robot_scene(s, 0.5)
            b = make_two_robot_scene(s + 50_000, 0.5)
            out.append(
                LabeledPair(b.query, a.target, np.eye(4), False, "world", {"other_world": True})
            )
    return out


# -- KITTI 00 scan ranges --------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def _kitti_poses() -> np.ndarray:
    from sgloc.data import data_path
    from sgloc.datasets import make_dataset

    return make_dataset("kitti_objects", data_path("kitti00")).poses


@functools.lru_cache(maxsize=256)
def kitti_graph(first: int, last: int) -> SemanticGraph:
    """Robot graph of KITTI 00 scans first..last (inclusive) in its own start frame."""
    from sgloc.data import data_path
    from sgloc.datasets import make_dataset
    from sgloc.extraction import build_graph

    ds = make_dataset("kitti_objects", data_path("kitti00"), scans=(first, last), start_frame=True)
    return build_graph(ds, name=f"kitti00[{first}-{last}]")


def kitti_ground_truth(a: tuple[int, int], b: tuple[int, int]) -> np.ndarray:
    """T_A_B between the start frames (LiDAR) of scan ranges a and b."""
    P = _kitti_poses()
    return invert(P[a[0]]) @ P[b[0]]


def trajectory_overlap(a: tuple[int, int], b: tuple[int, int], radius: float = 10.0) -> float:
    """Fraction of range b's scan positions within `radius` m of range a's trajectory."""
    xyz = _kitti_poses()[:, :3, 3]
    pa, pb = xyz[a[0] : a[1] + 1], xyz[b[0] : b[1] + 1]
    d, _ = cKDTree(pa).query(pb)
    return float(np.mean(d < radius))


def _trajectory_gap(a: tuple[int, int], b: tuple[int, int]) -> float:
    xyz = _kitti_poses()[:, :3, 3]
    d, _ = cKDTree(xyz[a[0] : a[1] + 1]).query(xyz[b[0] : b[1] + 1])
    return float(d.min())


def kitti_pairs(
    n: int,
    positive: bool,
    seed: int = 0,
    length: tuple[int, int] = (400, 800),
    min_overlap: float = 0.2,
    cut: float = NEGATIVE_CUT,
    max_draws: int = 20_000,
) -> list[LabeledPair]:
    """Two robots = two KITTI 00 scan ranges (lengths drawn in `length`), each in its own start
    frame. Positives: trajectory overlap (`trajectory_overlap`, 10 m) >= `min_overlap`, from
    revisits or from ranges sharing scans. Negatives: trajectories at least 2 * cut apart,
    and the query cut as for every negative."""
    n_scans = len(_kitti_poses())
    rng = np.random.default_rng([seed, 600 + int(positive)])
    out, seen = [], set()
    for _ in range(max_draws):
        if len(out) >= n:
            break
        la, lb = rng.integers(length[0], length[1] + 1, 2)
        a0 = int(rng.integers(0, n_scans - la))
        b0 = int(rng.integers(0, n_scans - lb))
        a, b = (a0 // 50 * 50, a0 // 50 * 50 + int(la)), (b0 // 50 * 50, b0 // 50 * 50 + int(lb))
        if (a, b) in seen:
            continue
        ov = trajectory_overlap(a, b)
        if positive and ov < min_overlap:
            continue
        if not positive and _trajectory_gap(a, b) < 2 * cut:
            continue
        seen.add((a, b))
        T = kitti_ground_truth(a, b)
        q, t = kitti_graph(*b), kitti_graph(*a)
        if not positive:
            q = cut_shared_area(q, t, T, cut)
        shared = max(a[0], b[0]) <= min(a[1], b[1])
        info = {"target_scans": a, "query_scans": b, "overlap": ov, "shares_scans": shared}
        out.append(LabeledPair(q, t, T, positive, "kitti00", info))
    return out


# -- Rendered synthetic city (sgloc.sim, through the evaluation harness' cached runs) --------
def city_graphs(world: int, overlap: float) -> tuple[SemanticGraph, SemanticGraph, np.ndarray]:
    """(query, target, T_target_query) of city run `world` at `overlap` (320x180, 400 m).

    Uses the newest graphs in the evaluation harness' disk cache for that run, even when they
    were rendered by an earlier version of the sim code (the cache key names it); renders and
    caches the run (`sgloc.evaluation.pairs._city_graphs`) only when none is cached."""
    from sgloc.evaluation.pairs import _city_graphs
    from sgloc.evaluation.pairs_sim import evaluation_cache_dir

    found = sorted(
        evaluation_cache_dir().glob(f"city-w{world}-o{overlap:g}-320x180-L400-*.npz"),
        key=lambda p: p.stat().st_mtime,
    )
    if not found:
        return _city_graphs(world, overlap, 320, 180, 400.0)
    z = np.load(found[-1])
    name = found[-1].stem
    return (
        SemanticGraph(z["q_pos"], z["q_lab"], name=f"{name}:query"),
        SemanticGraph(z["t_pos"], z["t_lab"], name=f"{name}:target"),
        z["T"],
    )


def city_pairs(
    n: int,
    positive: bool,
    seed: int = 0,
    worlds: tuple[int, ...] = (0, 1, 2),
    overlaps: tuple[float, ...] = (0.2, 0.5, 0.8),
    cut: float = NEGATIVE_CUT,
) -> list[LabeledPair]:
    """Robots of the rendered city (graphs extracted from rendered frames, cached on disk).
    Positives: the runs of `worlds` x `overlaps`; negatives: the same worlds at overlap 0 with
    the shared area cut, and robot B of one world against robot A of another. Each pair gets
    its own random rigid motion of the target and a 90 % object dropout of both maps."""

    def graphs(world: int, ov: float):
        return city_graphs(world, ov)

    out = []
    for i in range(n):
        rng = np.random.default_rng([seed, i, 63])
        w = worlds[i % len(worlds)]
        if positive:
            ov = overlaps[(i // len(worlds)) % len(overlaps)]
            q, t, T0 = graphs(w, ov)
            info = {"world": w, "overlap": ov}
        elif i % 2 == 0:
            q, t, T0 = graphs(w, 0.0)
            q = cut_shared_area(q, t, T0, cut)
            info = {"world": w, "overlap": 0.0}
        else:
            w2 = worlds[(i + 1) % len(worlds)]
            q, _, _ = graphs(w2, 0.5)
            _, t, _ = graphs(w, 0.5)
            T0 = np.eye(4)
            info = {"world": w, "query_world": w2}
        q, t = _dropout(q, 0.9, rng), _dropout(t, 0.9, rng)
        out.append(_moved(q, t, T0, rng, positive, "city", info))
    return out


def default_pair_sets(seed: int = 0, scale: int = 1, city: bool = False) -> list[LabeledPair]:
    """The benchmark's sets: per source `scale` x (positives, negatives) =
    airsim (40, 40), object world (40, 40), KITTI 00 (40, 40), and with `city` the rendered
    city (40, 40; renders and caches 3 worlds x 5 runs on first use)."""
    n = 40 * scale
    out = (
        airsim_pairs(n, True, seed, keep=0.9)
        + airsim_pairs(n, False, seed, keep=0.9)
        + world_pairs(n, True, seed)
        + world_pairs(n, False, seed)
        + kitti_pairs(n, True, seed)
        + kitti_pairs(n, False, seed)
    )
    if city:
        out += city_pairs(n, True, seed) + city_pairs(n, False, seed)
    return out
