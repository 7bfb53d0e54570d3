"""`sgloc experiment NAME --dataset D`: regenerate one of the paper's tables or figures."""

from __future__ import annotations

import time
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from sgloc.cli.app import app, fail
from sgloc.cli.options import config_option, merged_settings, parse_settings, preset_option
from sgloc.cli.outputs import claim_output
from sgloc.errors import SglocError
from sgloc.evaluation.experiments import (
    EXPERIMENTS,
    OVERLAPS,
    THRESHOLDS,
    ExperimentOptions,
    run_experiment,
)


def _floats(text: str | None, default: tuple[float, ...]) -> tuple[float, ...]:
    if not text:
        return default
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError as e:
        raise fail(f"expected comma-separated numbers, got {text!r}") from e


def _names(text: str | None, default: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(x.strip() for x in text.split(",") if x.strip()) if text else default


def _settings(items: list[str]) -> dict:
    try:
        return parse_settings(items)
    except SglocError as e:
        raise fail(str(e)) from None


@app.command("experiment")
def experiment_cmd(
    ctx: typer.Context,
    name: str = typer.Argument(..., help=f"One of: {' | '.join(EXPERIMENTS)}."),
    dataset: str = typer.Option(
        "airsim-guo", "--dataset", "-d", help="airsim-guo | kitti00 | synthetic | a folder."
    ),
    trials: int = typer.Option(100, help="Trials per setting (each its own seed and pose)."),
    out: Path | None = typer.Option(
        None, help="Results folder (default results/<name>-<dataset>-<timestamp>)."
    ),
    scheduler: str | None = typer.Option(
        None,
        help="Dask scheduler address (tcp://host:8786): run the trials on that cluster "
        "(needs pip install 'sgloc\\[dask]').",
    ),
    workers: int | None = typer.Option(
        None, min=1, help="Local worker processes (default: all CPUs; 1 = in this process)."
    ),
    seed: int = typer.Option(0, min=0, help="Seed of the first trial (trial i uses seed + i)."),
    threshold: float | None = typer.Option(
        None,
        help="RANSAC threshold T_error (m) of table/overlap/matches (default: 5, or the "
        "dataset's recommended value).",
    ),
    thresholds: str | None = typer.Option(
        None, help="Comma-separated RANSAC thresholds for threshold/pr (default 1,2,...,20)."
    ),
    overlaps: str | None = typer.Option(
        None, help="Comma-separated overlap rates for overlap (default 0.1,...,0.9)."
    ),
    descriptors: str | None = typer.Option(
        None, help="Comma-separated descriptors (default histogram,fast,random_walk)."
    ),
    rejections: str | None = typer.Option(
        None, help="Comma-separated rejections (default none,neighbor)."
    ),
    descriptor: str = typer.Option("histogram", help="Descriptor of overlap and matches."),
    setting: list[str] = typer.Option(
        [],
        "--set",
        metavar="NAME=VALUE",
        help="Localizer setting NAME=VALUE (repeatable), e.g. --set tau=3; "
        "overrides the dataset's recommended settings.",
    ),
    preset: str | None = preset_option(),
    config: Path | None = config_option(),
    dataset_param: list[str] = typer.Option(
        [], "--param", metavar="NAME=VALUE", help="Dataset parameter NAME=VALUE (repeatable)."
    ),
    repeats: int = typer.Option(
        1, help="Timing repeats per trial; each stage's fastest time is kept (results equal)."
    ),
    clock: str = typer.Option(
        "cpu", help="Stage timer: cpu (this thread's CPU time; robust on a shared machine) | wall."
    ),
    from_csv: Path | None = typer.Option(
        None, help="Re-make tables and figures from an earlier run's trials.csv (no trials)."
    ),
) -> None:
    """Run one of the paper's experiments and write CSV, Markdown table, PNGs and config YAML.

    NAME: table (Table 1), threshold (Fig. 4), pr (Fig. 5), overlap (Fig. 6), matches (Fig. 7).

    Example: sgloc experiment table --dataset airsim-guo --trials 100 --out results/table1
    """
    if name not in EXPERIMENTS:
        raise fail(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)}")
    if clock not in ("cpu", "wall"):
        raise fail(f"--clock must be cpu or wall, got {clock!r}")
    if trials < 1:
        raise fail(f"--trials must be >= 1, got {trials}")
    if from_csv is not None and not from_csv.is_file():
        raise fail(f"--from-csv {from_csv}: no such file")
    if from_csv is not None:
        _no_trial_options(ctx, from_csv)
    opt = ExperimentOptions(
        trials=trials,
        first_seed=seed,
        threshold=threshold,
        thresholds=_floats(thresholds, THRESHOLDS),
        overlaps=_floats(overlaps, OVERLAPS),
        descriptors=_names(descriptors, ExperimentOptions.descriptors),
        rejections=_names(rejections, ExperimentOptions.rejections),
        descriptor=descriptor,
        settings=merged_settings(preset, config, setting),
        dataset_params=_settings(dataset_param),
        from_csv=str(from_csv) if from_csv else None,
        repeats=max(1, repeats),
        clock=clock,
    )
    if out is None:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        out = Path("results") / f"{name}-{Path(dataset).name}-{stamp}"
    given = [p for p in (Path(dataset), config, from_csv) if p is not None and p.exists()]
    claim_output(ctx, out, given)
    console = Console()
    with Progress(
        TextColumn(f"[bold]{name}[/] on {dataset}: {{task.description}}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=False,
    ) as bar:
        task = bar.add_task("trials", total=None)

        def progress(done: int, total: int, phase: str = "trials") -> None:
            bar.update(task, completed=done, total=total, description=phase)

        result = run_experiment(
            name, dataset, out, opt, workers=workers, scheduler=scheduler, progress=progress
        )
    console.print(result.markdown, markup=False, highlight=False, soft_wrap=True)
    console.print(f"results in {result.folder}/: " + ", ".join(p.name for p in result.files))


#: Options that only shape how trials run; --from-csv runs none.
_TRIAL_OPTIONS = ("workers", "scheduler", "repeats", "clock")


def _no_trial_options(ctx: typer.Context, from_csv: Path) -> None:
    """Refuse options given with --from-csv that it would ignore (it re-makes the tables from
    the CSV's trials and runs none): --trials and --seed unless they agree with the CSV."""
    from sgloc.evaluation.report import read_csv

    def typed(name: str) -> bool:  # by the enum's name: typer may bundle its own click
        return getattr(ctx.get_parameter_source(name), "name", "") == "COMMANDLINE"

    seeds = sorted({int(r["seed"]) for r in read_csv(str(from_csv)) if "seed" in r})
    csv = {"trials": len(seeds), "seed": seeds[0] if seeds else None}
    given = [n for n in _TRIAL_OPTIONS if typed(n)]
    given += [n for n in ("trials", "seed") if typed(n) and ctx.params[n] != csv[n]]
    if given:
        flags = ", ".join("--" + n for n in given)
        raise fail(
            f"{flags}: --from-csv runs no trials (its {from_csv.name} holds {csv['trials']} "
            f"per setting from seed {csv['seed']}); drop {'it' if len(given) == 1 else 'them'}, "
            "or drop --from-csv to run new trials."
        )
