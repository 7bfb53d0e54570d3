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
from typing import Any, ClassVar

import numpy as np

from sgloc.errors import DatasetError, UnknownNameError
from sgloc.geometry import invert, random_rigid_transform
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


KITTI_LC_FILES = ("kitti_lc_test_0_10.txt", "kitti_lc_test_10_20.txt", "kitti_lc_test_20_30.txt")


@functools.lru_cache(maxsize=2)
def _kitti_sequence(root: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T_seq_lidar (N,4,4) per scan, revisit pairs (k,2) i<j, their M (k,4,4) with
    p_j = M p_i) of KITTI 00 under `root`, read once per process."""
    from sgloc.datasets.kitti_objects import TR_KITTI_00
    from sgloc.io.poses import read_kitti_poses

    P = read_kitti_poses(Path(root) / "poses_00.txt")
    Tr = np.eye(4)
    Tr[:3] = TR_KITTI_00
    pairs, Ms = [], []
    for name in KITTI_LC_FILES:
        f = Path(root) / name
        if f.is_file():
            a = np.loadtxt(f, skiprows=1, ndmin=2)
            pairs.append(a[:, [1, 3]].astype(np.int64))
            Ms.append(a[:, 4:20].reshape(-1, 4, 4))
    if not pairs:
        raise DatasetError(f"{root}: no kitti_lc_test_*.txt revisit files.")
    ij, M = np.concatenate(pairs), np.concatenate(Ms)
    swap = ij[:, 0] > ij[:, 1]
    ij[swap] = ij[swap][:, ::-1]
    M[swap] = np.linalg.inv(M[swap])
    return P @ Tr, ij, M


@functools.lru_cache(maxsize=256)
def _kitti_graph(root: str, first: int, last: int, edge_radius: float) -> SemanticGraph:
    """One robot's graph from scans first..last (inclusive), in its first scan's LiDAR frame."""
    from sgloc.datasets import make_dataset
    from sgloc.extraction import build_graph, kitti_objects_extraction_config

    ds = make_dataset("kitti_objects", root, scans=(first, last), start_frame=True)
    g = build_graph(ds, kitti_objects_extraction_config(), name=f"kitti00[{first}-{last}]")
    return g.with_edge_radius(edge_radius)


@functools.lru_cache(maxsize=8)
def _kitti_places(src: Kitti00Pairs) -> np.ndarray:
    _, ij, _ = _kitti_sequence(src.root)
    ok = np.flatnonzero(ij[:, 1] - ij[:, 0] >= src.min_gap)
    ok = ok[np.lexsort((ij[ok, 1], ij[ok, 0]))]
    chosen: list[int] = []
    for k in ok:
        if any(abs(ij[k, 0] - ij[c, 0]) < src.length // 2 for c in chosen):
            continue
        _, _, ovs = src._sliding(int(k))
        if ovs.size and ovs.max() >= src.min_max_overlap and ovs.min() <= 0.1:
            chosen.append(int(k))
    if not chosen:
        raise DatasetError(f"{src.root}: no revisit with a long enough shared stretch.")
    picks = np.linspace(0, len(chosen) - 1, min(src.n_places, len(chosen)))
    return np.array(chosen)[np.round(picks).astype(int)]


def route_overlap(xy_query: np.ndarray, xy_target: np.ndarray, radius: float) -> float:
    """Fraction of the query route's length (scan positions (n,2), metres) that passes within
    `radius` of the target route's scan positions."""
    from scipy.spatial import cKDTree

    step = np.linalg.norm(np.diff(xy_query, axis=0), axis=1)
    near = cKDTree(xy_target).query(xy_query[:-1], distance_upper_bound=radius)[0] < radius
    return float((step * near).sum() / max(step.sum(), 1e-9))


@register_pair_source("kitti00")
@dataclass(frozen=True)
class Kitti00Pairs:
    """KITTI 00 LiDAR objects (GOSMatch) as two robots, each mapping a scan range in its own
    first-scan frame; the target is also moved by a random rigid transform per trial.

    overlap=None: the fixed split of the data README (robot A = target = scans `split[0:2]`,
    robot B = query = scans `split[2:4]`).
    overlap=o: trial seed s uses revisit place s % n_places (distinct revisits (i, j) of the
    sequence from kitti_lc_test_*.txt, j - i >= min_gap scans; graphs are built once per place
    and process); robot A maps `length` scans centred on i, robot B a window of
    `length` scans near j, slid so that the fraction of B's route within `radius` m of A's
    route is as close to o as the trajectory allows (the achieved value is in the row as
    pair_overlap).
    Ground truth T_A_B: in overlap mode the poses chained through the revisit's refined
    transform M (kitti_lc_test_*.txt; more accurate than the raw poses near the revisit, and
    the windows are centred on it); for the fixed split the raw poses (M is only locally
    accurate and the split's maps reach hundreds of metres beyond it).
    """

    #: Recommended localizer settings (the extraction preset's: precise LiDAR centroids).
    localizer_settings: ClassVar[dict[str, Any]] = {"ransac_threshold": 2.0, "tau": 2.0}

    root: str | None = None
    overlap: float | None = None
    length: int = 300
    radius: float = 10.0
    min_gap: int = 600
    n_places: int = 10
    min_max_overlap: float = 0.5
    split: tuple[int, int, int, int] = (0, 800, 3900, 4540)
    max_translation: float = 200.0
    max_roll_pitch_deg: float = 5.0
    edge_radius: float = 20.0

    def resolved(self) -> Kitti00Pairs:
        from sgloc.data import data_path

        root = Path(self.root) if self.root else data_path("kitti00")
        return dataclasses.replace(self, root=str(root.resolve()))

    def _sliding(self, k: int) -> tuple[tuple[int, int], np.ndarray, np.ndarray]:
        """For revisit k: robot A's scans, the candidate first scans of robot B's window, and
        each window's route overlap with A (cumulative sums over the route, all at once)."""
        from scipy.spatial import cKDTree

        L_seq, ij, _ = _kitti_sequence(self.root)
        xy = L_seq[:, [0, 2], 3]  # the camera sequence frame: ground plane is x-z
        n, (i, j) = len(L_seq), ij[k]
        a0 = int(np.clip(i - self.length // 2, 0, n - self.length))
        a = (a0, a0 + self.length - 1)
        lo = max(a[1] + 1, j - 2 * self.length)
        starts = np.arange(lo, max(lo, min(n - self.length, j + self.length)) + 1)
        step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        near = cKDTree(xy[a[0] : a[1] + 1]).query(xy[:-1], distance_upper_bound=self.radius)[0]
        c_all = np.concatenate([[0.0], np.cumsum(step)])
        c_near = np.concatenate([[0.0], np.cumsum(step * (near < self.radius))])
        e = starts + self.length - 1
        ovs = (c_near[e] - c_near[starts]) / np.maximum(c_all[e] - c_all[starts], 1e-9)
        return a, starts, ovs

    def places(self) -> np.ndarray:
        """Indices of up to `n_places` distinct revisits (j - i >= min_gap) spread over the
        sequence, each on a shared stretch of road long enough that robot B's window can be
        slid from overlap <= 0.1 to >= `min_max_overlap` with robot A's."""
        return _kitti_places(self)

    def windows(self, seed: int) -> tuple[tuple[int, int], tuple[int, int], int, float]:
        """(A scans, B scans, revisit index, achieved overlap) for a trial seed."""
        L_seq, ij, _ = _kitti_sequence(self.root)
        if self.overlap is None:
            # Raw poses: the split's maps extend hundreds of scans from any revisit, where a
            # revisit's locally refined M is off by ~1 deg (measured: 64 of B's objects land
            # within 1 m of a same-class A object with the raw poses, 7 with M).
            xy = L_seq[:, [0, 2], 3]
            a, b = (self.split[0], self.split[1]), (self.split[2], self.split[3])
            ov = route_overlap(xy[b[0] : b[1] + 1], xy[a[0] : a[1] + 1], self.radius)
            return a, b, -1, ov
        places = self.places()
        k = int(places[int(seed) % len(places)])
        a, starts, ovs = self._sliding(k)
        best = int(np.argmin(np.abs(ovs - self.overlap)))
        s = int(starts[best])
        return a, (s, s + self.length - 1), k, float(ovs[best])

    def __call__(self, seed: int) -> Pair:
        src = self if self.root else self.resolved()
        L_seq, ij, M = _kitti_sequence(src.root)
        a, b, k, ov = src.windows(seed)
        target = _kitti_graph(src.root, a[0], a[1], src.edge_radius)
        query = _kitti_graph(src.root, b[0], b[1], src.edge_radius)
        if k >= 0:  # chain through the refined revisit: A <- L_i <- L_j <- B
            i, j = ij[k]
            T_A_B = invert(L_seq[a[0]]) @ L_seq[i] @ invert(M[k]) @ invert(L_seq[j]) @ L_seq[b[0]]
        else:
            T_A_B = invert(L_seq[a[0]]) @ L_seq[b[0]]
        pair = _moved_target(
            query, target, T_A_B, seed, src.max_translation, src.max_roll_pitch_deg
        )
        pair.info.update(
            {"overlap": round(ov, 4), "scans_a": f"{a[0]}-{a[1]}", "scans_b": f"{b[0]}-{b[1]}"}
        )
        return pair


#: Disk cache of graphs extracted from rendered synthetic runs (gitignored).
CACHE_DIR = Path(".sgloc_cache") / "evaluation"


@functools.lru_cache(maxsize=1)
def _code_hash() -> str:
    """Short hash of the simulator's and the extraction's source (a cache key part, so cached
    graphs are rebuilt when that code changes)."""
    import hashlib

    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha1()
    for p in sorted([*(root / "sim").glob("*.py"), *(root / "extraction").glob("*.py")]):
        h.update(p.read_bytes())
    return h.hexdigest()[:8]


@functools.lru_cache(maxsize=64)
def _city_graphs(
    world: int, overlap: float, width: int, height: int, length: float
) -> tuple[SemanticGraph, SemanticGraph, np.ndarray]:
    """(query = backwardCar graph, target = forwardCar graph, T_target_query) of the synthetic
    city run `world` at `overlap`: rendered and extracted once, then read from the disk cache."""
    from sgloc.data import PROJECT_ROOT

    key = f"city-w{world}-o{overlap:g}-{width}x{height}-L{length:g}-{_code_hash()}"
    path = PROJECT_ROOT / CACHE_DIR / f"{key}.npz"
    if path.is_file():
        z = np.load(path)
        return (
            SemanticGraph(z["q_pos"], z["q_lab"], name=f"{key}:query"),
            SemanticGraph(z["t_pos"], z["t_lab"], name=f"{key}:target"),
            z["T"],
        )
    from sgloc.extraction import build_graph
    from sgloc.sim.run import QUERY, TARGET, make_synthetic_run

    run = make_synthetic_run(seed=world, overlap=overlap, width=width, height=height, length=length)
    t = build_graph(run.frames(TARGET), name=f"{key}:target")
    q = build_graph(run.frames(QUERY), name=f"{key}:query")
    T = run.ground_truth
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{np.random.default_rng().integers(1 << 30)}.tmp.npz")
    np.savez(tmp, q_pos=q.positions, q_lab=q.labels, t_pos=t.positions, t_lab=t.labels, T=T)
    tmp.replace(path)
    return q, t, T


@register_pair_source("city")
@dataclass(frozen=True)
class CityPairs:
    """The rendered synthetic city (`sgloc.sim`): two robots drive opposite ways sharing
    `overlap` of their routes; each map is extracted from its rendered semantic + depth frames
    and lies in the robot's own start frame. Trial seed s uses city `s % n_worlds` (rendering
    is the expensive part; graphs are cached on disk under .sgloc_cache/), and the target is
    moved by a random rigid transform per trial."""

    #: Recommended localizer settings (sgloc.sim.CITY_LOCALIZER_SETTINGS: buildings weigh less).
    localizer_settings: ClassVar[dict[str, Any]] = {"class_weights": {0: 0.1}}

    overlap: float = 0.5
    n_worlds: int = 5
    width: int = 320
    height: int = 180
    length: float = 400.0
    max_translation: float = 200.0
    max_roll_pitch_deg: float = 5.0

    def world(self, seed: int) -> int:
        return int(seed) % self.n_worlds

    def prepare(self, seed: int) -> str:
        """Render and extract the world of `seed` into the cache (for parallel warm-up)."""
        _city_graphs(self.world(seed), self.overlap, self.width, self.height, self.length)
        return f"world {self.world(seed)}"

    def __call__(self, seed: int) -> Pair:
        w = self.world(seed)
        q, t, T0 = _city_graphs(w, self.overlap, self.width, self.height, self.length)
        pair = _moved_target(q, t, T0, seed, self.max_translation, self.max_roll_pitch_deg)
        pair.info.update({"overlap": self.overlap, "world": w})
        return pair


@functools.lru_cache(maxsize=8)
def _airsim_run_graphs(root: str, target: str, query: str) -> tuple[SemanticGraph, ...]:
    """(query graph, target graph) extracted from an Airsim-layout run, once per process."""
    from sgloc.datasets import make_dataset
    from sgloc.extraction import build_graph

    graphs = []
    for robot in (query, target):
        ds = make_dataset("airsim", root, robot=robot)
        graphs.append(build_graph(ds, name=f"{Path(root).name}:{robot}"))
    return tuple(graphs)


@register_pair_source("airsim-run")
@dataclass(frozen=True)
class AirsimRunPairs:
    """A two-robot run in Guo's Airsim layout (e.g. written by `sgloc.sim`): the folders
    `target` and `query` (frames + airsim.txt) and `ground_truth.txt` (T_target_query). Both
    graphs are extracted from the images once per process; the target is moved by a random
    rigid transform per trial."""

    root: str = "."
    target: str = "forwardCar"
    query: str = "backwardCar"
    max_translation: float = 200.0
    max_roll_pitch_deg: float = 5.0

    def __call__(self, seed: int) -> Pair:
        from sgloc.sim.airsim_writer import read_ground_truth

        q, t = _airsim_run_graphs(str(Path(self.root).resolve()), self.target, self.query)
        T0 = read_ground_truth(self.root)
        return _moved_target(q, t, T0, seed, self.max_translation, self.max_roll_pitch_deg)


#: Dataset names that stand for another source with set parameters (filled in as modules land).
ALIASES: dict[str, str] = {"synthetic": "city"}


def make_pair_source(name: str, **params: Any) -> PairSource:
    """A pair source by registered name (or alias), or by a folder: an Airsim-layout two-robot
    run (with ground_truth.txt), or a folder holding two graph files."""
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
    if path.is_dir() and (path / "ground_truth.txt").is_file():
        return AirsimRunPairs(root=str(path.resolve()), **params)
    if path.is_dir():
        return GraphFilePairs(root=str(path.resolve()), **params)
    raise UnknownNameError(
        f"unknown dataset {name!r}; choose one of {', '.join(dataset_names())} or give a folder "
        "holding two graph files or an Airsim-layout run with ground_truth.txt."
    )


def dataset_names() -> list[str]:
    """Every name `make_pair_source` accepts (registered sources and aliases)."""
    return sorted(set(PAIR_SOURCES) | set(ALIASES))
