"""Calibration of the covariance of accepted transforms on real data: the KITTI 00 positive
pairs of benchmarks/hard_cases.py (tuning and held-out apart), localized with the default
settings; how often the true error falls inside the covariance's 95 % region.

    python benchmarks/covariance.py [--workers N] [--refresh] [--out DIR] [--update-docs]

Stage 1 (cached in --out/fits-<split>.pkl; --refresh redoes it): localize every pair, keep the
final matched points, the estimate and the ground truth. Stage 2: the covariance of each
accepted estimate (`sgloc.covariance.transform_covariance`), the true error in its tangent
convention and the coverage; with --fit also the inflation constants chosen on the tuning pairs
(printed; they are copied into sgloc.covariance by hand). --update-docs writes
docs/covariance.md and docs/covariance.png.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import pickle  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SPLITS = ("tuning", "heldout")


def hard_cases() -> Any:
    """benchmarks/hard_cases.py as a module (its pair builder)."""
    if "hard_cases" in sys.modules:
        return sys.modules["hard_cases"]
    spec = importlib.util.spec_from_file_location("hard_cases", ROOT / "benchmarks" / "hard_cases.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["hard_cases"] = mod
    spec.loader.exec_module(mod)
    return mod


# ---------------------------------------------------------------------------------------------
# Stage 1: localize the pairs (cached).


def fit_pair(spec: Any) -> dict[str, Any]:
    """Localize one KITTI positive pair with the default settings; what the covariance needs."""
    from sgloc.evaluation.trials import limit_blas_threads
    from sgloc.localizer import localize

    hc = hard_cases()
    limit_blas_threads()
    pair = hc.make_pair(spec)
    gt = hc.gt_check(pair)
    res = localize(pair.query, pair.target, seed=spec.seed)
    m = res.matches
    return {
        "category": spec.category, "index": spec.index, "pair": spec.label,
        "gt_ok": bool(gt["gt_ok"]), "success": bool(res.success),
        "T_est": res.transform, "T_true": pair.T_target_query,
        "T_moved_own": pair.T_moved_own,
        "src": pair.query.positions[m[:, 0]], "dst": pair.target.positions[m[:, 1]],
        "labels": pair.query.labels[m[:, 0]],
        "query_centroid": pair.query.positions.mean(axis=0), "n_query": len(pair.query),
        "covariance": getattr(res, "covariance", None),
    }  # fmt: skip


def _fit_chunk(specs: list[Any]) -> list[dict[str, Any]]:
    return [fit_pair(s) for s in specs]


def collect(split: str, workers: int) -> list[dict[str, Any]]:
    """Stage 1 for one split: a row per KITTI positive pair of hard_cases.py."""
    hc = hard_cases()
    heldout = split == "heldout"
    specs = [s for c in hc.KITTI_POSITIVES for s in hc.category_specs(c, False, heldout)]
    chunks: dict[tuple, list[Any]] = {}
    for s in specs:  # pairs sharing a target map in one process (its graph is cached)
        chunks.setdefault((s.category, s.a), []).append(s)
    if workers <= 1:
        rows = [r for c in chunks.values() for r in _fit_chunk(c)]
    else:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers) as pool:
            rows = [r for part in pool.map(_fit_chunk, chunks.values()) for r in part]
    order = {c: i for i, c in enumerate(hc.KITTI_POSITIVES)}
    return sorted(rows, key=lambda r: (order[r["category"]], r["index"]))


def load_fits(out: Path, split: str, workers: int, refresh: bool) -> list[dict[str, Any]]:
    path = out / f"fits-{split}.pkl"
    if path.is_file() and not refresh:
        return pickle.loads(path.read_bytes())
    t0 = time.time()
    rows = collect(split, workers)
    out.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(rows))
    print(f"{split}: {len(rows)} pairs localized in {time.time() - t0:.0f} s -> {path}")
    return rows


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--workers", type=int, default=1, help="processes for stage 1")
    p.add_argument("--refresh", action="store_true", help="redo stage 1 (the localizations)")
    p.add_argument("--out", type=Path, default=ROOT / "results" / "covariance")
    p.add_argument("--update-docs", action="store_true", help="write docs/covariance.md + .png")
    p.add_argument("--collect-only", action="store_true", help="stage 1 only")
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    fits = {s: load_fits(args.out, s, args.workers, args.refresh) for s in SPLITS}
    if args.collect_only:
        return


if __name__ == "__main__":
    main()
