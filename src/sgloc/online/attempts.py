"""Localization attempts between two robots' maps, run here, on local processes or on a Dask
cluster; each attempt is a pure function of its graphs, config and seed. Run here, a target
may come prepared (`sgloc.PreparedMap`, the same result): a map that is the target of several
attempts is then described once."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from sgloc.errors import SglocError
from sgloc.maps.graph import SemanticGraph
from sgloc.online.records import Attempt
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.localizer import Localizer
from sgloc.pipeline.prepared import PreparedMap
from sgloc.runtime.tasks import run_all, runs_here

#: One attempt: (query graph, target graph or prepared map, seed).
Pair = tuple[SemanticGraph, "SemanticGraph | PreparedMap", Any]


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
    graph = target.graph if isinstance(target, PreparedMap) else target
    transform = covariance = None
    try:
        res = localizer(query, target, np.random.default_rng(seed))
        accepted, confidence = bool(res.accepted), float(res.confidence or 0.0)
        n_matches, reason = int(len(res.matches)), res.reason
        if res.accepted:
            transform, covariance = res.transform, res.covariance
    except SglocError as e:
        accepted, confidence, n_matches, reason = False, 0.0, 0, str(e)
    return Attempt(query.name, graph.name, 0.0, accepted, transform, confidence, n_matches,
                   reason, time.perf_counter() - t0, (len(query), len(target)), covariance)


def localize_task(task: tuple) -> Attempt:
    """Worker: `localize_pair` on graphs passed as arrays (so any process or Dask worker can).
    task = (key, qpos, qlab, qr, tpos, tlab, tr, config, seed); config: a LocalizerConfig (it
    pickles) or its `to_dict`."""
    _key, qpos, qlab, qr, tpos, tlab, tr, cfg, seed = task  # the key is for the caller
    if not isinstance(cfg, LocalizerConfig):
        cfg = LocalizerConfig.from_dict(cfg)
    q = SemanticGraph(qpos, qlab, qr, name="query")
    t = SemanticGraph(tpos, tlab, tr, name="target")
    return localize_pair(Localizer(cfg), q, t, seed)


def run_attempts(
    pairs: list[Pair], config: LocalizerConfig, scheduler: str | None = None,
    workers: int | None = 0,
) -> list[Attempt]:
    """Localize each (query, target, seed) of `pairs` with `config`, results in order: in this
    process (one localizer; prepared targets serve every query against them) or, as arrays,
    on the Dask scheduler at `scheduler` / on `workers` local processes
    (`sgloc.runtime.tasks.run_all`; None: CPU count; 0 or 1: in this process)."""
    scheduler = scheduler or None
    if not pairs:
        return []
    if runs_here(len(pairs), workers, scheduler):
        localizer = Localizer(config)
        return [localize_pair(localizer, q, t, seed) for q, t, seed in pairs]
    tasks = []
    for k, (q, t, seed) in enumerate(pairs):
        t = t.graph if isinstance(t, PreparedMap) else t
        tasks.append((k, q.positions, q.labels, q.edge_radius, t.positions, t.labels,
                      t.edge_radius, config, seed))
    return run_all(tasks, localize_task, workers, scheduler)
