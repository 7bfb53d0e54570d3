"""The paper's experiments as a library feature (`sgloc experiment`): `experiment_job` checks an
experiment's options and `ExperimentJob.run` runs its trials and writes the CSV, Markdown
table, figures and config (the evaluation harness, `sgloc.evaluation.experiments`, does the
work)."""

from sgloc.experiments.job import EXPERIMENTS, ExperimentJob, experiment_job

__all__ = ["EXPERIMENTS", "ExperimentJob", "experiment_job"]
