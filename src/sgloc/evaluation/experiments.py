"""The paper's experiments by name, each writing a results folder.

`run_experiment(name, dataset, ...)` builds the sweep, runs its trials (serially, on local
processes or on a Dask cluster), and writes into `out`: `trials.csv` (one row per trial),
`table.md` (Markdown summary), PNG figures, and `config.yaml` (the exact sweep and localizer
configs, software version and git commit).

Names: table (Table 1), threshold (Fig. 4 + error distribution at 5 m), pr (Fig. 5),
overlap (Fig. 6), matches (Fig. 7).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.errors import UnknownNameError
from sgloc.evaluation.metrics import T_P, correct_matches, pose_errors
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
from sgloc.evaluation.sweeps import (
    DESCRIPTOR_NAMES,
    OVERLAPS,
    REJECTION_NAMES,
    THRESHOLDS,
    Sweep,
    config_for,
)
from sgloc.evaluation.trials import LOCALIZER_STREAM, prepare_tasks, run_prepare, run_tasks
from sgloc.localizer import Localizer

EXPERIMENTS = ("table", "threshold", "pr", "overlap", "matches")


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
    rows: list[dict[str, Any]]


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
    """A `run_tasks` progress callback that reports (done, total, phase) to `progress`."""
    done = [0]

    def tick(n: int) -> None:
        done[0] += n
        if progress:
            progress(done[0], total, phase)

    return tick


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
    opt = options or ExperimentOptions()
    if name not in EXPERIMENTS:
        raise _unknown(name)
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    opt = resolved_options(dataset, opt)  # fails early on a bad dataset name
    if name == "matches":
        return _matches(dataset, folder, opt)
    sweep = make_sweep(name, dataset, opt)
    tasks = sweep.tasks()
    t0 = time.perf_counter()
    if opt.from_csv:
        rows = read_csv(opt.from_csv)
    else:
        prep = prepare_tasks(tasks)  # e.g. render each synthetic world once, in parallel
        if prep:
            tick_prep = _ticker(progress, len(prep), "preparing worlds")
            tick_prep(0)
            run_tasks(prep, workers, scheduler, tick_prep, fn=run_prepare)
        rows = run_tasks(tasks, workers, scheduler, _ticker(progress, len(tasks), "trials"))
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
    return ExperimentOutput(folder, files, md, rows)


def _cell_name(settings: dict[str, Any], params: dict[str, Any]) -> str:
    items = {**settings, **params}
    return ",".join(f"{k}={v}" for k, v in items.items())


def _outputs(
    name: str, dataset: str, rows: list[dict[str, Any]], folder: Path, opt: ExperimentOptions
) -> tuple[str, list[Path]]:
    from sgloc.evaluation import plots  # deferred: matplotlib costs ~0.25 s at import

    figs: list[Path] = []
    if name == "table":
        summary = summarize(rows, ["descriptor", "rejection"])
        md = table1_markdown(summary, with_paper=dataset == "airsim-guo")
        figs.append(
            plots.error_distribution(rows, folder / "error_distribution.png", opt.threshold)
        )
        return md, figs
    if name in ("threshold", "pr"):
        summary = summarize(rows, ["descriptor", "rejection", "ransac_threshold"])
        md = sweep_markdown(summary, ["descriptor", "rejection", "ransac_threshold"])
        if name == "threshold":
            figs.append(plots.error_vs_threshold(rows, folder / "error_vs_threshold.png"))
            if any(abs(float(r["ransac_threshold"]) - 5.0) < 1e-9 for r in rows):
                figs.append(plots.error_distribution(rows, folder / "error_distribution_5m.png"))
        else:
            figs.append(plots.pr_curves(rows, folder / "pr_curves.png"))
        return md, figs
    # overlap
    summary = summarize(rows, ["overlap", "rejection"])
    md = sweep_markdown(summary, ["overlap", "rejection"])
    figs.append(
        plots.overlap_boxplots(
            rows, folder / "overlap_boxplots.png", f"{dataset}: translation error vs overlap"
        )
    )
    return md, figs


def _matches(dataset: str, folder: Path, opt: ExperimentOptions) -> ExperimentOutput:
    """Fig. 7: one pair (seed `first_seed`), the matches of each stage with neighbor rejection,
    and the final matches of the baseline on the same pair."""
    from sgloc.evaluation import plots  # deferred: matplotlib costs ~0.25 s at import

    seed = opt.first_seed
    pair = make_pair_source(dataset, **opt.dataset_params)(seed)
    base = {"descriptor": opt.descriptor, "ransac_threshold": opt.threshold, **opt.settings}
    results = {}
    for rej in ("neighbor", "none"):
        cfg = config_for({**base, "rejection": rej})
        rng = np.random.default_rng([seed, LOCALIZER_STREAM])
        results[rej] = (cfg, Localizer(cfg)(pair.query, pair.target, rng))
    nb, bl = results["neighbor"][1], results["none"][1]
    stages = {
        "original matches": nb.candidates,
        "after neighbor rejection": nb.survivors,
        "final (neighbor + RANSAC)": nb.matches,
        "final (RANSAC only)": bl.matches,
    }
    fig = plots.matches_picture(
        pair.query.positions,
        pair.target.positions,
        pair.T_target_query,
        stages,
        folder / "matches.png",
        T_P,
        f"{dataset}, seed {seed}: green = correct (within {T_P:g} m under ground truth)",
    )
    body = []
    for label, m in stages.items():
        ok = correct_matches(
            pair.query.positions, pair.target.positions, m, pair.T_target_query, T_P
        )
        body.append([label, len(m), int(ok.sum())])
    md = f"# matches on {dataset} (seed {seed})\n\n" + markdown_table(
        ["stage", "matches", "correct"], body
    )
    for rej, (_, res) in results.items():
        te, re = pose_errors(res.transform, pair.T_target_query)
        md += f"\n{rej}: localized={res.success}, translation error {fmt(te)} m, "
        md += f"rotation error {fmt(re)} deg"
    md += "\n"
    (folder / "table.md").write_text(md)
    exp = {"name": "matches", "dataset": dataset, "dataset_params": opt.dataset_params,
           "seed": seed}  # fmt: skip
    cfg_file = write_config_yaml(
        folder / "config.yaml", exp, {k: v[0].to_dict() for k, v in results.items()}
    )
    return ExperimentOutput(folder, [fig, folder / "table.md", cfg_file], md, [])
