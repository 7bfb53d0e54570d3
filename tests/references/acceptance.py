"""Numpy references of the acceptance stage's kernels (`sgloc.acceptance.evidence_kernels`,
`sgloc.acceptance.runner_up_kernels`, `sgloc.maps.neighbor_kernels.near_class_counts`): equal to
rounding where they use other sums (closed-form axes, residual expansions)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from sgloc.acceptance.chance import (
    ChanceModel,
    log10_colocation_p,
    nfa_over_radii_each,
    per_object_min,
    permutation_lambda,
)
from sgloc.acceptance.rivals import best_distinct
from sgloc.estimation import yaw_from_pairs
from sgloc.geometry import apply


def reflect_across_line(points: np.ndarray, on_line: np.ndarray) -> np.ndarray:
    """`sgloc.acceptance.mirror.reflect_across_line`, the principal axis by an SVD."""
    xy = on_line[:, :2]
    centre = xy.mean(axis=0)
    _, _, vt = np.linalg.svd(xy - centre, full_matrices=False)
    normal = np.array([-vt[0, 1], vt[0, 0]])  # across the line, horizontal
    out = points.copy()
    out[:, :2] -= 2.0 * ((points[:, :2] - centre) @ normal)[:, None] * normal
    return out


def inlier_spread(points: np.ndarray, dof: int = 6) -> float:
    """`sgloc.acceptance.assessment.inlier_spread` by SVDs."""
    if len(points) < 3:
        return 0.0
    if dof == 4:
        s = np.linalg.svd(points[:, :2] - points[:, :2].mean(axis=0), compute_uv=False)
        return float(s[0] / np.sqrt(len(points)))
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return float(s[1] / np.sqrt(len(points)))


def squared_residuals_of(T: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """`sgloc.acceptance.assessment.squared_residuals_of` in numpy."""
    return np.sum((apply(T, src) - dst) ** 2, axis=1)


def near_counts(
    model: ChanceModel, moved: np.ndarray, weights: tuple[np.ndarray | None, ...] = (None,)
) -> list[np.ndarray]:
    """`model.near_counts(moved, weights)` by KD-trees (scipy), any weights."""
    n, k = len(moved), model.n_classes
    if n == 0:
        return [np.zeros((0, k)) for _ in weights]
    from scipy.spatial import cKDTree

    tree = cKDTree(model.positions)
    pairs = cKDTree(moved).sparse_distance_matrix(tree, model.radius, output_type="ndarray")
    i, j = pairs["i"], pairs["j"]
    cell = i * k + model.labels[j]
    return [
        np.bincount(cell, None if w is None else w[j], minlength=n * k).reshape(n, k)
        for w in weights
    ]


def near_targets(model: ChanceModel, moved: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """`model.near_targets(moved, targets)`: `near_counts` weighted by each object's count in
    `targets`."""
    usage = np.bincount(targets, minlength=len(model.labels)).astype(np.float64)
    return near_counts(model, moved, (usage,))[0]


def chance_terms(labels, counts, used, qi, tlab, inlier, chance: ChanceModel) -> tuple:
    """`sgloc.acceptance.chance.chance_terms` in numpy."""
    k = int(np.count_nonzero(np.bincount(qi[inlier])))
    lam = chance.expected_inliers(counts, qi, tlab)
    lam_p = permutation_lambda(used[qi, tlab], inlier, tlab, counts[qi, tlab], chance)
    _, C, mu = log10_colocation_p(SimpleNamespace(labels=labels), counts > 0, qi[inlier])
    return k, lam, lam_p, C, mu


def object_nfa_over_radii(res2, qi, rows, n_objects, radius, lams, m, n_tests, sample=3):
    """`sgloc.acceptance.chance.object_nfa_over_radii` by a sort (`per_object_min`)."""
    return nfa_over_radii_each(per_object_min(res2[rows], qi[rows]), radius, lams, m, n_tests,
                               sample)  # fmt: skip


def _first_draws(i: np.ndarray, j: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The pairs (i, j) without repeats, each at its first draw, in draw order: a pair drawn
    again gives the same 4-dof hypothesis, and the best (first) one stays the same."""
    _, first = np.unique(i * m + j, return_index=True)
    first.sort()
    return i[first], j[first]


def _yaw_hypotheses(src, dst, i, j) -> tuple[np.ndarray, np.ndarray] | None:
    """4-dof hypotheses from consistent candidate pairs (i, j) apart in xy."""
    pair = np.stack([i, j], axis=1)
    S, D = src[pair], dst[pair]
    ok = (
        np.minimum(
            np.linalg.norm(S[:, 1, :2] - S[:, 0, :2], axis=1),
            np.linalg.norm(D[:, 1, :2] - D[:, 0, :2], axis=1),
        )
        > 1e-6
    )
    return yaw_from_pairs(S[ok], D[ok]) if ok.any() else None


def yaw_runner_up(src, dst, T, exclude, i, j, radius, cfg) -> tuple[int, np.ndarray | None]:
    """`sgloc.acceptance.rivals.runner_up`'s dof=4 branch from the drawn pairs (i, j) on, in
    numpy (the reference of `sgloc.acceptance.runner_up_kernels.best_yaw_alternative`)."""
    hyp = _yaw_hypotheses(src, dst, *_first_draws(i, j, len(src)))
    if hyp is None:
        return 0, None
    return best_distinct(*hyp, T, src, dst, exclude, radius, cfg)
