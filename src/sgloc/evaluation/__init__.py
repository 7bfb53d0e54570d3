"""Evaluation harness: the paper's metrics, pair sources, trial runner, sweeps, reports, plots.

from sgloc.evaluation import make_pair_source, descriptor_rejection_sweep, run_tasks, summarize
rows = run_tasks(descriptor_rejection_sweep("airsim-guo", trials=10).tasks())
"""

from sgloc.evaluation.metrics import (
    FAILURE_M,
    T_P,
    MatchStats,
    correct_matches,
    is_failure,
    match_stats,
    pose_errors,
    recall_precision,
)
from sgloc.evaluation.pairs import dataset_names, make_pair_source
from sgloc.evaluation.report import summarize, write_csv
from sgloc.evaluation.scenes import PAIR_SOURCES, Pair, register_pair_source
from sgloc.evaluation.sweeps import (
    Sweep,
    descriptor_rejection_sweep,
    overlap_sweep,
    threshold_sweep,
)
from sgloc.evaluation.trials import TrialTask, reproducible_part, run_task, run_tasks

__all__ = [
    "FAILURE_M",
    "PAIR_SOURCES",
    "T_P",
    "MatchStats",
    "Pair",
    "Sweep",
    "TrialTask",
    "correct_matches",
    "dataset_names",
    "descriptor_rejection_sweep",
    "is_failure",
    "make_pair_source",
    "match_stats",
    "overlap_sweep",
    "pose_errors",
    "recall_precision",
    "register_pair_source",
    "reproducible_part",
    "run_task",
    "run_tasks",
    "summarize",
    "threshold_sweep",
    "write_csv",
]
