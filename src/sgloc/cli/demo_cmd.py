"""`sgloc demo`: the whole pipeline from pixels to transform on the rendered synthetic city.

First run: generate a city and two robots' routes, render both robots' semantic + depth images
into an Airsim-layout run under the cache folder (~/.cache/sgloc/demo/<key>); later runs reuse
it. Then read the run back with the `airsim` loader, extract both graphs, localize robot B
(query) in robot A's map (target), print the error against the ground truth and save a PNG of
the two maps aligned with the final matches (`sgloc.sim.demo`). `--objects-only` runs the tiny
object world instead (no rendering).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from sgloc.cli.app import app, compile_note, fail, not_localized
from sgloc.cli.options import localizer_config
from sgloc.cli.outputs import claim_output
from sgloc.cli.progress import progress_bar
from sgloc.geometry import transform_error
from sgloc.io.files import is_sgloc_picture
from sgloc.io.pictures import picture_path

if TYPE_CHECKING:
    from sgloc.sim.demo import DemoResult

#: Where `sgloc demo` saves its picture unless told otherwise (relative to the current folder).
DEFAULT_OUT = Path("results") / "demo" / "aligned_maps.png"

Seed = Annotated[int, typer.Option(min=0, help="Seed of the city, the routes and RANSAC.")]
Overlap = Annotated[float, typer.Option(help="Fraction of the two robots' routes they share.")]
Width = Annotated[int, typer.Option(help="Image width (px); fx = width / 2.")]
Height = Annotated[int, typer.Option(help="Image height (px).")]
Length = Annotated[float, typer.Option(help="Route length of each robot (m).")]
Step = Annotated[float, typer.Option(help="Distance between frames (m).")]
Descriptor = Annotated[str, typer.Option(
    help="distance_histogram | triangles | histogram | random_walk | fast"
)]
Rejection = Annotated[str, typer.Option(help="neighbor | none")]
CacheDir = Annotated[Path | None, typer.Option(
    help="Where rendered runs are kept (default $SGLOC_CACHE or ~/.cache/sgloc)."
)]
Refresh = Annotated[bool, typer.Option(help="Render again even if the run is cached.")]
PaperDefaults = Annotated[bool, typer.Option(
    help="Localize with the paper's defaults only (no city class weights)."
)]
Out = Annotated[str, typer.Option(
    metavar="PATH",
    help="Picture of the aligned maps: .png, .jpg, .pdf, .svg, ... (the format follows the "
    "ending), or a folder (existing, or ending in '/') to get aligned_maps.png in it. Its "
    "folder is created; an existing picture is replaced only if sgloc drew it.",
)]
ObjectsOnly = Annotated[bool, typer.Option(
    "--objects-only", help="Use the tiny object world (no rendering, instant)."
)]
Preset = Annotated[str | None, typer.Option(
    "--preset", help="Named localizer settings (default: city; see sgloc.pipeline.presets)."
)]
Setting = Annotated[list[str] | None, typer.Option(
    "--set", metavar="NAME=VALUE", help="A setting NAME=VALUE (repeatable)."
)]


@app.command("demo")
def demo_cmd(
    ctx: typer.Context,
    seed: Seed = 0,
    overlap: Overlap = 0.5,
    width: Width = 320,
    height: Height = 180,
    length: Length = 400.0,
    step: Step = 2.0,
    descriptor: Descriptor = "distance_histogram",
    rejection: Rejection = "neighbor",
    cache_dir: CacheDir = None,
    refresh: Refresh = False,
    paper_defaults: PaperDefaults = False,
    out: Out = str(DEFAULT_OUT),
    objects_only: ObjectsOnly = False,
    preset: Preset = None,
    setting: Setting = None,
) -> None:
    """Render a synthetic city seen by two robots, build their semantic graphs, localize one in
    the other and compare with the ground truth.

    Example: sgloc demo --overlap 0.3 --descriptor fast --out demo.png
    """
    if not 0.0 <= overlap <= 1.0:
        raise fail(f"--overlap must be in [0, 1], got {overlap}.")
    picture = claim_output(ctx, picture_path(out, DEFAULT_OUT.name), [cache_dir], folder=False,
                           ours=is_sgloc_picture)
    from sgloc.sim.demo import city_demo, objects_demo  # deferred: the simulator (PIL, ...)

    console = Console()
    if objects_only:  # the object world's own settings: the defaults
        done = objects_demo(seed, overlap, localizer_config(preset, None, setting), descriptor,
                            rejection, picture)
    else:
        config = localizer_config(preset or ("paper" if paper_defaults else "city"), None, setting)
        demo = city_demo(_run(seed, overlap, width, height, length, step), config, descriptor,
                         rejection)  # checked before any display
        with _bar(console) as progress:
            done = demo(cache_dir, refresh, picture, progress, console.print)
    _print(console, done, picture)


def _run(seed: int, overlap: float, width: int, height: int, length: float, step: float):
    """The synthetic run's settings (`sgloc.sim.run.SyntheticRunConfig`)."""
    from sgloc.sim.run import SyntheticRunConfig

    return SyntheticRunConfig(seed=seed, overlap=overlap, width=width, height=height,
                              length=length, step=step)


def _bar(console: Console):
    columns = (TextColumn("{task.description:<28}"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn(), TimeRemainingColumn())
    return progress_bar(*columns, console=console, start=True, per_phase=True)


def _print(console: Console, done: DemoResult, out: Path) -> None:
    """The demo's report and picture; exit 1 (not localized) when B was not placed."""
    query, target, res = done.query, done.target, done.result
    if done.run_dir is None:
        console.print(f"robot A (target): {target}\nrobot B (query):  {query}")
    table = Table(show_header=False, box=None)
    table.add_row("robot A (target)", f"{len(target)} vertices, {target.n_edges} edges")
    table.add_row("robot B (query)", f"{len(query)} vertices, {query.n_edges} edges")
    table.add_row(
        "matches",
        f"{len(res.candidates)} candidates, {len(res.survivors)} after rejection, "
        f"{len(res.matches)} final",
    )
    table.add_row("time", f"{res.timings['total'] * 1e3:.1f} ms")
    if note := compile_note():
        table.add_row("", note)
    if res.accepted:
        te, re = transform_error(res.transform, done.truth)
        table.add_row("error vs ground truth", f"translation {te:.2f} m, rotation {re:.2f} deg")
    console.print(table)
    console.print(f"saved {out}")
    if not res.accepted:
        raise not_localized(res.reason)
