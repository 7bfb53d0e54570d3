"""The acceptance test's sums over candidates and objects in one pass each (numba).

The compiled forms of `sgloc.acceptance`'s numpy glue: the candidates' residuals under a
transform (`moved_residuals`, equal to rounding), the per-object inlier fits at the
test's radii (`object_fits`: `per_object_min`, then the sorted search of
`nfa_over_radii_each`; counts and maxima, the same bits), the chance levels and the
co-location count of the estimate (`chance_sums`: `expected_inliers`, `permutation_lambda`,
`log10_colocation_p`'s mean and count; sums in candidate order, equal to rounding), and the
xy principal axis of a set of points in closed form (`xy_axis`: `inlier_spread` with dof=4;
`reflect_xy`: `reflect_across_line`; no SVD, equal to rounding). No sort or search
(sgloc.kernels).
"""

from __future__ import annotations

import numpy as np

from sgloc.kernels import watch_compiles
from sgloc.kernels.dispatch import kernel


@kernel
def moved_residuals(T: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(m,) squared distances (m^2) of the points src (m,3) moved by T (4x4) from dst (m,3)."""
    out = np.empty(src.shape[0])
    for r in range(src.shape[0]):
        s = 0.0
        for a in range(3):
            e = T[a, 0] * src[r, 0] + T[a, 1] * src[r, 1] + T[a, 2] * src[r, 2] + T[a, 3]
            s += (e - dst[r, a]) ** 2
        out[r] = s
    return out


@kernel
def object_fits(
    res2: np.ndarray, qi: np.ndarray, rows: np.ndarray, n_objects: int, limits: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(k, top): per limit, how many query objects have their smallest squared residual
    (over the candidates of `rows` (m,) bool, query object `qi` (m,)) below it, and the
    largest of those minima (-1 when none). res2 (m,) m^2; limits (L,) m^2."""
    best = np.full(n_objects, np.inf)
    seen = np.zeros(n_objects, dtype=np.bool_)
    for r in range(res2.shape[0]):
        if rows[r]:
            seen[qi[r]] = True
            if res2[r] < best[qi[r]]:
                best[qi[r]] = res2[r]
    k = np.zeros(limits.shape[0], dtype=np.int64)
    top = np.full(limits.shape[0], -1.0)
    for o in range(n_objects):
        if seen[o]:
            for f in range(limits.shape[0]):
                if best[o] < limits[f]:
                    k[f] += 1
                    top[f] = max(top[f], best[o])
    return k, top


@kernel
def chance_sums(
    qi: np.ndarray,
    tlab: np.ndarray,
    inlier: np.ndarray,
    counts: np.ndarray,
    used: np.ndarray,
    class_count: np.ndarray,
    qlabels: np.ndarray,
) -> tuple[int, float, float, int, float]:
    """(distinct inlier query objects, lambda, lambda_p, C, mu) of the candidates (query object
    `qi`, target class `tlab`, `inlier` (m,)) under one transform: `counts`, `used` (n, K) the
    near counts and near candidate targets of the moved query objects (`ChanceModel`),
    `class_count` (K,), `qlabels` (n,) the query's classes (sgloc.acceptance.chance)."""
    n, n_classes = counts.shape
    m = qi.shape[0]
    per_class = np.zeros(n_classes)
    for r in range(m):
        per_class[tlab[r]] += 1.0
    is_inlier = np.zeros(n, dtype=np.bool_)
    lam, lam_p = 0.0, 0.0
    for r in range(m):
        o, c = qi[r], tlab[r]
        uniform = counts[o, c] / class_count[c]
        lam += uniform
        if per_class[c] > 1.0:
            lam_p += max(used[o, c] - (1.0 if inlier[r] else 0.0), 0.0) / (per_class[c] - 1.0)
        else:
            lam_p += uniform
        if inlier[r]:
            is_inlier[o] = True
    f = np.zeros(n_classes)
    for i in range(n):
        f[qlabels[i]] += 1.0
    f /= max(n, 1)
    mu, colocated, k = 0.0, 0, 0
    for i in range(n):
        if is_inlier[i]:
            k += 1
            continue
        for c in range(n_classes):
            if counts[i, c] > 0.0:
                mu += f[c]
        colocated += counts[i, qlabels[i]] > 0.0
    return k, lam, lam_p, colocated, mu


@kernel
def xy_axis(points: np.ndarray) -> tuple[float, float, float, float, float]:
    """(centre x, centre y, axis x, axis y, s): the mean of the xy of `points` (k,3), the unit
    direction of their first principal axis, and their largest singular value about the mean
    (the square root of the larger eigenvalue of their 2x2 scatter, in closed form)."""
    k = points.shape[0]
    cx, cy = 0.0, 0.0
    for i in range(k):
        cx += points[i, 0]
        cy += points[i, 1]
    cx, cy = cx / max(k, 1), cy / max(k, 1)
    a, b, c = 0.0, 0.0, 0.0
    for i in range(k):
        dx, dy = points[i, 0] - cx, points[i, 1] - cy
        a += dx * dx
        b += dx * dy
        c += dy * dy
    half = 0.5 * (a - c)
    root = np.sqrt(half * half + b * b)
    theta = 0.5 * np.arctan2(2.0 * b, a - c)
    return cx, cy, np.cos(theta), np.sin(theta), np.sqrt(max(0.5 * (a + c) + root, 0.0))


@kernel
def reflect_xy(points: np.ndarray, on_line: np.ndarray) -> np.ndarray:
    """`points` (n,3) reflected across the vertical plane through the xy principal axis of
    `on_line` (k,3) (`xy_axis`), in the same frame."""
    cx, cy, ax, ay, _ = xy_axis(on_line)
    nx, ny = -ay, ax
    out = np.empty((points.shape[0], 3))
    for i in range(points.shape[0]):
        d = 2.0 * ((points[i, 0] - cx) * nx + (points[i, 1] - cy) * ny)
        out[i, 0] = points[i, 0] - d * nx
        out[i, 1] = points[i, 1] - d * ny
        out[i, 2] = points[i, 2]
    return out


watch_compiles()  # an install's first compile is said (sgloc.kernels)
