"""Pair sources: a trial seed -> (query graph, target graph, ground-truth T_target_query).

A pair source is a small picklable object (a frozen dataclass of its parameters) with
`__call__(seed) -> Pair`; it is registered by name in `PAIR_SOURCES`, so any dataset plugs into
the trial runner. Everything random in a pair comes from the seed, so a trial is a pure function
of (source, parameters, seed) and gives the same pair on any process or Dask worker.

Seeds: the pair's randomness uses `np.random.default_rng([seed, PAIR_STREAM])`; the localizer in
a trial uses another stream of the same seed (see `sgloc.evaluation.trials`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.errors import DatasetError, UnknownNameError
from sgloc.geometry import random_rigid_transform
from sgloc.graph import SemanticGraph

#: Stream index of the pair's random numbers within a trial seed.
PAIR_STREAM = 0
GRAPH_SUFFIXES = (".pcd", ".json", ".npz")


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


PairSource = Callable[[int], Pair]

#: name -> class of pair source (called with its parameters, then with a seed).
PAIR_SOURCES: dict[str, type] = {}


def register_pair_source(name: str) -> Callable[[type], type]:
    """Class decorator: register a pair source class under `name`."""

    def deco(cls: type) -> type:
        PAIR_SOURCES[name] = cls
        cls.source_name = name
        return cls

    return deco


def pair_rng(seed: int) -> np.random.Generator:
    """The generator of a trial's pair randomness (initial transform, world, split)."""
    return np.random.default_rng([int(seed), PAIR_STREAM])


@functools.lru_cache(maxsize=16)
def load_graph_cached(path: str, edge_radius: float) -> SemanticGraph:
    """Load a graph file once per process (graphs are immutable, so sharing is safe)."""
    return SemanticGraph.load(path, edge_radius=edge_radius)


def _moved_target(
    query: SemanticGraph,
    target_same_frame: SemanticGraph,
    T_target_query0: np.ndarray,
    seed: int,
    max_translation: float,
    max_roll_pitch_deg: float,
) -> Pair:
    """Apply a random rigid transform T to the target map; GT becomes T @ T_target_query0."""
    T = random_rigid_transform(pair_rng(seed), max_translation, max_roll_pitch_deg)
    return Pair(
        query=query,
        target=target_same_frame.transformed(T),
        T_target_query=T @ T_target_query0,
        T_moved_own=T,
        info={"initial_translation_m": float(np.linalg.norm(T[:3, 3]))},
    )


@register_pair_source("airsim-guo")
@dataclass(frozen=True)
class AirsimGuoPairs:
    """Guo's Airsim object maps: cloud1 (query) against cloud2 moved by a random rigid transform
    (any yaw, roll/pitch up to `max_roll_pitch_deg`, translation up to `max_translation` m).
    Both maps are in the Airsim world frame, so the ground truth is that transform."""

    root: str | None = None
    query_file: str = "cloud1.pcd"
    target_file: str = "cloud2.pcd"
    max_translation: float = 200.0
    max_roll_pitch_deg: float = 5.0
    edge_radius: float = 20.0

    def resolved(self) -> AirsimGuoPairs:
        """A copy with `root` made absolute (so remote workers need no SGLOC_DATA)."""
        from sgloc.data import data_path

        root = Path(self.root) if self.root else data_path("airsim_guo")
        return dataclasses.replace(self, root=str(root.resolve()))

    def __call__(self, seed: int) -> Pair:
        src = self if self.root else self.resolved()
        root = Path(src.root)
        q = load_graph_cached(str(root / src.query_file), src.edge_radius)
        t = load_graph_cached(str(root / src.target_file), src.edge_radius)
        return _moved_target(q, t, np.eye(4), seed, src.max_translation, src.max_roll_pitch_deg)


@register_pair_source("object-world")
@dataclass(frozen=True)
class ObjectWorldPairs:
    """The tiny code-generated object world (`sgloc.sim.object_world`): each seed draws a new
    world and two robots whose routes share `overlap` of their length."""

    overlap: float = 0.5
    stretch: float = 300.0
    view_radius: float = 40.0
    noise: float = 0.5

    def __call__(self, seed: int) -> Pair:
        from sgloc.sim.object_world import make_two_robot_scene

        scene = make_two_robot_scene(
            seed=int(seed),
            overlap=self.overlap,
            stretch=self.stretch,
            view_radius=self.view_radius,
            noise=self.noise,
        )
        return Pair(scene.query, scene.target, scene.T_target_query, {"overlap": self.overlap})


@register_pair_source("graph-files")
@dataclass(frozen=True)
class GraphFilePairs:
    """Two graph files in a folder (query and target; `.pcd`, `.json` or `.npz`), the target
    moved by a random rigid transform per trial. The maps' own relative pose is the identity,
    or the 4x4 matrix in `T_target_query.txt` in the same folder (p_target = T p_query)."""

    root: str = "."
    query_file: str | None = None
    target_file: str | None = None
    max_translation: float = 200.0
    max_roll_pitch_deg: float = 5.0
    edge_radius: float = 20.0

    def files(self) -> tuple[Path, Path]:
        root = Path(self.root)
        if self.query_file and self.target_file:
            q, t = root / self.query_file, root / self.target_file
        else:
            found = sorted(p for p in root.iterdir() if p.suffix.lower() in GRAPH_SUFFIXES)
            named = {p.stem.lower(): p for p in found}
            if "query" in named and "target" in named:
                q, t = named["query"], named["target"]
            elif len(found) == 2:
                q, t = found
            else:
                raise DatasetError(
                    f"{root}: expected two graph files (query.* and target.*, or exactly two "
                    f"{'/'.join(GRAPH_SUFFIXES)} files), found {len(found)}."
                )
        for p in (q, t):
            if not p.is_file():
                raise DatasetError(f"{p}: no such graph file.")
        return q, t

    def __call__(self, seed: int) -> Pair:
        q_path, t_path = self.files()
        q = load_graph_cached(str(q_path.resolve()), self.edge_radius)
        t = load_graph_cached(str(t_path.resolve()), self.edge_radius)
        gt_file = Path(self.root) / "T_target_query.txt"
        T0 = np.loadtxt(gt_file).reshape(4, 4) if gt_file.is_file() else np.eye(4)
        return _moved_target(q, t, T0, seed, self.max_translation, self.max_roll_pitch_deg)


#: Dataset names that stand for another source with set parameters (filled in as modules land).
ALIASES: dict[str, str] = {"synthetic": "city"}


def _register_all() -> None:
    """Import the modules that register the heavier pair sources (KITTI, rendered runs)."""
    import sgloc.evaluation.pairs_kitti  # noqa: F401
    import sgloc.evaluation.pairs_sim  # noqa: F401
    import sgloc.evaluation.pairs_synthia  # noqa: F401


def make_pair_source(name: str, **params: Any) -> PairSource:
    """A pair source by registered name (or alias), or by a folder: a SYNTHIA sequence (with
    CameraParams/), an Airsim-layout two-robot run (with ground_truth.txt), or a folder holding
    two graph files."""
    _register_all()
    key = ALIASES.get(name, name)
    if key in PAIR_SOURCES:
        cls = PAIR_SOURCES[key]
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(params) - known
        if unknown:
            raise UnknownNameError(
                f"dataset {name!r} has no parameter(s) {', '.join(sorted(unknown))}; "
                f"it takes {', '.join(sorted(known))}."
            )
        src = cls(**params)
        return src.resolved() if hasattr(src, "resolved") else src
    path = Path(name)
    if path.is_dir() and (path / "CameraParams").is_dir():
        return PAIR_SOURCES["synthia"](root=str(path.resolve()), **params)
    if path.is_dir() and (path / "ground_truth.txt").is_file():
        return PAIR_SOURCES["airsim-run"](root=str(path.resolve()), **params)
    if path.is_dir():
        return GraphFilePairs(root=str(path.resolve()), **params)
    raise UnknownNameError(
        f"unknown dataset {name!r}; choose one of {', '.join(dataset_names())} or give a folder "
        "holding two graph files or an Airsim-layout run with ground_truth.txt."
    )


def dataset_names() -> list[str]:
    """Every name `make_pair_source` accepts (registered sources and aliases)."""
    _register_all()
    return sorted(set(PAIR_SOURCES) | set(ALIASES))


# Re-exported for callers of the earlier single module (e.g. acceptance_pairs).
from sgloc.evaluation.pairs_kitti import Kitti00Pairs, route_overlap  # noqa: E402
from sgloc.evaluation.pairs_sim import (  # noqa: E402
    CACHE_DIR,
    AirsimRunPairs,
    CityPairs,
    _city_graphs,
)

__all__ = [
    "ALIASES",
    "CACHE_DIR",
    "PAIR_SOURCES",
    "AirsimGuoPairs",
    "AirsimRunPairs",
    "CityPairs",
    "GraphFilePairs",
    "Kitti00Pairs",
    "ObjectWorldPairs",
    "Pair",
    "_city_graphs",
    "dataset_names",
    "make_pair_source",
    "pair_rng",
    "register_pair_source",
    "route_overlap",
]
