"""An experiment from options to results folder: the names and number lists parsed, the options
checked (an option `--from-csv` would ignore is refused), the default results folder named, and
the run (`sgloc.evaluation.experiments.run_experiment`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sgloc.errors import SglocError
from sgloc.evaluation.experiments import (
    EXPERIMENTS,
    OVERLAPS,
    THRESHOLDS,
    ExperimentOptions,
    ExperimentOutput,
    run_experiment,
)

#: Options that only shape how trials run; --from-csv runs none.
TRIAL_OPTIONS = ("workers", "scheduler", "repeats", "clock")

__all__ = ["EXPERIMENTS", "TRIAL_OPTIONS", "ExperimentJob", "experiment_job"]


@dataclass(frozen=True)
class ExperimentJob:
    """A checked experiment: `name` on `dataset` with `options`, written to `out`."""

    name: str
    dataset: str
    options: ExperimentOptions
    out: Path

    def run(self, workers: int | None = None, scheduler: Any = None,
            progress: Callable[[int, int, str], None] | None = None) -> ExperimentOutput:
        """Run the trials (local processes, or the Dask `scheduler`) and write the results
        folder (complete or not at all); `progress(done, total, phase)` follows the trials."""
        return run_experiment(self.name, self.dataset, self.out, self.options, workers=workers,
                              scheduler=scheduler, progress=progress)


def experiment_job(
    name: str,
    dataset: str,
    *,
    trials: int = 100,
    seed: int = 0,
    threshold: float | None = None,
    thresholds: str | None = None,
    overlaps: str | None = None,
    descriptors: str | None = None,
    rejections: str | None = None,
    descriptor: str = "histogram",
    settings: Callable[[], dict[str, Any]] | Mapping[str, Any] | None = None,
    params: Sequence[str] = (),
    repeats: int = 1,
    clock: str = "cpu",
    from_csv: str | Path | None = None,
    typed: Mapping[str, Any] | None = None,
    out: str | Path | None = None,
) -> ExperimentJob:
    """The checked experiment `name` on `dataset`: `thresholds`, `overlaps`, `descriptors`,
    `rejections` comma-separated (None: the defaults); `settings` the localizer settings (or
    the function reading them, called after the options' own checks); `params` the data set's
    NAME=VALUE items; `from_csv` re-makes the tables from an earlier run's trials.csv, refusing
    the `typed` options (given on the command line) it would ignore; `out` default
    results/<name>-<dataset>-<timestamp>. SglocError on a bad option."""
    from sgloc.io.settings_file import parse_assignments

    _check(name, clock, trials, from_csv)
    if from_csv is not None:
        _no_trial_options(Path(from_csv), name, typed or {})
    opt = ExperimentOptions(
        trials=trials, first_seed=seed, threshold=threshold,
        thresholds=_floats(thresholds, THRESHOLDS), overlaps=_floats(overlaps, OVERLAPS),
        descriptors=_names(descriptors, ExperimentOptions.descriptors),
        rejections=_names(rejections, ExperimentOptions.rejections), descriptor=descriptor,
        settings=dict(settings() if callable(settings) else settings or {}),
        dataset_params=parse_assignments(params), from_csv=str(from_csv) if from_csv else None,
        repeats=max(1, repeats), clock=clock,
    )  # fmt: skip
    if out is None:
        out = Path("results") / f"{name}-{Path(dataset).name}-{time.strftime('%Y%m%d-%H%M%S')}"
    return ExperimentJob(name, dataset, opt, Path(out))


def _check(name: str, clock: str, trials: int, from_csv: str | Path | None) -> None:
    if name not in EXPERIMENTS:
        raise SglocError(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)}")
    if clock not in ("cpu", "wall"):
        raise SglocError(f"--clock must be cpu or wall, got {clock!r}")
    if trials < 1:
        raise SglocError(f"--trials must be >= 1, got {trials}")
    if from_csv is not None and not Path(from_csv).is_file():
        raise SglocError(f"--from-csv {from_csv}: no such file")


def _floats(text: str | None, default: tuple[float, ...]) -> tuple[float, ...]:
    if not text:
        return default
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise SglocError(f"expected comma-separated numbers, got {text!r}") from None


def _names(text: str | None, default: Sequence[str]) -> tuple[str, ...]:
    return tuple(x.strip() for x in text.split(",") if x.strip()) if text else tuple(default)


def _no_trial_options(from_csv: Path, name: str, typed: Mapping[str, Any]) -> None:
    """Refuse a file that is not an experiment's trials.csv, and options typed with --from-csv
    that it would ignore (it re-makes the tables from the CSV's trials and runs none):
    TRIAL_OPTIONS, and --trials and --seed unless they agree with the CSV."""
    from sgloc.evaluation.experiments import read_trials

    seeds = sorted({int(r["seed"]) for r in read_trials(from_csv, name)})
    csv = {"trials": len(seeds), "seed": seeds[0] if seeds else None}
    given = [n for n in TRIAL_OPTIONS if n in typed]
    given += [n for n in ("trials", "seed") if n in typed and typed[n] != csv[n]]
    if given:
        flags = ", ".join("--" + n for n in given)
        raise SglocError(
            f"{flags}: --from-csv runs no trials (its {from_csv.name} holds {csv['trials']} "
            f"per setting from seed {csv['seed']}); drop {'it' if len(given) == 1 else 'them'}, "
            "or drop --from-csv to run new trials."
        )
