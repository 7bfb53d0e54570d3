"""The whole pipeline from pixels to transform on the rendered synthetic city (`sgloc demo`).

First run: generate a city and two robots' routes, render both robots' semantic + depth images
into an Airsim-layout run under the cache folder (<cache>/demo/<key>); later runs reuse it, and
the graphs extracted from it (kept beside it). Then read the run back with the `airsim` loader,
extract both graphs, localize robot B (query) in robot A's map (target) and draw the two maps
aligned with the final matches. `objects_demo` does the same on the tiny object world (no
rendering)."""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sgloc.io.pictures import picture_path
from sgloc.maps.graph import SemanticGraph
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.localizer import LocalizationResult, localize
from sgloc.sim.airsim_writer import read_ground_truth
from sgloc.sim.run import QUERY, TARGET, SyntheticRun, SyntheticRunConfig

#: What the demo reports as its work advances: done of total in a phase ("rendering WxH",
#: "extracting <robot>").
Progress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class DemoResult:
    """Robot B (query) localized in robot A's map (target): the result, the true
    T_target_query, and the rendered run it came from (None: the object world)."""

    target: SemanticGraph
    query: SemanticGraph
    result: LocalizationResult
    truth: np.ndarray
    run_dir: Path | None = None


def default_cache_dir() -> Path:
    """$SGLOC_CACHE, else the per-user cache folder (~/.cache/sgloc on Linux)."""
    from sgloc.datasets.downloads import cache_dir

    return cache_dir()


@dataclass(frozen=True)
class CityDemo:
    """A checked demo on the rendered city: the run to render, the localizer settings, the
    descriptor and rejection names."""

    run: SyntheticRunConfig
    config: LocalizerConfig
    descriptor: str = "distance_histogram"
    rejection: str = "neighbor"

    def __call__(
        self,
        cache_dir: Path | None = None,
        refresh: bool = False,
        out: Path | None = None,
        progress: Progress | None = None,
        note: Callable[[str], None] | None = None,
    ) -> DemoResult:
        """Render the run (or reuse it from `cache_dir`, default `default_cache_dir()`;
        `refresh`: render and extract again), extract both graphs, localize B in A (seed: the
        run's) and draw the aligned maps to the picture `out` (`demo_picture`). `note` hears
        that a cached run is used."""
        if out is not None:
            out = picture_path(out)  # a format sgloc cannot draw: refused before the work
        run_dir = cached_run(self.run, cache_dir, refresh, progress, note)
        target, query = run_graphs(run_dir, refresh, progress)
        res = localize(query, target, self.descriptor, self.rejection, seed=self.run.seed,
                       config=self.config)
        done = DemoResult(target, query, res, read_ground_truth(run_dir), run_dir)
        if out is not None:
            demo_picture(done, out)
        return done


def city_demo(
    run: SyntheticRunConfig,
    config: LocalizerConfig,
    descriptor: str = "distance_histogram",
    rejection: str = "neighbor",
) -> CityDemo:
    """The demo of `run` localizing with `config`, `descriptor` and `rejection`; UnknownNameError
    for a descriptor or rejection that does not exist, before anything is rendered."""
    LocalizerConfig().with_overrides(descriptor=descriptor, rejection=rejection)
    return CityDemo(run, config, descriptor, rejection)


def cached_run(
    run: SyntheticRunConfig, cache_dir: Path | None = None, refresh: bool = False,
    progress: Progress | None = None, note: Callable[[str], None] | None = None,
) -> Path:
    """The folder of the rendered `run` under `cache_dir`/demo, rendered now (through a
    `.partial` folder renamed when complete) unless it is there and not `refresh`."""
    run_dir = (cache_dir or default_cache_dir()) / "demo" / run.key()
    if not refresh and (run_dir / "run.json").is_file():
        if note is not None:
            note(f"using the cached run {run_dir}")
        return run_dir
    sim = SyntheticRun(run)  # validates the settings before anything is written
    if run_dir.exists():
        shutil.rmtree(run_dir)
    tmp = run_dir.with_name(run_dir.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    total, done = sum(sim.n_frames(r) for r in sim.robots), [0]
    phase = f"rendering {run.width}x{run.height}"

    def step(n: int) -> None:
        done[0] += n
        if progress is not None:
            progress(done[0], total, phase)

    step(0)
    sim.write(tmp, progress=step)
    tmp.rename(run_dir)
    return run_dir


def run_graphs(
    run_dir: Path, refresh: bool = False, progress: Progress | None = None
) -> tuple[SemanticGraph, SemanticGraph]:
    """(target, query): both robots' graphs of the rendered run (`airsim` loader, default
    extraction), read from beside the run when extracted before (and not `refresh`); a graph
    extracted now is kept there unless the folder is read-only."""
    from sgloc.datasets import make_dataset
    from sgloc.extraction import ExtractionConfig, build_graph

    graphs: dict[str, SemanticGraph] = {}
    ext = ExtractionConfig()
    for robot in (TARGET, QUERY):
        cached = graph_file(run_dir, robot, ext)
        if cached.is_file() and not refresh:  # extracted before from this very run
            g = SemanticGraph.load(cached, ext.edge_radius)
            graphs[robot] = SemanticGraph(g.positions, g.labels, g.edge_radius, name=robot)
            continue
        ds = make_dataset("airsim", run_dir, robot=robot)
        ticks = _ticker(progress, len(ds), f"extracting {robot}")
        graphs[robot] = build_graph(ds.frames(), ext, name=robot, progress=ticks)
        with contextlib.suppress(OSError):  # a read-only cache: extract again next time
            graphs[robot].save(cached)
    return graphs[TARGET], graphs[QUERY]


def _ticker(progress: Progress | None, total: int, phase: str) -> Callable[[object], None]:
    done = [0]

    def tick(_frame: object) -> None:
        done[0] += 1
        if progress is not None:
            progress(done[0], total, phase)

    if progress is not None:
        progress(0, total, phase)
    return tick


def graph_file(run_dir: Path, robot: str, ext: object) -> Path:
    """Where robot's graph extracted with `ext` from the cached run is kept."""
    import hashlib

    key = hashlib.sha256(repr(ext).encode()).hexdigest()[:16]
    return run_dir / f"graph-{robot}-{key}.json"


def objects_demo(
    seed: int, overlap: float, config: LocalizerConfig, descriptor: str = "distance_histogram",
    rejection: str = "neighbor", out: Path | None = None,
) -> DemoResult:
    """The demo on the tiny object world (`make_two_robot_scene`): localize, draw to `out`."""
    from sgloc.sim.object_world import make_two_robot_scene

    if out is not None:
        out = picture_path(out)

    scene = make_two_robot_scene(seed=seed, overlap=overlap)
    res = localize(scene.query, scene.target, descriptor, rejection, seed=seed, config=config)
    done = DemoResult(scene.target, scene.query, res, scene.T_target_query)
    if out is not None:
        demo_picture(done, out)
    return done


def demo_picture(done: DemoResult, out: Path) -> Path:
    """Top-down view (x right, y up) of robot A's map and robot B's map placed by the estimated
    transform (the true one when not localized), classes coloured, final matches as lines and,
    for a rendered run, the two routes and the error in the title (`sgloc.io.pictures`).
    `out`: a picture file of any of `picture_formats` (an earlier picture of sgloc is
    replaced), or a folder to draw aligned_maps.png in (`picture_path`); the path drawn."""
    from sgloc.io.files import is_sgloc_picture, staged_file
    from sgloc.io.pictures import plot_aligned_maps

    out = picture_path(out)

    res = done.result
    T = res.transform if res.accepted else done.truth
    how = "estimated" if res.accepted else "ground-truth (not localized)"
    title = f"B placed in A's map by the {how} transform"
    names, routes = None, None
    if done.run_dir is not None:
        from sgloc.geometry import transform_error
        from sgloc.sim.city import CITY_CLASSES

        names, routes = CITY_CLASSES, _routes(done.run_dir)
        if res.accepted:
            te, re = transform_error(res.transform, done.truth)
            conf = "" if res.confidence is None else f", confidence {res.confidence:.3f}"
            title = f"B placed in A's map: error {te:.2f} m / {re:.2f}°{conf}"
    with staged_file(out, ours=is_sgloc_picture) as tmp:
        plot_aligned_maps(done.target, done.query, T, res.matches, tmp, title, names, routes)
    return out


def _routes(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    from sgloc.datasets import make_dataset

    return (make_dataset("airsim", run_dir, robot=TARGET).poses[:, :3, 3],
            make_dataset("airsim", run_dir, robot=QUERY).poses[:, :3, 3])
