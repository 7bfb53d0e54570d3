"""`sgloc experiment NAME --dataset D`: regenerate one of the paper's tables or figures."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn

from sgloc.cli.app import app
from sgloc.cli.options import ConfigFile, Preset, merged_settings
from sgloc.cli.outputs import claim_output
from sgloc.cli.progress import progress_bar

#: The experiments' names as the help shows them: sgloc.experiments.EXPERIMENTS, written out
#: because importing the experiments (the evaluation harness, scipy.ndimage, ...) would slow the
#: start of every command (tests/test_cli.py checks that the two agree).
NAMES = ("table", "threshold", "pr", "overlap", "matches")

Name = Annotated[str, typer.Argument(metavar="NAME", help=f"One of: {' | '.join(NAMES)}.")]
Dataset = Annotated[str, typer.Option(
    "--dataset", "-d", help="airsim-guo | kitti00 | synthetic | a folder."
)]
Trials = Annotated[int, typer.Option(help="Trials per setting (each its own seed and pose).")]
Out = Annotated[Path | None, typer.Option(
    help="Results folder (default results/<name>-<dataset>-<timestamp>)."
)]
Scheduler = Annotated[str | None, typer.Option(
    help="Dask scheduler address (tcp://host:8786): run the trials on that cluster "
    "(needs pip install 'sgloc\\[dask]').",
)]
Workers = Annotated[int | None, typer.Option(
    min=1, help="Local worker processes (default: all CPUs; 1 = in this process)."
)]
Seed = Annotated[int, typer.Option(
    min=0, help="Seed of the first trial (trial i uses seed + i)."
)]
Threshold = Annotated[float | None, typer.Option(
    help="RANSAC threshold T_error (m) of table/overlap/matches (default: 5, or the "
    "dataset's recommended value).",
)]
Thresholds = Annotated[str | None, typer.Option(
    help="Comma-separated RANSAC thresholds for threshold/pr (default 1,2,...,20)."
)]
Overlaps = Annotated[str | None, typer.Option(
    help="Comma-separated overlap rates for overlap (default 0.1,...,0.9)."
)]
Descriptors = Annotated[str | None, typer.Option(
    help="Comma-separated descriptors (default histogram,fast,random_walk)."
)]
Rejections = Annotated[str | None, typer.Option(
    help="Comma-separated rejections (default none,neighbor)."
)]
Descriptor = Annotated[str, typer.Option(help="Descriptor of overlap and matches.")]
Setting = Annotated[list[str] | None, typer.Option(
    "--set", metavar="NAME=VALUE",
    help="Localizer setting NAME=VALUE (repeatable), e.g. --set tau=3; "
    "overrides the dataset's recommended settings.",
)]
Param = Annotated[list[str] | None, typer.Option(
    "--param", metavar="NAME=VALUE", help="Dataset parameter NAME=VALUE (repeatable)."
)]
Repeats = Annotated[int, typer.Option(
    help="Timing repeats per trial; each stage's fastest time is kept (results equal)."
)]
Clock = Annotated[str, typer.Option(
    help="Stage timer: cpu (this thread's CPU time; robust on a shared machine) | wall."
)]
FromCsv = Annotated[Path | None, typer.Option(
    help="Re-make tables and figures from an earlier run's trials.csv (no trials)."
)]


@app.command("experiment")
def experiment_cmd(
    ctx: typer.Context,
    name: Name,
    dataset: Dataset = "airsim-guo",
    trials: Trials = 100,
    out: Out = None,
    scheduler: Scheduler = None,
    workers: Workers = None,
    seed: Seed = 0,
    threshold: Threshold = None,
    thresholds: Thresholds = None,
    overlaps: Overlaps = None,
    descriptors: Descriptors = None,
    rejections: Rejections = None,
    descriptor: Descriptor = "histogram",
    setting: Setting = None,
    preset: Preset = None,
    config: ConfigFile = None,
    dataset_param: Param = None,
    repeats: Repeats = 1,
    clock: Clock = "cpu",
    from_csv: FromCsv = None,
) -> None:
    """Run one of the paper's experiments and write CSV, Markdown table, PNGs and config YAML.

    NAME: table (Table 1), threshold (Fig. 4), pr (Fig. 5), overlap (Fig. 6), matches (Fig. 7).

    Example: sgloc experiment table --dataset airsim-guo --trials 100 --out results/table1
    """
    job = _job(
        ctx, name, dataset, trials=trials, seed=seed, threshold=threshold, thresholds=thresholds,
        overlaps=overlaps, descriptors=descriptors, rejections=rejections, descriptor=descriptor,
        settings=lambda: merged_settings(preset, config, setting), params=dataset_param or [],
        repeats=repeats, clock=clock, from_csv=from_csv, out=out,
    )
    claim_output(ctx, job.out, [p for p in (Path(dataset), config, from_csv) if p and p.exists()])
    with _bar(name, dataset) as progress:
        result = job.run(workers=workers, scheduler=scheduler, progress=progress)
    _print(result)


def _job(ctx: typer.Context, name: str, dataset: str, **options: Any):
    """The experiment's job (`sgloc.experiments.experiment_job`, imported when a command runs
    one) with the trial options given on the command line."""
    from sgloc.experiments import experiment_job

    return experiment_job(name, dataset, typed=_typed(ctx), **options)


def _typed(ctx: typer.Context) -> dict[str, Any]:
    """The trial options given on the command line, by name (`--from-csv` refuses them)."""
    from sgloc.experiments.job import TRIAL_OPTIONS

    def typed(name: str) -> bool:  # by the enum's name: typer may bundle its own click
        return getattr(ctx.get_parameter_source(name), "name", "") == "COMMANDLINE"

    return {n: ctx.params[n] for n in (*TRIAL_OPTIONS, "trials", "seed") if typed(n)}


def _bar(name: str, dataset: str):
    columns = (TextColumn(f"[bold]{name}[/] on {dataset}: {{task.description}}"), BarColumn(),
               MofNCompleteColumn(), TimeRemainingColumn())
    return progress_bar(*columns, console=Console(), first="trials")


def _print(result) -> None:
    console = Console()
    console.print(result.markdown, markup=False, highlight=False, soft_wrap=True)
    console.print(f"results in {result.folder}/: " + ", ".join(p.name for p in result.files))
