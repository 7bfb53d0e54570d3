"""Localization attempts between two robots' maps, run here, on local processes or on a Dask
cluster; each attempt is a pure function of its arrays, config and seed."""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from sgloc.config import LocalizerConfig
from sgloc.errors import SglocError
from sgloc.graph import SemanticGraph


def fallback_covariance(
    n_matches: int, threshold: float, query_positions: np.ndarray
) -> np.ndarray:
    """(6,6) covariance [rx ry rz tx ty tz] for a link whose result carries none.

    A rough model: each of the n inlier matches fixes the translation to within the RANSAC
    `threshold` (metres), so sigma_t = threshold / sqrt(n); the rotation follows from that over
    the query map's RMS extent r (>= 1 m): sigma_r = sigma_t / r rad. Both are inflated 2x
    since matched object centres share map-level offsets the model does not see.
    """
    n = max(int(n_matches), 1)
    sigma_t = 2.0 * float(threshold) / np.sqrt(n)
    pts = np.asarray(query_positions, np.float64).reshape(-1, 3)
    r = float(np.sqrt(((pts - pts.mean(axis=0)) ** 2).sum(axis=1).mean())) if len(pts) else 1.0
    sigma_r = sigma_t / max(r, 1.0)
    return np.diag([sigma_r**2] * 3 + [sigma_t**2] * 3)


def localize_task(task: tuple) -> dict[str, Any]:
    """Worker: localize `query` in `target` (graphs passed as arrays so any process or Dask
    worker can). task = (key, qpos, qlab, qr, tpos, tlab, tr, cfg_dict, seed)."""
    from sgloc.localizer import Localizer

    key, qpos, qlab, qr, tpos, tlab, tr, cfg_dict, seed = task
    t0 = time.perf_counter()
    q = SemanticGraph(qpos, qlab, qr, name="query")
    t = SemanticGraph(tpos, tlab, tr, name="target")
    cfg = LocalizerConfig.from_dict(cfg_dict)
    out: dict[str, Any] = {"key": key, "transform": None, "covariance": None}
    try:
        res = Localizer(cfg)(q, t, np.random.default_rng(seed))
        cov = getattr(res, "covariance", None)
        out.update(
            accepted=bool(res.success), confidence=float(res.confidence or 0.0),
            n_matches=int(len(res.matches)), reason=res.reason,
        )
        if res.success:
            out["transform"] = res.transform
            if cov is not None:
                out["covariance"] = np.asarray(cov, np.float64)
                out["cov_source"] = "the localizer's covariance"
            else:
                out["covariance"] = fallback_covariance(
                    len(res.matches), cfg.ransac.threshold, qpos
                )
                out["cov_source"] = "fallback covariance from the inlier count"
    except SglocError as e:
        out.update(accepted=False, confidence=0.0, n_matches=0, reason=str(e))
    out["seconds"] = time.perf_counter() - t0
    return out


def run_tasks(
    tasks: list[tuple], scheduler: str | None = None, workers: int | None = 0
) -> list[dict]:
    """Run `localize_task` over `tasks`: on the Dask scheduler at `scheduler`, else on
    `workers` local processes (None: CPU count; 0 or 1: in this process). Results in order."""
    if scheduler:
        from sgloc.optional import require

        Client = require("distributed", "dask", "--scheduler (a Dask cluster)").Client
        try:
            client = Client(scheduler, timeout=10)
        except (OSError, ValueError, TypeError) as e:  # unreachable or malformed address
            raise SglocError(
                f"cannot reach the Dask scheduler at {scheduler!r} ({e}); start one with "
                "`dask scheduler` or omit --scheduler to use local processes."
            ) from None
        try:
            return client.gather(client.map(localize_task, tasks, pure=False))
        finally:
            client.close()
    n = workers if workers is not None else (os.cpu_count() or 1)
    if n <= 1 or len(tasks) <= 1:
        return [localize_task(t) for t in tasks]
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=min(n, len(tasks))) as pool:
        return list(pool.map(localize_task, tasks, chunksize=max(1, len(tasks) // (4 * n))))
