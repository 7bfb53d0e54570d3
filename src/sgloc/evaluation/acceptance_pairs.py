"""Labelled map pairs for the acceptance test: positives (the maps overlap) and negatives (they
do not), from Guo's Airsim maps, KITTI 00 scan ranges, the code-generated object world and the
rendered city, built by the same map builders and target motion as the trials' pair sources.

Every builder is a pure function of its arguments and seed. Negatives are made non-overlapping by
a *cut*: every query object within `cut` metres (ground truth) of any target object is removed,
so no true correspondence can exist.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sgloc.evaluation.pairs import AirsimGuoPairs, ObjectWorldPairs
from sgloc.evaluation.pairs_kitti import kitti_graph, kitti_ground_truth, kitti_root, kitti_sequence
from sgloc.evaluation.pairs_sim import city_graphs
from sgloc.evaluation.scenes import Pair, move_target, route_overlap
from sgloc.geometry import apply
from sgloc.maps.graph import SemanticGraph

#: Metres: a negative's query keeps only objects farther than this from every target object.
NEGATIVE_CUT = 25.0


@dataclass
class LabeledPair(Pair):
    """A `Pair` labelled `positive` (do the maps overlap) and with the name of its `source`."""

    positive: bool = True
    source: str = ""


def _labeled(pair: Pair, positive: bool, source: str, info: dict) -> LabeledPair:
    fields = {**vars(pair), "info": {**info, **pair.info}}
    return LabeledPair(**fields, positive=positive, source=source)


def _cut_drop_move(
    q: SemanticGraph,
    t: SemanticGraph,
    T0: np.ndarray,
    rng: np.random.Generator,
    keep: float,
    cut: float | None,
) -> Pair:
    """The pair of maps q, t (ground truth T0): q's shared area cut out when `cut` is set, each
    object kept with probability `keep`, the target moved (all draws from `rng`)."""
    if cut is not None:
        q = cut_shared_area(q, t, T0, cut)
    if keep < 1.0:
        q, t = _dropout(q, keep, rng), _dropout(t, keep, rng)
    return move_target(q, t, T0, rng)


def cut_shared_area(
    query: SemanticGraph, target: SemanticGraph, T_target_query: np.ndarray, cut: float
) -> SemanticGraph:
    """`query` without the objects lying within `cut` metres of any target object (ground
    truth T_target_query), i.e. with the shared area cut out."""
    d, _ = cKDTree(target.positions).query(apply(T_target_query, query.positions))
    return query.subgraph(np.flatnonzero(d > cut), name=f"{query.name}-cut{cut:g}")


def _dropout(g: SemanticGraph, keep: float, rng: np.random.Generator) -> SemanticGraph:
    return g.subgraph(np.flatnonzero(rng.random(len(g)) < keep), name=g.name)


# -- Airsim (Guo's maps; ground truth identity) ---------------------------------------------
def airsim_pairs(
    n: int, positive: bool, seed: int = 0, keep: float = 1.0, cut: float = NEGATIVE_CUT
) -> list[LabeledPair]:
    """Airsim trials: cloud1 (query) against cloud2 moved by a random rigid transform.

    Negatives alternate the direction (cloud1 with cloud2's area cut out, against cloud2; and
    cloud2 with cloud1's area cut out, against cloud1). `keep` < 1 drops each object with
    probability 1 - keep (a different detection run), so the n pairs differ."""
    c1, c2, _, _ = AirsimGuoPairs().resolved().maps(0)
    out = []
    for i in range(n):
        q, t = (c1, c2) if (positive or i % 2 == 0) else (c2, c1)
        cut_i = None if positive else cut
        pair = _cut_drop_move(q, t, np.eye(4), np.random.default_rng([seed, i, 6]), keep, cut_i)
        info = {"query": pair.query.name, "keep": keep, "cut": cut_i}
        out.append(_labeled(pair, positive, "airsim", info))
    return out


# -- Object world (sgloc.sim.object_world, through the `object-world` pair source) -------------
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
    out = []
    for i in range(n):
        s = seed * 100_000 + i
        if positive:
            ov = overlaps[i % len(overlaps)]
            out.append(_labeled(ObjectWorldPairs(ov)(s), True, "world", {}))
        elif i % 2 == 0:
            p = ObjectWorldPairs(0.0)(s)
            p.query = cut_shared_area(p.query, p.target, p.T_target_query, cut)
            out.append(_labeled(p, False, "world", {}))
        else:
            a, b = ObjectWorldPairs(0.5)(s), ObjectWorldPairs(0.5)(s + 50_000)
            pair = Pair(b.query, a.target, np.eye(4))
            out.append(_labeled(pair, False, "world", {"other_world": True}))
    return out


# -- KITTI 00 scan ranges --------------------------------------------------------------------
def kitti_pairs(
    n: int,
    positive: bool,
    seed: int = 0,
    length: tuple[int, int] = (400, 800),
    min_overlap: float = 0.2,
    cut: float = NEGATIVE_CUT,
    max_draws: int = 20_000,
    radius: float = 10.0,
) -> list[LabeledPair]:
    """Two robots = two KITTI 00 scan ranges (lengths drawn in `length`), each in its own start
    frame (`kitti_graph`). Positives: route overlap (`route_overlap` of the query's route with
    the target's, `radius` m) >= `min_overlap`, from revisits or from ranges sharing scans.
    Negatives: routes at least 2 * cut apart, and the query cut as for every negative."""
    root = kitti_root()
    xy = kitti_sequence(root)[0][:, [0, 2], 3]  # the ground plane of the sequence frame
    rng = np.random.default_rng([seed, 600 + int(positive)])
    out, seen = [], set()
    for _ in range(max_draws):
        if len(out) >= n:
            break
        la, lb = rng.integers(length[0], length[1] + 1, 2)
        a0 = int(rng.integers(0, len(xy) - la))
        b0 = int(rng.integers(0, len(xy) - lb))
        a, b = (a0 // 50 * 50, a0 // 50 * 50 + int(la)), (b0 // 50 * 50, b0 // 50 * 50 + int(lb))
        if (a, b) in seen:
            continue
        xa, xb = xy[a[0] : a[1] + 1], xy[b[0] : b[1] + 1]
        ov = route_overlap(xb, xa, radius)
        if positive and ov < min_overlap:
            continue
        if not positive and cKDTree(xa).query(xb)[0].min() < 2 * cut:
            continue
        seen.add((a, b))
        T = kitti_ground_truth(root, a, b)
        q, t = kitti_graph(root, *b), kitti_graph(root, *a)
        if not positive:
            q = cut_shared_area(q, t, T, cut)
        shared = max(a[0], b[0]) <= min(a[1], b[1])
        info = {"target_scans": a, "query_scans": b, "overlap": ov, "shares_scans": shared}
        out.append(_labeled(Pair(q, t, T), positive, "kitti00", info))
    return out


# -- Rendered synthetic city (sgloc.sim, the `city` pair source's cached runs) ----------------
def city_pairs(
    n: int,
    positive: bool,
    seed: int = 0,
    worlds: tuple[int, ...] = (0, 1, 2),
    overlaps: tuple[float, ...] = (0.2, 0.5, 0.8),
    cut: float = NEGATIVE_CUT,
) -> list[LabeledPair]:
    """Robots of the rendered city (graphs extracted from rendered frames, cached on disk; the
    newest cached run is used even if older code rendered it). Positives: the runs of `worlds`
    x `overlaps`; negatives: the same worlds at overlap 0 with the shared area cut, and robot B
    of one world against robot A of another. Each pair gets its own random rigid motion of the
    target and a 90 % object dropout of both maps."""

    def graphs(world: int, ov: float) -> tuple[SemanticGraph, SemanticGraph, np.ndarray]:
        return city_graphs(world, ov, any_code_version=True)

    out = []
    for i in range(n):
        rng = np.random.default_rng([seed, i, 63])
        w, cut_i = worlds[i % len(worlds)], None
        if positive:
            ov = overlaps[(i // len(worlds)) % len(overlaps)]
            q, t, T0 = graphs(w, ov)
            info = {"world": w, "overlap": ov}
        elif i % 2 == 0:
            q, t, T0 = graphs(w, 0.0)
            cut_i, info = cut, {"world": w, "overlap": 0.0}
        else:
            w2 = worlds[(i + 1) % len(worlds)]
            q, t, T0 = graphs(w2, 0.5)[0], graphs(w, 0.5)[1], np.eye(4)
            info = {"world": w, "query_world": w2}
        out.append(_labeled(_cut_drop_move(q, t, T0, rng, 0.9, cut_i), positive, "city", info))
    return out


def default_pair_sets(
    seed: int = 0, scale: int = 1, city: bool = False, kitti: bool = True
) -> list[LabeledPair]:
    """The benchmark's sets: per source `scale` x (positives, negatives) =
    airsim (40, 40), object world (40, 40), KITTI 00 (40, 40; needs the downloaded set, left
    out with `kitti=False`), and with `city` the rendered city (40, 40; renders and caches
    3 worlds x 5 runs on first use)."""
    out: list[LabeledPair] = []
    sources = [(airsim_pairs, {"keep": 0.9}), (world_pairs, {})]
    sources += [(kitti_pairs, {})] if kitti else []
    for build, kw in sources + ([(city_pairs, {})] if city else []):
        out += build(40 * scale, True, seed, **kw) + build(40 * scale, False, seed, **kw)
    return out
