"""Grids of trials (`Sweep`) and the paper's experiments by name, each writing a results folder.

`run_experiment(name, dataset, ...)` builds the sweep, runs its trials (serially, on local
processes or on a Dask cluster), and writes into `out`: `trials.csv` (one row per trial),
`table.md` (Markdown summary), PNG figures, and `config.yaml` (the exact sweep and localizer
configs, software version and git commit).

Names: table (Table 1), threshold (Fig. 4 + error distribution at 5 m), pr (Fig. 5),
overlap (Fig. 6), matches (Fig. 7).
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.errors import DatasetError, UnknownNameError
from sgloc.evaluation.metrics import FAILURE_M, T_P, correct_matches
from sgloc.evaluation.pairs import make_pair_source
from sgloc.evaluation.report import (
    fmt,
    markdown_table,
    read_csv,
    summarize,
    sweep_markdown,
    table1_markdown,
    write_config_yaml,
    write_csv,
)
from sgloc.evaluation.trials import (
    LOCALIZER_STREAM,
    TrialTask,
    prepare_tasks,
    run_prepare,
    run_trials,
)
from sgloc.io.files import check_regular_file, naming, staged_folder
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.localizer import Localizer

EXPERIMENTS = ("table", "threshold", "pr", "overlap", "matches")
DESCRIPTOR_NAMES = ("histogram", "fast", "random_walk")
REJECTION_NAMES = ("none", "neighbor")
#: RANSAC thresholds T_error of Fig. 4-5 (metres).
THRESHOLDS = tuple(float(x) for x in range(1, 21))
OVERLAPS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)


@dataclass
class Sweep:
    """A grid of trials over localizer settings and pair-source parameters. Trial i of every
    cell uses seed `first_seed + i`, so cells are compared on the same pairs and initial
    transforms (paired comparisons), and any cell can be re-run alone.

    dataset / dataset_params: the pair source and its fixed parameters.
    settings: fixed localizer settings (flat names, as `localize(**settings)` takes them).
    axes: localizer settings to sweep, name -> values (e.g. {"ransac_threshold": [1, 2]}).
    dataset_axes: pair-source parameters to sweep (e.g. {"overlap": [0.1, 0.3]}).
    trials: trials per grid cell; first_seed: seed of trial 0.
    repeats: timing repeats per trial (each stage's fastest is kept; results are identical).
    clock: "cpu" (stage CPU time, default) or "wall" (see `TrialTask`).
    """

    dataset: str
    dataset_params: dict[str, Any] = field(default_factory=dict)
    settings: dict[str, Any] = field(default_factory=dict)
    axes: dict[str, Sequence[Any]] = field(default_factory=dict)
    dataset_axes: dict[str, Sequence[Any]] = field(default_factory=dict)
    trials: int = 100
    first_seed: int = 0
    T_p: float = T_P
    failure_m: float = FAILURE_M
    repeats: int = 1
    clock: str = "cpu"

    def cells(self) -> list[tuple[dict[str, Any], dict[str, Any]]]:
        """Every (localizer settings, dataset parameters) of the grid, in a fixed order."""
        out = []
        for combo in itertools.product(*self.dataset_axes.values(), *self.axes.values()):
            point = dict(zip([*self.dataset_axes, *self.axes], combo, strict=True))
            settings = {**self.settings, **{k: point[k] for k in self.axes}}
            params = {**self.dataset_params, **{k: point[k] for k in self.dataset_axes}}
            out.append((settings, params))
        return out

    def tasks(self) -> list[TrialTask]:
        """The trials of the whole grid, seed-major: trial i of every cell, then trial i + 1.
        Interleaving the cells exposes them all alike to load that drifts during a run (on a
        shared machine even CPU times drift by tens of percent), so their times compare."""
        cells = [
            (config_for(settings).to_dict(), params, {k: params[k] for k in self.dataset_axes})
            for settings, params in self.cells()
        ]
        shared = {k: getattr(self, k) for k in ("T_p", "failure_m", "repeats", "clock")}
        return [
            TrialTask(self.dataset, cfg, self.first_seed + i, params, tags, **shared)
            for i in range(self.trials)
            for cfg, params, tags in cells
        ]


def _stage_params() -> set[str]:
    """Names of every registered descriptor's and rejector's parameters."""
    from sgloc.descriptors import DESCRIPTORS
    from sgloc.rejection import REJECTORS

    stages = [*DESCRIPTORS.values(), *REJECTORS.values()]
    return {f.name for cls in stages for f in dataclasses.fields(cls)}


def config_for(settings: dict[str, Any]) -> LocalizerConfig:
    """The LocalizerConfig of flat `settings`; a parameter of another descriptor or rejector
    than the cell's (e.g. tau when rejection is none) is left out, a misspelt one still raises."""
    stage = {k: settings[k] for k in ("descriptor", "rejection") if k in settings}
    cfg = LocalizerConfig().with_overrides(**stage)
    for key, value in settings.items():
        if key in stage:
            continue
        try:
            cfg = cfg.with_overrides(**{key: value})
        except UnknownNameError:
            if key not in _stage_params():
                raise
    return cfg


@dataclass
class ExperimentOptions:
    """Options of an experiment (the CLI's flags)."""

    trials: int = 100
    first_seed: int = 0
    threshold: float | None = None
    thresholds: Sequence[float] = THRESHOLDS
    overlaps: Sequence[float] = OVERLAPS
    descriptors: Sequence[str] = DESCRIPTOR_NAMES
    rejections: Sequence[str] = REJECTION_NAMES
    descriptor: str = "histogram"
    settings: dict[str, Any] = field(default_factory=dict)
    dataset_params: dict[str, Any] = field(default_factory=dict)
    from_csv: str | None = None
    repeats: int = 1
    clock: str = "cpu"


@dataclass
class ExperimentOutput:
    """What an experiment wrote: the folder, its files, and the Markdown table."""

    folder: Path
    files: list[Path]
    markdown: str


def resolved_options(dataset: str, opt: ExperimentOptions) -> ExperimentOptions:
    """Options with the dataset's recommended localizer settings filled in: the pair source's
    `localizer_settings` (e.g. a 2 m RANSAC threshold for KITTI's precise LiDAR centroids)
    under the options' own settings; threshold defaults to theirs, else 5 m (Table 1)."""
    src = make_pair_source(dataset, **opt.dataset_params)
    defaults = dict(getattr(src, "localizer_settings", {}))
    thr = defaults.pop("ransac_threshold", 5.0)
    return dataclasses.replace(
        opt,
        threshold=float(opt.threshold if opt.threshold is not None else thr),
        settings={**defaults, **opt.settings},
    )


def make_sweep(name: str, dataset: str, opt: ExperimentOptions) -> Sweep:
    """The sweep behind experiment `name` (matches has none: it is a single trial): table
    (Table 1) every descriptor x rejection at one RANSAC threshold; threshold and pr (Fig. 4-5)
    the same over the thresholds T_error; overlap (Fig. 6) the rejections over the pair
    source's `overlap` parameter."""
    opt = resolved_options(dataset, opt)
    thr = {"ransac_threshold": opt.threshold}
    by_setting = {"descriptor": list(opt.descriptors), "rejection": list(opt.rejections)}
    dataset_axes = {}
    if name == "table":
        settings, axes = {**thr, **opt.settings}, by_setting
    elif name in ("threshold", "pr"):
        settings = dict(opt.settings)
        axes = {**by_setting, "ransac_threshold": [float(t) for t in opt.thresholds]}
    elif name == "overlap":
        settings = {"descriptor": opt.descriptor, **thr, **opt.settings}
        axes = {"rejection": list(opt.rejections)}
        dataset_axes = {"overlap": [float(o) for o in opt.overlaps]}
    else:
        raise _unknown(name)
    return Sweep(
        dataset, dict(opt.dataset_params), settings, axes, dataset_axes, opt.trials,
        opt.first_seed, repeats=opt.repeats, clock=opt.clock,
    )  # fmt: skip


def _unknown(name: str) -> UnknownNameError:
    return UnknownNameError(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)}.")


def _ticker(progress: Callable | None, total: int, phase: str) -> Callable[[int], None]:
    """A `run_trials` progress callback that reports (done, total, phase) to `progress`, starting
    with (0, total, phase)."""
    done = itertools.count(1)  # run_trials ticks one trial at a time
    if progress:
        progress(0, total, phase)
    return (lambda n: progress(next(done), total, phase)) if progress else (lambda n: None)


def run_experiment(
    name: str,
    dataset: str,
    out: str | Path,
    options: ExperimentOptions | None = None,
    workers: int | None = None,
    scheduler: Any = None,
    progress: Callable[[int, int, str], None] | None = None,
) -> ExperimentOutput:
    """Run experiment `name` on `dataset` and write its results folder `out`.

    progress(done, total, phase) is called as trials (and world preparations) finish.
    """
    if name not in EXPERIMENTS:
        raise _unknown(name)
    out = Path(out)
    with staged_folder(out) as stage:  # the folder appears complete or not at all
        result = _run_into(name, dataset, stage, options, workers, scheduler, progress)
    return dataclasses.replace(
        result, folder=out, files=[out / p.relative_to(stage) for p in result.files]
    )


def _run_into(
    name: str,
    dataset: str,
    folder: Path,
    options: ExperimentOptions | None,
    workers: int | None,
    scheduler: Any,
    progress: Callable[[int, int, str], None] | None,
) -> ExperimentOutput:
    """run_experiment's work, written into `folder`."""
    opt = resolved_options(dataset, options or ExperimentOptions())  # fails early on a bad name
    if name == "matches":
        return _matches(dataset, folder, opt)
    sweep = make_sweep(name, dataset, opt)
    tasks = sweep.tasks()
    t0 = time.perf_counter()
    if opt.from_csv:
        rows = read_trials(opt.from_csv, name)
    else:
        prep = prepare_tasks(tasks)  # e.g. render each synthetic world once, in parallel
        if prep:
            tick = _ticker(progress, len(prep), "preparing worlds")
            run_trials(prep, workers, scheduler, tick, fn=run_prepare)
        rows = run_trials(tasks, workers, scheduler, _ticker(progress, len(tasks), "trials"))
    wall = time.perf_counter() - t0
    files = [write_csv(rows, folder / "trials.csv")]
    md, figs = _outputs(name, dataset, rows, folder, opt)
    files += figs
    if opt.from_csv:
        seeds = sorted({int(r["seed"]) for r in rows})
        run = f"seeds {seeds[0]}-{seeds[-1]}; tables and figures re-made from {opt.from_csv}"
    else:
        last = sweep.first_seed + sweep.trials - 1
        run = f"{sweep.trials} per cell, seeds {sweep.first_seed}-{last}; wall time {wall:.0f} s"
    md = f"# {name} on {dataset}\n\n{len(rows)} trials ({run}).\n\n" + md
    with naming(folder / "table.md"):
        (folder / "table.md").write_text(md)
    files.append(folder / "table.md")
    cfg_path = folder / "config.yaml"
    if not (opt.from_csv and cfg_path.exists()):  # keep the config of the run that made the CSV
        configs = {_cell_name(s, p): config_for(s).to_dict() for s, p in sweep.cells()}
        exp = {"name": name, **dataclasses.asdict(sweep), "workers": workers}
        exp["scheduler"] = str(scheduler)
        if opt.from_csv:
            exp["from_csv"] = opt.from_csv
        write_config_yaml(cfg_path, exp, configs)
    files.append(cfg_path)
    return ExperimentOutput(folder, files, md)


#: The columns every experiment's trials.csv holds that its tables and figures read.
TRIAL_COLUMNS = ("seed", "descriptor", "rejection", "ransac_threshold", "localized", "failed")


def read_trials(path: str | Path, name: str) -> list[dict[str, Any]]:
    """The trial rows of an earlier run's trials.csv (for `--from-csv`); DatasetError naming the
    file when it is not one (another table, no rows, a column missing or not a number)."""
    what = "trials.csv of an earlier `sgloc experiment` run"
    fix = f"give the trials.csv that `sgloc experiment {name} --out DIR` wrote in DIR"
    check_regular_file(path, what, DatasetError)
    try:
        rows = read_csv(path)
    except (UnicodeDecodeError, csv.Error) as e:
        raise DatasetError(f"{path}: not a {what} ({e}); {fix}.") from None
    needed = (*TRIAL_COLUMNS, "overlap") if name == "overlap" else TRIAL_COLUMNS
    missing = [c for c in needed if c not in rows[0]] if rows else []
    if not rows or missing:
        held = f"no {', '.join(missing)} column" if rows else "no trial rows"
        raise DatasetError(f"{path}: not a {what} ({held}); {fix}.")
    for i, r in enumerate(rows, start=2):
        numbers = (r["seed"], r["ransac_threshold"], r.get("overlap", 0))
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in numbers):
            raise DatasetError(f"{path}, line {i}: seed, ransac_threshold or overlap is not a "
                               f"number; {fix}.")
    return rows


def _cell_name(settings: dict[str, Any], params: dict[str, Any]) -> str:
    return ",".join(f"{k}={v}" for k, v in {**settings, **params}.items())


def _outputs(
    name: str, dataset: str, rows: list[dict[str, Any]], folder: Path, opt: ExperimentOptions
) -> tuple[str, list[Path]]:
    from sgloc.evaluation import plots  # deferred: matplotlib costs ~0.25 s at import

    if name == "table":
        md = table1_markdown(summarize(rows, ["descriptor", "rejection"]), dataset == "airsim-guo")
        fig = plots.error_distribution(rows, folder / "error_distribution.png", opt.threshold)
        return md, [fig]
    if name == "overlap":
        by, title = ["overlap", "rejection"], f"{dataset}: translation error vs overlap"
        figs = [plots.overlap_boxplots(rows, folder / "overlap_boxplots.png", title)]
        return sweep_markdown(summarize(rows, by), by), figs
    by = ["descriptor", "rejection", "ransac_threshold"]
    md = sweep_markdown(summarize(rows, by), by)
    if name == "pr":
        return md, [plots.pr_curves(rows, folder / "pr_curves.png")]
    figs = [plots.error_vs_threshold(rows, folder / "error_vs_threshold.png")]
    if any(abs(float(r["ransac_threshold"]) - 5.0) < 1e-9 for r in rows):
        figs.append(plots.error_distribution(rows, folder / "error_distribution_5m.png"))
    return md, figs


def _matches(dataset: str, folder: Path, opt: ExperimentOptions) -> ExperimentOutput:
    """Fig. 7: one pair (seed `first_seed`), the matches of each stage with neighbor rejection,
    and the final matches of the baseline on the same pair."""
    from sgloc.evaluation import plots  # deferred: matplotlib costs ~0.25 s at import

    seed = opt.first_seed
    pair = make_pair_source(dataset, **opt.dataset_params)(seed)
    q, t, T_gt = pair.query.positions, pair.target.positions, pair.T_target_query
    base = {"descriptor": opt.descriptor, "ransac_threshold": opt.threshold, **opt.settings}
    cfgs = {rej: config_for({**base, "rejection": rej}) for rej in ("neighbor", "none")}
    results = {}
    for rej, cfg in cfgs.items():
        rng = np.random.default_rng([seed, LOCALIZER_STREAM])
        results[rej] = Localizer(cfg)(pair.query, pair.target, rng)
    nb, bl = results["neighbor"], results["none"]
    stages = {
        "original matches": nb.candidates,
        "after neighbor rejection": nb.survivors,
        "final (neighbor + RANSAC)": nb.matches,
        "final (RANSAC only)": bl.matches,
    }
    title = f"{dataset}, seed {seed}: green = correct (within {T_P:g} m under ground truth)"
    fig = plots.matches_picture(q, t, T_gt, stages, folder / "matches.png", T_P, title)
    body = [[k, len(m), int(correct_matches(q, t, m, T_gt, T_P).sum())] for k, m in stages.items()]
    md = f"# matches on {dataset} (seed {seed})\n\n"
    md += markdown_table(["stage", "matches", "correct"], body)
    for rej, res in results.items():
        te, re = pair.own_frame_errors(res.transform)
        md += f"\n{rej}: localized={res.accepted}, translation error {fmt(te)} m, "
        md += f"rotation error {fmt(re)} deg"
    with naming(folder / "table.md"):
        (folder / "table.md").write_text(md + "\n")
    exp = {"name": "matches", "dataset": dataset, "dataset_params": opt.dataset_params}
    configs = {k: c.to_dict() for k, c in cfgs.items()}
    cfg_file = write_config_yaml(folder / "config.yaml", {**exp, "seed": seed}, configs)
    return ExperimentOutput(folder, [fig, folder / "table.md", cfg_file], md + "\n")
