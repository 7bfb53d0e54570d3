"""The trial runner: one trial = one pair from a pair source + one `localize` run, scored.

A trial is a pure function of its `TrialTask` (dataset name and parameters, localizer config,
seed): the pair's randomness and the localizer's come from two streams of the seed, so the same
task gives the same row (timings aside) in this process, in a process pool, or on a Dask worker.
Trials run serially, on local processes (`workers`), or on a Dask cluster (`scheduler`).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sgloc.evaluation.metrics import FAILURE_M, T_P, is_failure, match_stats, pose_errors
from sgloc.evaluation.pairs import make_pair_source
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.localizer import Localizer
from sgloc.runtime.tasks import Progress, run_all

#: Stream index of the localizer's random numbers (RANSAC, random walks) within a trial seed.
LOCALIZER_STREAM = 1


@dataclass
class TrialTask:
    """Everything one trial depends on (small and picklable).

    dataset / dataset_params: a pair source name (or folder) and its parameters.
    config: a `LocalizerConfig.to_dict()`.
    seed: the trial seed (pair and localizer randomness).
    tags: sweep coordinates copied into the row (e.g. {"overlap": 0.3}).
    repeats: run the (deterministic) localization this many times and keep each stage's
        fastest time, as timeit does: on a loaded machine a single run's wall times measure
        the other processes as much as ours.
    clock: "cpu" (default) times each stage by the CPU time of this thread, "wall" by
        wall-clock time. On a machine shared with other work, wall times mostly measure the
        wait for a core (measured here: ~200 ms wall for ~30 ms of CPU); single-threaded
        (see `limit_blas_threads`), CPU time is the stage's own cost, what an idle machine
        shows as wall time.
    """

    dataset: str
    config: dict[str, Any]
    seed: int
    dataset_params: dict[str, Any] = field(default_factory=dict)
    tags: dict[str, Any] = field(default_factory=dict)
    T_p: float = T_P
    failure_m: float = FAILURE_M
    repeats: int = 1
    clock: str = "cpu"


#: The localizer's stages timed in every row (t_<stage>_ms; NaN when a stage did not run).
STAGES = ("descriptors", "matching", "rejection", "ransac", "estimation", "total")


@functools.cache
def limit_blas_threads() -> None:
    """Limit BLAS/OpenMP to one thread in this process (once). Trials are small matrix work:
    a multi-threaded OpenBLAS only spins on a loaded machine (measured here: matching 2 ms
    single-threaded, ~170 ms with OpenBLAS threads while other processes ran), and parallel
    trial workers would oversubscribe the cores."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)


def run_task(task: TrialTask) -> dict[str, Any]:
    """Run one trial and return its row as a flat dict: the task's tags, then dataset, settings,
    seed, outcome, pose errors, match counts and recall/precision (`match_stats`), stage times (ms),
    the call's CPU time, the localizer's reason, then the pair's info as pair_* columns.

    translation_error_m / rotation_error_deg: of T_est @ inv(T_gt) in the target map's own
    frame; translation_error_moved_m: the same in the randomly moved frame the target was
    handed over in (adds up to |rotation error| x |random shift|); `failed` uses the former.
    BLAS runs single-threaded in the calling process from then on (see `limit_blas_threads`).
    """
    limit_blas_threads()
    pair = make_pair_source(task.dataset, **task.dataset_params)(task.seed)
    cfg = LocalizerConfig.from_dict(task.config)
    localizer = Localizer(cfg)
    clock = time.thread_time if task.clock == "cpu" else time.perf_counter
    timings, cpu = [], []
    for _ in range(max(1, task.repeats)):
        rng = np.random.default_rng([int(task.seed), LOCALIZER_STREAM])
        c0 = time.thread_time()
        res = localizer(pair.query, pair.target, rng, clock=clock)
        cpu.append(time.thread_time() - c0)
        timings.append(res.timings)
    ms = {k: 1e3 * min(t[k] for t in timings) for k in timings[0]}
    te_moved, _ = pose_errors(res.transform, pair.T_target_query)
    te, re = pair.own_frame_errors(res.transform)
    q, t, T_gt = pair.query.positions, pair.target.positions, pair.T_target_query
    st = match_stats(q, t, res.candidates, res.survivors, res.matches, T_gt, task.T_p)
    return {
        **task.tags,
        "dataset": task.dataset,
        "descriptor": cfg.descriptor,
        "rejection": cfg.rejection,
        "ransac_threshold": float(cfg.ransac.threshold),
        "seed": int(task.seed),
        "localized": bool(res.accepted),
        "failed": is_failure(te, task.failure_m),
        "translation_error_m": te,
        "rotation_error_deg": re,
        "translation_error_moved_m": te_moved,
        **st,
        **{f"t_{k}_ms": ms.get(k, float("nan")) for k in STAGES},
        "t_cpu_ms": 1e3 * min(cpu),
        "reason": res.reason,
        **{f"t_{k}_ms": v for k, v in ms.items() if k not in STAGES},  # e.g. acceptance
        **{f"pair_{k}": v for k, v in pair.info.items()},
    }


def prepare_tasks(tasks: Sequence[TrialTask]) -> list[TrialTask]:
    """The first trial of each distinct world the trials need, for sources whose pairs come
    from an expensive disk-cached world (a `world(seed)` method, e.g. a rendered city); empty
    for the others. Run them with `run_trials(..., fn=run_prepare)` to build each world once."""
    first: dict[tuple, TrialTask] = {}
    for t in tasks:
        src = make_pair_source(t.dataset, **t.dataset_params)
        if hasattr(src, "world"):
            first.setdefault((src, src.world(t.seed)), t)
    return list(first.values())


def run_prepare(task: TrialTask) -> None:
    """Build the task's pair once, so that its world is in the cache (picklable entry point;
    no localization, which would change the kernels a later trial of this process runs)."""
    make_pair_source(task.dataset, **task.dataset_params)(task.seed)


def run_trials(
    tasks: Sequence[TrialTask],
    workers: int | None = None,
    scheduler: Any = None,
    progress: Progress | None = None,
    fn: Callable[[TrialTask], Any] = run_task,
) -> list[Any]:
    """Run trials (`fn` of each task, default `run_task`) and return the results in the order
    of `tasks`, by the one task runner `sgloc.runtime.tasks.run_all`.

    workers: local processes (None: the number of CPUs; 0 or 1: in this process).
    scheduler: a Dask scheduler address ("tcp://host:8786") or a `distributed.Client`; when
        given, the trials run on that cluster instead (its workers must see the same data paths).
    progress: called with the number of trials just finished (for a progress bar).
    """
    return run_all(tasks, fn, workers, scheduler, progress)


def reproducible_part(row: dict[str, Any]) -> dict[str, Any]:
    """A row without its timing columns (t_*): what must be identical for the same task."""
    return {k: v for k, v in row.items() if not k.startswith("t_")}
