"""Rivals of an alignment: is there a different one, and how well is it supported?

`distinct_from` is the one test of "a different alignment" (the runner-up search here and the
whole-map verification); `runner_up` searches the candidates the estimate does not explain for
the best distinct alternative (4-dof pairs, compiled when `sgloc.kernels` is in use, or 6-dof
triples). Hypotheses come from `sgloc.estimation`'s minimal-sample fits.
"""

from __future__ import annotations

import numpy as np

from sgloc.acceptance.config import AcceptanceConfig
from sgloc.consistency.pairwise import ConsistentPairs, unpack_rows
from sgloc.consistency.sampled import SampledConsistency
from sgloc.estimation import (
    non_collinear,
    rigid_from_triplets,
    squared_residuals,
    tilt_deg,
)


def distinct_from(
    R: np.ndarray, t: np.ndarray, T: np.ndarray, c: np.ndarray, metres: float, degrees: float
) -> np.ndarray:
    """(B,) bool: the hypotheses (R (B,3,3), t (B,3)) that move point `c` (3,) more than
    `metres` away from where T (4x4) moves it, or turn more than `degrees` from T."""
    shift = np.linalg.norm(R @ c + t - (T[:3, :3] @ c + T[:3, 3]), axis=1)
    cosang = (np.einsum("bij,ij->b", R, T[:3, :3]) - 1.0) / 2.0
    turn = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
    return (shift > metres) | (turn > degrees)


def runner_up(
    src: np.ndarray,
    dst: np.ndarray,
    T: np.ndarray,
    exclude: np.ndarray,
    consistency: np.ndarray | None,
    edges: ConsistentPairs | SampledConsistency,
    radius: float,
    cfg: AcceptanceConfig,
    rng: np.random.Generator,
    dof: int = 6,
    max_tilt: float | None = None,
) -> tuple[int, np.ndarray | None]:
    """Best distinct alternative to T: (its inlier count among the candidates, its 4x4 transform).

    The alternative must stand on its own evidence: it is drawn from, and scored on, only the
    candidates outside `exclude` (those T explains within twice the radius), so a slight tilt of
    T that keeps most of T's matches is not counted as a rival. Hypotheses come from triples of
    pairwise-consistent candidates (`consistency`, packed rows: |D(q_i,q_j) - D(t_i,t_j)| <
    2 * radius; above ALL_PAIRS_LIMIT candidates `edges` is a sample of pairs), drawn at
    random and fitted in one batch; those within the distinctness bounds of T are discarded.
    dof=4: hypotheses about the z axis from the consistent pairs themselves; `max_tilt`
    (degrees): hypotheses tilting the up axis more are not alternatives.
    """
    free = ~exclude
    if free.sum() < 3 or cfg.runner_up_samples <= 0:
        return 0, None
    if isinstance(edges, SampledConsistency):
        i, j = edges.draw(free, cfg.runner_up_samples, rng)
        if len(i) == 0:
            return 0, None
    else:
        kept = edges.within(free)
        if kept.size == 0:
            return 0, None
        i, j = kept.at(rng.integers(0, kept.size, cfg.runner_up_samples))
    if dof == 4:
        return _compiled_yaw_runner_up(src, dst, T, exclude, i, j, radius, cfg)
    rows = edges if isinstance(edges, SampledConsistency) else consistency
    hyp = _triplet_hypotheses(src, dst, i, j, rows, free, rng, max_tilt)
    if hyp is None:
        return 0, None
    return best_distinct(*hyp, T, src, dst, exclude, radius, cfg)


def best_distinct(R: np.ndarray, t: np.ndarray, T: np.ndarray, src: np.ndarray, dst: np.ndarray,
                  exclude: np.ndarray, radius: float, cfg) -> tuple[int, np.ndarray | None]:
    """Of the hypotheses (R (k,3,3), t (k,3)) distinct from T, the one with the most inliers
    (within `radius` m) among the candidates not in `exclude`: (its inliers, its 4x4), or
    (0, None) when none is distinct."""
    # Distinctness, measured where it matters: at the centroid of T's support (query frame).
    c = src[exclude].mean(axis=0) if exclude.any() else src.mean(axis=0)
    distinct = distinct_from(R, t, T, c, cfg.distinct_translation, cfg.distinct_rotation)
    if not distinct.any():
        return 0, None
    R, t, free = R[distinct], t[distinct], ~exclude
    counts = (squared_residuals(R, t, src[free], dst[free]) < radius**2).sum(axis=1)
    h = int(np.argmax(counts))
    T2 = np.eye(4)
    T2[:3, :3], T2[:3, 3] = R[h], t[h]
    return int(counts[h]), T2


def _compiled_yaw_runner_up(
    src, dst, T, exclude, i, j, radius, cfg
) -> tuple[int, np.ndarray | None]:
    """`runner_up`'s dof=4 branch from the drawn pairs (i, j) on, in one compiled pass
    (`sgloc.acceptance.runner_up_kernels`): 4-dof hypotheses from the pairs apart in xy (each
    distinct pair at its first draw), those distinct from T at the centre of T's support, the
    one with the most inliers among the free candidates."""
    from sgloc.acceptance.runner_up_kernels import best_yaw_alternative

    count, T2, found = best_yaw_alternative(
        np.ascontiguousarray(src, dtype=np.float64),
        np.ascontiguousarray(dst, dtype=np.float64),
        i,
        j,
        ~exclude,
        np.ascontiguousarray(T, dtype=np.float64),
        float(cfg.distinct_translation),
        float(cfg.distinct_rotation),
        float(radius),
    )
    return (int(count), T2) if found else (0, None)


def _triplet_hypotheses(
    src, dst, i, j, consistency, free, rng, max_tilt
) -> tuple[np.ndarray, np.ndarray] | None:
    """6-dof hypotheses: each consistent pair (i, j) completed by a random candidate
    consistent with both; tilted beyond `max_tilt` degrees dropped."""
    if isinstance(consistency, SampledConsistency):
        k3 = consistency.third(i, j, free, rng)
        has = k3 >= 0
        if not has.any():
            return None
    else:
        common = unpack_rows(consistency[i] & consistency[j], len(free)) & free
        has = common.any(axis=1)
        if not has.any():
            return None
        keys = np.where(common, rng.random(common.shape, dtype=np.float32), -1.0)
        k3 = np.argmax(keys, axis=1)
    trip = np.column_stack([i, j, k3])[has]
    S, D = src[trip], dst[trip]
    ok = non_collinear(S, 1e-2) & non_collinear(D, 1e-2)
    if not ok.any():
        return None
    R, t = rigid_from_triplets(S[ok], D[ok])
    if max_tilt is not None:
        up = tilt_deg(R) <= max_tilt
        R, t = R[up], t[up]
    return (R, t) if len(R) else None
