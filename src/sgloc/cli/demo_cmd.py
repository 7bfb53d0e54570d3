"""`sgloc demo`: the whole pipeline from pixels to transform on the rendered synthetic city.

First run: generate a city and two robots' routes, render both robots' semantic + depth images
into an Airsim-layout run under the cache folder (~/.cache/sgloc/demo/<key>); later runs reuse
it. Then read the run back with the `airsim` loader, extract both graphs, localize robot B
(query) in robot A's map (target), print the error against the ground truth and save a PNG of
the two maps aligned with the final matches. `--objects-only` runs the tiny object world
instead (no rendering).
"""

from __future__ import annotations

import os
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

from sgloc.cli.app import app, fail
from sgloc.geometry import apply, transform_error
from sgloc.graph import SemanticGraph
from sgloc.localizer import LocalizationResult, localize


def default_cache_dir() -> Path:
    """$SGLOC_CACHE, else $XDG_CACHE_HOME/sgloc, else ~/.cache/sgloc."""
    if os.environ.get("SGLOC_CACHE"):
        return Path(os.environ["SGLOC_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "sgloc"


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
    seed: int = typer.Option(0, min=0, help="Seed of the city, the routes and RANSAC."),
    overlap: float = typer.Option(0.5, help="Fraction of the two robots' routes they share."),
    width: int = typer.Option(320, help="Image width (px); fx = width / 2."),
    height: int = typer.Option(180, help="Image height (px)."),
    length: float = typer.Option(400.0, help="Route length of each robot (m)."),
    step: float = typer.Option(2.0, help="Distance between frames (m)."),
    descriptor: str = typer.Option("histogram", help="histogram | random_walk | fast"),
    rejection: str = typer.Option("neighbor", help="neighbor | none"),
    cache_dir: Path | None = typer.Option(
        None, help="Where rendered runs are kept (default $SGLOC_CACHE or ~/.cache/sgloc)."
    ),
    refresh: bool = typer.Option(False, help="Render again even if the run is cached."),
    paper_defaults: bool = typer.Option(
        False, help="Localize with the paper's defaults only (no city class weights)."
    ),
    out: Path = typer.Option(Path("sgloc_demo.png"), help="PNG of the aligned maps."),
    objects_only: bool = typer.Option(
        False, "--objects-only", help="Use the tiny object world (no rendering, instant)."
    ),
) -> None:
    """Render a synthetic city seen by two robots, build their semantic graphs, localize one in
    the other and compare with the ground truth.

    Example: sgloc demo --overlap 0.3 --descriptor fast --out demo.png
    """
    console = Console()
    if not 0.0 <= overlap <= 1.0:
        raise fail(f"--overlap must be in [0, 1], got {overlap}.")
    if objects_only:
        _objects_only(console, seed, overlap, descriptor, rejection)
        return
    from sgloc.config import LocalizerConfig

    LocalizerConfig().with_overrides(descriptor=descriptor, rejection=rejection)  # fail early
    from sgloc.datasets import make_dataset
    from sgloc.extraction import ExtractionConfig, build_graph
    from sgloc.sim import QUERY, TARGET, SyntheticRunConfig, read_ground_truth
    from sgloc.sim.run import SyntheticRun, city_localizer_config

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
            ds = make_dataset("airsim", run_dir, robot=robot)
            task = progress.add_task(f"extracting {robot}", total=len(ds))
            graphs[robot] = build_graph(
                ds.frames(), ext, name=robot, progress=lambda _f, t=task: progress.advance(t)
            )
    T_gt = read_ground_truth(run_dir)
    target, query = graphs[TARGET], graphs[QUERY]
    config = None if paper_defaults else city_localizer_config()
    res = localize(query, target, descriptor, rejection, seed=seed, config=config)
    _report(console, query, target, res, T_gt)
    T_plot = res.transform if res.success else T_gt
    path = plot_aligned_maps(target, query, T_plot, res.matches, out, run_dir, res.success)
    console.print(f"saved {path}")
    if not res.success:
        raise fail(f"not localized: {res.reason}")


def _report(console, query, target, res: LocalizationResult, T_gt: np.ndarray) -> None:
    table = Table(show_header=False, box=None)
    table.add_row("robot A (target)", f"{len(target)} vertices, {target.n_edges} edges")
    table.add_row("robot B (query)", f"{len(query)} vertices, {query.n_edges} edges")
    table.add_row(
        "matches",
        f"{len(res.candidates)} candidates, {len(res.survivors)} after rejection, "
        f"{len(res.matches)} final",
    )
    table.add_row("time", f"{res.timings['total'] * 1e3:.1f} ms")
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
) -> Path:
    """Top view of robot A's map and robot B's map placed by `T_target_query`, vertices
    coloured by class, final matches as lines (and the two routes when `run_dir` is given)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    from sgloc.classes import AIRSIM_COLORS
    from sgloc.sim.city import CITY_CLASSES

    t = target.positions
    q = apply(T_target_query, query.positions)
    # the map frames are AirSim body frames (x forward, y right, z down): seen from above,
    # y runs right and x up
    both = np.concatenate([t, q])
    w, h = np.ptp(both[:, 1]) + 20.0, np.ptp(both[:, 0]) + 20.0
    fig, ax = plt.subplots(figsize=(float(np.clip(6.0 * w / h, 4.0, 9.0)), 6.0))
    colours = AIRSIM_COLORS / 255.0
    ax.scatter(t[:, 1], t[:, 0], s=9, c=colours[target.labels % len(colours)], marker="o")
    ax.scatter(q[:, 1], q[:, 0], s=14, c=colours[query.labels % len(colours)], marker="x")
    if run_dir is not None:
        from sgloc.datasets import make_dataset
        from sgloc.sim import QUERY, TARGET

        pa = make_dataset("airsim", run_dir, robot=TARGET).poses[:, :3, 3]
        pb = apply(T_target_query, make_dataset("airsim", run_dir, robot=QUERY).poses[:, :3, 3])
        ax.plot(pa[:, 1], pa[:, 0], "-", c="0.3", lw=1.0, label="robot A route (target)")
        ax.plot(pb[:, 1], pb[:, 0], "--", c="tab:purple", lw=1.0, label="robot B route (query)")
    m = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    if len(m):
        segs = np.stack([q[m[:, 0]][:, [1, 0]], t[m[:, 1]][:, [1, 0]]], axis=1)
        ax.add_collection(LineCollection(segs, colors="tab:green", lw=2.0, alpha=0.9))
        ax.scatter(
            t[m[:, 1], 1],
            t[m[:, 1], 0],
            s=45,
            facecolors="none",
            edgecolors="tab:green",
            linewidths=1.2,
            label="final matches",
        )
    present = np.unique(np.concatenate([target.labels, query.labels]))
    for c in present[present < len(CITY_CLASSES)]:
        ax.scatter([], [], s=12, c=[colours[c]], label=CITY_CLASSES[c])
    ax.legend(fontsize=6, loc="best", markerscale=1.0, ncol=2)
    how = "estimated" if estimated else "ground-truth (not localized)"
    ax.set_title(
        f"A's map (o) and B's map (x) placed by the {how} transform; {len(m)} final matches",
        fontsize=8,
    )
    ax.set_aspect("equal")
    ax.set_xlabel("y (m)")
    ax.set_ylabel("x (m)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _objects_only(console: Console, seed: int, overlap: float, descriptor: str, rejection: str):
    from sgloc.sim import make_two_robot_scene

    scene = make_two_robot_scene(seed=seed, overlap=overlap)
    console.print(f"robot A (target): {scene.target}\nrobot B (query):  {scene.query}")
    res = localize(scene.query, scene.target, descriptor, rejection, seed=seed)
    console.print(
        f"candidates {len(res.candidates)}  after rejection {len(res.survivors)}  "
        f"final matches {len(res.matches)}  in {res.timings['total'] * 1e3:.1f} ms"
    )
    if not res.success:
        raise fail(f"not localized: {res.reason}")
    te, re = transform_error(res.transform, scene.T_target_query)
    console.print(f"error against ground truth: translation {te:.2f} m, rotation {re:.2f} deg")
