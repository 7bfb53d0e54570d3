"""Localization attempts between two robots' maps, run here, on local processes or on a Dask
cluster; each attempt is a pure function of its arrays, config and seed."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from sgloc.errors import SglocError
from sgloc.maps.graph import SemanticGraph
from sgloc.online.records import Attempt
from sgloc.pipeline.config import LocalizerConfig
from sgloc.runtime.tasks import run_all


def localize_pair(
    localizer, query: SemanticGraph, target: SemanticGraph, seed: Any
) -> Attempt:
    """Localize `query` in `target` with `localizer` (a `sgloc.Localizer`) and the random seed
    `seed`, as an `Attempt` named by the graphs' names, at stamp 0.0 (the session sets the
    robots' names, the stamp and the sizes it counts): accepted, transform (T_target_query),
    covariance (6,6, `sgloc.estimation.covariance`), confidence, n_matches, reason, seconds.
    The localizer keeps nothing between calls; a `sgloc.PreparedMap` as `target` carries what
    its preparation computed to every call."""
    t0 = time.perf_counter()
    transform = covariance = None
    try:
        res = localizer(query, target, np.random.default_rng(seed))
        accepted, confidence = bool(res.accepted), float(res.confidence or 0.0)
        n_matches, reason = int(len(res.matches)), res.reason
        if res.accepted:
            transform, covariance = res.transform, res.covariance
    except SglocError as e:
        accepted, confidence, n_matches, reason = False, 0.0, 0, str(e)
    return Attempt(query.name, target.name, 0.0, accepted, transform, confidence, n_matches,
                   reason, time.perf_counter() - t0, (len(query), len(target)), covariance)


def localize_task(task: tuple) -> Attempt:
    """Worker: `localize_pair` on graphs passed as arrays (so any process or Dask worker can).
    task = (key, qpos, qlab, qr, tpos, tlab, tr, config, seed); config: a LocalizerConfig (it
    pickles) or its `to_dict`."""
    from sgloc.pipeline.localizer import Localizer

    _key, qpos, qlab, qr, tpos, tlab, tr, cfg, seed = task  # the key is for the caller
    if not isinstance(cfg, LocalizerConfig):
        cfg = LocalizerConfig.from_dict(cfg)
    q = SemanticGraph(qpos, qlab, qr, name="query")
    t = SemanticGraph(tpos, tlab, tr, name="target")
    return localize_pair(Localizer(cfg), q, t, seed)


def run_tasks(
    tasks: list[tuple], scheduler: str | None = None, workers: int | None = 0
) -> list[Attempt]:
    """Run `localize_task` over `tasks` (`sgloc.runtime.tasks.run_all`): on the Dask scheduler at
    `scheduler`, else on `workers` local processes (None: CPU count; 0 or 1: in this process).
    Results in order."""
    return run_all(tasks, localize_task, workers, scheduler or None)
