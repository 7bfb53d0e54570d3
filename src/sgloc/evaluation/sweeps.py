"""Sweeps: grids of trials over localizer settings and pair-source parameters (the paper's
experiments build theirs in `sgloc.evaluation.experiments.make_sweep`).

Trial i of every grid cell uses seed `first_seed + i`, so cells are compared on the same pairs
and initial transforms (paired comparisons), and any cell can be re-run alone.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from sgloc.config import LocalizerConfig
from sgloc.errors import UnknownNameError
from sgloc.evaluation.metrics import FAILURE_M, T_P
from sgloc.evaluation.trials import TrialTask

DESCRIPTOR_NAMES = ("histogram", "fast", "random_walk")
REJECTION_NAMES = ("none", "neighbor")
#: RANSAC thresholds T_error of Fig. 4-5 (metres).
THRESHOLDS = tuple(float(x) for x in range(1, 21))
OVERLAPS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)


@dataclass
class Sweep:
    """A grid of trials.

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
        names = [*self.dataset_axes, *self.axes]
        out = []
        for combo in itertools.product(*self.dataset_axes.values(), *self.axes.values()):
            point = dict(zip(names, combo, strict=True))
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
        return [
            TrialTask(
                dataset=self.dataset,
                config=cfg,
                seed=self.first_seed + i,
                dataset_params=params,
                tags=tags,
                T_p=self.T_p,
                failure_m=self.failure_m,
                repeats=self.repeats,
                clock=self.clock,
            )
            for i in range(self.trials)
            for cfg, params, tags in cells
        ]


def _stage_params() -> set[str]:
    """Names of every registered descriptor's and rejector's parameters."""
    from sgloc.descriptors import DESCRIPTORS
    from sgloc.rejection import REJECTORS

    return {
        f.name
        for cls in [*DESCRIPTORS.values(), *REJECTORS.values()]
        for f in dataclasses.fields(cls)
    }


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
