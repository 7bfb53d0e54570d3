"""`sgloc demo`: the whole pipeline from pixels to transform on the rendered synthetic city.

First run: generate a city and two robots' routes, render both robots' semantic + depth images
into an Airsim-layout run under the cache folder (~/.cache/sgloc/demo/<key>); later runs reuse
it. Then read the run back with the `airsim` loader, extract both graphs, localize robot B
(query) in robot A's map (target), print the error against the ground truth and save a PNG of
the two maps aligned with the final matches. `--objects-only` runs the tiny object world
instead (no rendering).
"""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from sgloc.cli.app import app, compile_note, fail, not_localized
from sgloc.cli.outputs import claim_output
from sgloc.geometry import transform_error
from sgloc.io.files import is_sgloc_picture, staged_file
from sgloc.maps.graph import SemanticGraph
from sgloc.pipeline.localizer import LocalizationResult, localize

#: Where `sgloc demo` saves its picture unless told otherwise (relative to the current folder).
DEFAULT_OUT = Path("results") / "demo" / "aligned_maps.png"


def default_cache_dir() -> Path:
    """$SGLOC_CACHE, else the per-user cache folder (~/.cache/sgloc on Linux)."""
    from sgloc.datasets.downloads import cache_dir

    return cache_dir()


def _progress(console: Console) -> Progress:
    return Progress(
        TextColumn("{task.description:<28}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=False,
    )


@app.command("demo")
def demo_cmd(
    ctx: typer.Context,
    seed: int = typer.Option(0, min=0, help="Seed of the city, the routes and RANSAC."),
    overlap: float = typer.Option(0.5, help="Fraction of the two robots' routes they share."),
    width: int = typer.Option(320, help="Image width (px); fx = width / 2."),
    height: int = typer.Option(180, help="Image height (px)."),
    length: float = typer.Option(400.0, help="Route length of each robot (m)."),
    step: float = typer.Option(2.0, help="Distance between frames (m)."),
    descriptor: str = typer.Option(
        "distance_histogram", help="distance_histogram | triangles | histogram | random_walk | fast"
    ),
    rejection: str = typer.Option("neighbor", help="neighbor | none"),
    cache_dir: Path | None = typer.Option(
        None, help="Where rendered runs are kept (default $SGLOC_CACHE or ~/.cache/sgloc)."
    ),
    refresh: bool = typer.Option(False, help="Render again even if the run is cached."),
    paper_defaults: bool = typer.Option(
        False, help="Localize with the paper's defaults only (no city class weights)."
    ),
    out: Path = typer.Option(
        DEFAULT_OUT, help="PNG of the aligned maps (its folder is created; an existing file is "
        "replaced only if sgloc drew it)."
    ),
    objects_only: bool = typer.Option(
        False, "--objects-only", help="Use the tiny object world (no rendering, instant)."
    ),
    preset: str | None = typer.Option(
        None, "--preset",
        help="Named localizer settings (default: city; see sgloc.pipeline.presets)."
    ),
    setting: list[str] = typer.Option(
        [], "--set", metavar="NAME=VALUE", help="A setting NAME=VALUE (repeatable)."
    ),
) -> None:
    """Render a synthetic city seen by two robots, build their semantic graphs, localize one in
    the other and compare with the ground truth.

    Example: sgloc demo --overlap 0.3 --descriptor fast --out demo.png
    """
    console = Console()
    if not 0.0 <= overlap <= 1.0:
        raise fail(f"--overlap must be in [0, 1], got {overlap}.")
    claim_output(ctx, out, [cache_dir], folder=False, ours=is_sgloc_picture)
    if objects_only:
        from sgloc.cli.options import localizer_config

        config = localizer_config(preset, None, setting)  # the object world's own: the defaults
        _objects_only(console, seed, overlap, descriptor, rejection, config, out)
        return
    from sgloc.pipeline.config import LocalizerConfig

    LocalizerConfig().with_overrides(descriptor=descriptor, rejection=rejection)  # fail early
    from sgloc.datasets import make_dataset
    from sgloc.extraction import ExtractionConfig, build_graph
    from sgloc.sim import QUERY, TARGET, SyntheticRunConfig, read_ground_truth
    from sgloc.sim.run import SyntheticRun

    cfg = SyntheticRunConfig(
        seed=seed, overlap=overlap, width=width, height=height, length=length, step=step
    )
    run_dir = (cache_dir or default_cache_dir()) / "demo" / cfg.key()
    with _progress(console) as progress:
        if refresh or not (run_dir / "run.json").is_file():
            run = SyntheticRun(cfg)  # validates the settings before anything is written
            if run_dir.exists():
                shutil.rmtree(run_dir)
            tmp = run_dir.with_name(run_dir.name + ".partial")
            shutil.rmtree(tmp, ignore_errors=True)
            total = sum(run.n_frames(r) for r in run.robots)
            task = progress.add_task(f"rendering {width}x{height}", total=total)
            run.write(tmp, progress=lambda n: progress.advance(task, n))
            tmp.rename(run_dir)
        else:
            console.print(f"using the cached run {run_dir}")
        graphs: dict[str, SemanticGraph] = {}
        ext = ExtractionConfig()
        for robot in (TARGET, QUERY):
            cached = _graph_file(run_dir, robot, ext)
            if cached.is_file() and not refresh:  # extracted before from this very run
                g = SemanticGraph.load(cached, ext.edge_radius)
                graphs[robot] = SemanticGraph(g.positions, g.labels, g.edge_radius, name=robot)
                continue
            ds = make_dataset("airsim", run_dir, robot=robot)
            task = progress.add_task(f"extracting {robot}", total=len(ds))
            graphs[robot] = build_graph(
                ds.frames(), ext, name=robot, progress=lambda _f, t=task: progress.advance(t)
            )
            with contextlib.suppress(OSError):  # a read-only cache: extract again next time
                graphs[robot].save(cached)
    T_gt = read_ground_truth(run_dir)
    target, query = graphs[TARGET], graphs[QUERY]
    from sgloc.cli.options import localizer_config

    config = localizer_config(preset or ("paper" if paper_defaults else "city"), None, setting)
    res = localize(query, target, descriptor, rejection, seed=seed, config=config)
    _report(console, query, target, res, T_gt)
    T_plot = res.transform if res.success else T_gt
    title = None
    if res.success:
        te, re = transform_error(res.transform, T_gt)
        conf = "" if res.confidence is None else f", confidence {res.confidence:.3f}"
        title = f"B placed in A's map: error {te:.2f} m / {re:.2f}°{conf}"
    with staged_file(out, ours=is_sgloc_picture) as tmp:
        plot_aligned_maps(target, query, T_plot, res.matches, tmp, run_dir, res.success, title)
    console.print(f"saved {out}")
    if not res.success:
        raise not_localized(res.reason)


def _graph_file(run_dir: Path, robot: str, ext) -> Path:
    """Where robot's graph extracted with `ext` from the cached run is kept."""
    import hashlib

    key = hashlib.sha256(repr(ext).encode()).hexdigest()[:16]
    return run_dir / f"graph-{robot}-{key}.json"


def _report(console, query, target, res: LocalizationResult, T_gt: np.ndarray) -> None:
    table = Table(show_header=False, box=None)
    table.add_row("robot A (target)", f"{len(target)} vertices, {target.n_edges} edges")
    table.add_row("robot B (query)", f"{len(query)} vertices, {query.n_edges} edges")
    table.add_row(
        "matches",
        f"{len(res.candidates)} candidates, {len(res.survivors)} after rejection, "
        f"{len(res.matches)} final",
    )
    table.add_row("time", f"{res.timings['total'] * 1e3:.1f} ms {compile_note()}".rstrip())
    if res.success:
        te, re = transform_error(res.transform, T_gt)
        table.add_row("error vs ground truth", f"translation {te:.2f} m, rotation {re:.2f} deg")
    console.print(table)


def plot_aligned_maps(
    target: SemanticGraph,
    query: SemanticGraph,
    T_target_query: np.ndarray,
    matches: np.ndarray,
    path: Path,
    run_dir: Path | None = None,
    estimated: bool = True,
    title: str | None = None,
) -> Path:
    """Top-down view (x right, y up) of robot A's map and robot B's map placed by
    `T_target_query`, classes coloured, final matches as lines, and the two routes when
    `run_dir` is given (sgloc.io.pictures.plot_aligned_maps)."""
    from sgloc.io.pictures import plot_aligned_maps as plot
    from sgloc.sim.city import CITY_CLASSES

    routes = None
    if run_dir is not None:
        from sgloc.datasets import make_dataset
        from sgloc.sim import QUERY, TARGET

        routes = (
            make_dataset("airsim", run_dir, robot=TARGET).poses[:, :3, 3],
            make_dataset("airsim", run_dir, robot=QUERY).poses[:, :3, 3],
        )
    how = "estimated" if estimated else "ground-truth (not localized)"
    title = title or f"B placed in A's map by the {how} transform"
    return plot(target, query, T_target_query, matches, path, title, CITY_CLASSES, routes)


def _objects_only(
    console: Console, seed: int, overlap: float, descriptor: str, rejection: str, config, out: Path
) -> None:
    """The demo on the tiny object world: localize, report, draw the picture to `out`."""
    from sgloc.io.pictures import plot_aligned_maps as plot
    from sgloc.sim import make_two_robot_scene

    scene = make_two_robot_scene(seed=seed, overlap=overlap)
    console.print(f"robot A (target): {scene.target}\nrobot B (query):  {scene.query}")
    res = localize(scene.query, scene.target, descriptor, rejection, seed=seed, config=config)
    _report(console, scene.query, scene.target, res, scene.T_target_query)
    how = "estimated" if res.success else "ground-truth (not localized)"
    with staged_file(out, ours=is_sgloc_picture) as tmp:
        plot(
            scene.target, scene.query, res.transform if res.success else scene.T_target_query,
            res.matches, tmp, f"B placed in A's map by the {how} transform",
        )  # fmt: skip
    console.print(f"saved {out}")
    if not res.success:
        raise not_localized(res.reason)
