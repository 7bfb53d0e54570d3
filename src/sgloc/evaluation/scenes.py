"""What every evaluation scene is made of: the `Pair`, the random motion of the target map, the
route overlap, and the registry of pair sources.

Above `metrics` only, below every other module of `sgloc.evaluation`. The map builders sit
beside their data (`pairs_kitti`, `pairs_sim`, `pairs`); trials, the acceptance
pair sets, the fleet scenes and the benchmarks all build their pairs from them and from here.

Seeds: a pair source's randomness uses `pair_rng(seed)` = `np.random.default_rng([seed,
PAIR_STREAM])`; the localizer in a trial uses another stream of the same seed.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from sgloc.evaluation.metrics import pose_errors
from sgloc.extraction import extraction_preset
from sgloc.geometry import invert, random_rigid_transform
from sgloc.maps.graph import DEFAULT_EDGE_RADIUS, SemanticGraph
from sgloc.registry import Registry

#: Stream index of the pair's random numbers within a trial seed.
PAIR_STREAM = 0
#: Default random motion of the target map: translation (m) and roll/pitch (deg) bounds.
MAX_TRANSLATION, MAX_ROLL_PITCH_DEG = 200.0, 5.0


@dataclass
class Pair:
    """Two robots' graphs and the ground truth: p_target = T_target_query @ p_query.

    T_moved_own: the random rigid motion applied to the target map in this trial (its map
    frame "own" -> the frame it is handed to the localizer in, "moved"); identity when none.
    Pose errors are reported in the target map's own frame (undoing that motion), so that a
    random 200 m shift of the frame's origin does not turn rotation error into translation
    error; the error in the moved frame is reported beside it.
    """

    query: SemanticGraph
    target: SemanticGraph
    T_target_query: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)
    T_moved_own: np.ndarray = field(default_factory=lambda: np.eye(4))

    def own_frame_errors(self, T_est: np.ndarray | None) -> tuple[float, float]:
        """(translation m, rotation deg) of the estimate T_est (query -> moved target) against
        the ground truth, in the target map's own frame; NaN when there is no estimate."""
        T_own_moved = invert(self.T_moved_own)
        T_own = None if T_est is None else T_own_moved @ T_est
        return pose_errors(T_own, T_own_moved @ self.T_target_query)


PairSource = Callable[[int], Pair]

#: name -> class of pair source (called with its parameters, then with a seed); "synthetic"
#: is another name of "city".
PAIR_SOURCES: Registry[type] = Registry("dataset", aliases={"synthetic": "city"})

#: Class decorator: register a pair source class under a name (`@register_pair_source("x")`).
register_pair_source = PAIR_SOURCES.register


def pair_rng(seed: int) -> np.random.Generator:
    """The generator of a trial's pair randomness (initial transform, world, split)."""
    return np.random.default_rng([int(seed), PAIR_STREAM])


@functools.lru_cache(maxsize=16)
def load_graph_cached(path: str, edge_radius: float) -> SemanticGraph:
    """Load a graph file once per process (graphs are immutable, so sharing is safe)."""
    return SemanticGraph.load(path, edge_radius=edge_radius)


@functools.lru_cache(maxsize=512)
def extracted_graph(
    dataset: str, root: str, name: str, edge_radius: float = DEFAULT_EDGE_RADIUS, **selection: Any
) -> SemanticGraph:
    """The graph extracted, with the data set's extraction preset, from the frames of
    `make_dataset(dataset, root, **selection)`; once per process."""
    from sgloc.datasets import make_dataset
    from sgloc.extraction import build_graph

    graph = build_graph(make_dataset(dataset, root, **selection), extraction_preset(dataset), name)
    return graph.with_edge_radius(edge_radius)


def move_target(
    query: SemanticGraph,
    target_same_frame: SemanticGraph,
    T_target_query0: np.ndarray,
    rng: np.random.Generator,
    max_translation: float = MAX_TRANSLATION,
    max_roll_pitch_deg: float = MAX_ROLL_PITCH_DEG,
) -> Pair:
    """The pair with the target map moved by a random rigid transform T drawn from `rng` (any
    yaw, roll/pitch up to `max_roll_pitch_deg`, translation up to `max_translation` m); the
    ground truth becomes T @ T_target_query0. Pair sources pass `pair_rng(seed)`."""
    T = random_rigid_transform(rng, max_translation, max_roll_pitch_deg)
    return Pair(
        query=query,
        target=target_same_frame.transformed(T),
        T_target_query=T @ T_target_query0,
        T_moved_own=T,
        info={"initial_translation_m": float(np.linalg.norm(T[:3, 3]))},
    )


@dataclass(frozen=True)
class MovedTargetSource:
    """Base of the pair sources that hand the target map over moved by a random rigid transform
    per trial: a source names its maps and their ground truth in `maps(seed) -> (query, target,
    T_target_query0, info)`, and `__call__(seed)` moves the target (`move_target` with
    `pair_rng(seed)`) and adds `info` to the pair's."""

    max_translation: float = MAX_TRANSLATION
    max_roll_pitch_deg: float = MAX_ROLL_PITCH_DEG
    #: The data set whose folder under SGLOC_DATA is the default `root` (sources with a root).
    data_set: ClassVar[str | None] = None

    def resolved(self) -> MovedTargetSource:
        """A copy with `root` made absolute (so remote workers need no SGLOC_DATA)."""
        if not hasattr(self, "root"):
            return self
        return dataclasses.replace(self, root=scene_data_root(self.root, self.data_set))

    def maps(self, seed: int) -> tuple[SemanticGraph, SemanticGraph, np.ndarray, dict[str, Any]]:
        """(query, target, T_target_query0 in the maps' own frames, info) of trial `seed`."""
        raise NotImplementedError

    def __call__(self, seed: int) -> Pair:
        q, t, T0, info = self.resolved().maps(seed)
        rng = pair_rng(seed)
        pair = move_target(q, t, T0, rng, self.max_translation, self.max_roll_pitch_deg)
        pair.info.update(info)
        return pair


def scene_data_root(root: str | None, data_set: str | None) -> str:
    """`root` made absolute, or the folder of `data_set` under SGLOC_DATA when it is unset (so
    remote workers need no SGLOC_DATA)."""
    from pathlib import Path

    from sgloc.datasets.downloads import data_path

    return str((Path(root) if root else data_path(data_set)).resolve())


def route_overlap(xy_query: np.ndarray, xy_target: np.ndarray, radius: float) -> float:
    """Fraction of the query route's length (positions (n,2) or (n,3) along the route, metres)
    that passes within `radius` of the target route's positions. The one overlap definition of
    the evaluation (`window_overlaps` computes it for many windows at once)."""
    return float(window_overlaps(xy_query, xy_target, np.array([0]), len(xy_query), radius)[0])


def window_overlaps(
    route: np.ndarray, target_route: np.ndarray, starts: np.ndarray, length: int, radius: float
) -> np.ndarray:
    """`route_overlap(route[s : s + length], target_route, radius)` for every window start s of
    `starts`, all at once by cumulative sums over the route."""
    from scipy.spatial import cKDTree

    step = np.linalg.norm(np.diff(route, axis=0), axis=1)
    near = cKDTree(target_route).query(route[:-1], distance_upper_bound=radius)[0] < radius
    c_all = np.concatenate([[0.0], np.cumsum(step)])
    c_near = np.concatenate([[0.0], np.cumsum(step * near)])
    e = starts + length - 1
    return (c_near[e] - c_near[starts]) / np.maximum(c_all[e] - c_all[starts], 1e-9)
