"""Pair sources from rendered runs: `city` (the synthetic city, graphs cached on disk) and
`airsim-run` (any two-robot run in Guo's Airsim layout)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from sgloc.evaluation.scenes import MovedTargetSource, extracted_graph, register_pair_source
from sgloc.maps.graph import SemanticGraph
from sgloc.pipeline.presets import localizer_settings as preset_settings


def evaluation_cache_dir() -> Path:
    """Where extracted city graphs are cached:
    `<sgloc.datasets.downloads.cache_dir()>/evaluation`."""
    from sgloc.datasets.downloads import cache_dir

    return cache_dir() / "evaluation"


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
def city_graphs(
    world: int,
    overlap: float,
    width: int = 320,
    height: int = 180,
    length: float = 400.0,
    any_code_version: bool = False,
) -> tuple[SemanticGraph, SemanticGraph, np.ndarray]:
    """(query = backwardCar graph, target = forwardCar graph, T_target_query) of the synthetic
    city run `world` at `overlap`: rendered and extracted once, then read from the disk cache.

    any_code_version: use the newest cached graphs of that run even when an earlier version of
    the sim or extraction code made them (the cache key names it; rendering takes minutes)."""
    stem = f"city-w{world}-o{overlap:g}-{width}x{height}-L{length:g}"
    path = evaluation_cache_dir() / f"{stem}-{_code_hash()}.npz"
    found = sorted(path.parent.glob(f"{stem}-*.npz"), key=lambda p: p.stat().st_mtime)
    if any_code_version and found:
        path = found[-1]
    elif not path.is_file():
        _render_city(path, world, overlap, width, height, length)
    z, key = np.load(path), path.stem
    return (
        SemanticGraph(z["q_pos"], z["q_lab"], name=f"{key}:query"),
        SemanticGraph(z["t_pos"], z["t_lab"], name=f"{key}:target"),
        z["T"],
    )


def _render_city(
    path: Path, world: int, overlap: float, width: int, height: int, length: float
) -> None:
    """Render the city run, extract both robots' graphs and save them at `path` (atomically)."""
    from sgloc.extraction import build_graph
    from sgloc.sim.run import QUERY, TARGET, make_synthetic_run

    run = make_synthetic_run(seed=world, overlap=overlap, width=width, height=height, length=length)
    t, q = build_graph(run.frames(TARGET)), build_graph(run.frames(QUERY))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{np.random.default_rng().integers(1 << 30)}.tmp.npz")
    T = run.ground_truth
    np.savez(tmp, q_pos=q.positions, q_lab=q.labels, t_pos=t.positions, t_lab=t.labels, T=T)
    tmp.replace(path)


@register_pair_source("city")
@dataclass(frozen=True)
class CityPairs(MovedTargetSource):
    """The rendered synthetic city (`sgloc.sim`): two robots drive opposite ways sharing
    `overlap` of their routes; each map is extracted from its rendered semantic + depth frames
    and lies in the robot's own start frame. Trial seed s uses city `s % n_worlds` (rendering
    is the expensive part; graphs are cached on disk under sgloc.datasets.downloads.cache_dir()),
    and the target is moved by a random rigid transform per trial."""

    #: Recommended localizer settings (the `city` preset: buildings weigh less).
    localizer_settings: ClassVar[dict[str, Any]] = preset_settings("city")

    overlap: float = 0.5
    n_worlds: int = 5
    width: int = 320
    height: int = 180
    length: float = 400.0

    def world(self, seed: int) -> int:
        """The city of trial `seed` (what the disk cache holds; see `trials.prepare_tasks`)."""
        return int(seed) % self.n_worlds

    def maps(self, seed: int) -> tuple[SemanticGraph, SemanticGraph, np.ndarray, dict[str, Any]]:
        w = self.world(seed)
        q, t, T0 = city_graphs(w, self.overlap, self.width, self.height, self.length)
        return q, t, T0, {"overlap": self.overlap, "world": w}


@register_pair_source("airsim-run")
@dataclass(frozen=True)
class AirsimRunPairs(MovedTargetSource):
    """A two-robot run in Guo's Airsim layout (e.g. written by `sgloc.sim`): the folders
    `target` and `query` (frames + airsim.txt) and `ground_truth.txt` (T_target_query). Both
    graphs are extracted from the images once per process; the target is moved by a random
    rigid transform per trial."""

    root: str = "."
    target: str = "forwardCar"
    query: str = "backwardCar"

    def maps(self, seed: int) -> tuple[SemanticGraph, SemanticGraph, np.ndarray, dict[str, Any]]:
        from sgloc.sim.airsim_writer import read_ground_truth

        name = Path(self.root).name
        q, t = (
            extracted_graph("airsim", self.root, f"{name}:{r}", robot=r)
            for r in (self.query, self.target)
        )
        return q, t, read_ground_truth(self.root), {}
