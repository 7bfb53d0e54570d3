"""The paper's evaluation metrics (its Section IV: pose errors, recall and precision of matches).

- Pose error: translation (m) and rotation (deg) of `T_err = T_est @ inv(T_gt)`, both mapping
  query into target, i.e. measured in the target map's frame (`sgloc.geometry.transform_error`).
- Final matches: the RANSAC inliers. A match (i, j) is correct when query vertex i, mapped by
  the ground truth, lies within `T_p` (10 m) of target vertex j.
- Recall = correct final matches / correct matches among the original candidates;
  precision = correct final matches / final matches.
- Failure: translation error > `failure_m` (20 m), or not localized at all.

Conventions for empty sets: recall is NaN when the candidates hold no correct match (nothing to
recall); precision is NaN when there is no final match (a run that was not localized). Tables
average over the trials where a value is defined and count failures separately.
"""

from __future__ import annotations

import numpy as np

from sgloc.geometry import apply, transform_error

#: Distance (m) under the ground truth within which a match counts as correct (paper: T_p).
T_P = 10.0
#: Translation error (m) above which a run counts as failed (paper, Fig. 1).
FAILURE_M = 20.0


def correct_matches(
    query_positions: np.ndarray,
    target_positions: np.ndarray,
    matches: np.ndarray,
    T_target_query: np.ndarray,
    tol: float = T_P,
) -> np.ndarray:
    """(k,) bool: whether each match (query index, target index) is correct, i.e. the query
    vertex mapped into the target frame by the ground truth lies within `tol` metres of the
    target vertex."""
    matches = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    if len(matches) == 0:
        return np.zeros(0, dtype=bool)
    q = apply(T_target_query, np.asarray(query_positions)[matches[:, 0]])
    t = np.asarray(target_positions)[matches[:, 1]]
    return np.linalg.norm(q - t, axis=1) < tol


def recall_precision(
    n_correct_final: int, n_final: int, n_correct_candidates: int
) -> tuple[float, float]:
    """(recall, precision) as fractions in [0, 1]; NaN where the denominator is 0."""
    recall = n_correct_final / n_correct_candidates if n_correct_candidates else float("nan")
    precision = n_correct_final / n_final if n_final else float("nan")
    return recall, precision


def pose_errors(T_est: np.ndarray | None, T_gt: np.ndarray) -> tuple[float, float]:
    """(translation error m, rotation error deg) in the target frame; NaN when not localized."""
    if T_est is None:
        return float("nan"), float("nan")
    return transform_error(T_est, T_gt)


def is_failure(translation_error: float, failure_m: float = FAILURE_M) -> bool:
    """A run fails when it is not localized (NaN error) or its translation error > failure_m."""
    return not (np.isfinite(translation_error) and translation_error <= failure_m)


def match_stats(
    query_positions: np.ndarray,
    target_positions: np.ndarray,
    candidates: np.ndarray,
    survivors: np.ndarray,
    final: np.ndarray,
    T_target_query: np.ndarray,
    tol: float = T_P,
) -> dict[str, float]:
    """The candidate, surviving (after rejection) and final matches and their correct ones under
    the ground truth T_target_query (correctness radius `tol` metres), as counts n_<stage> and
    n_correct_<stage>, then recall and precision."""
    out: dict[str, float] = {}
    for stage, m in (("candidates", candidates), ("survivors", survivors), ("final", final)):
        ok = correct_matches(query_positions, target_positions, m, T_target_query, tol)
        out[f"n_{stage}"], out[f"n_correct_{stage}"] = int(len(ok)), int(ok.sum())
    rp = recall_precision(out["n_correct_final"], out["n_final"], out["n_correct_candidates"])
    return {**out, "recall": rp[0], "precision": rp[1]}
