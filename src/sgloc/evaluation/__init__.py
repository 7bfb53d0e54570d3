"""Evaluation harness: the paper's metrics, pair sources, trial runner, sweeps, reports, plots.

from sgloc.evaluation import make_pair_source, run_trials, summarize
from sgloc.evaluation.experiments import ExperimentOptions, make_sweep
rows = run_trials(make_sweep("table", "airsim-guo", ExperimentOptions(trials=10)).tasks())
"""

from sgloc.evaluation.pairs import make_pair_source
from sgloc.evaluation.report import summarize
from sgloc.evaluation.scenes import Pair, register_pair_source
from sgloc.evaluation.trials import reproducible_part, run_task, run_trials

__all__ = [
    "Pair",
    "make_pair_source",
    "register_pair_source",
    "reproducible_part",
    "run_task",
    "run_trials",
    "summarize",
]
