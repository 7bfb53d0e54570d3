"""The acceptance test's search for the best distinct 4-dof alternative in one pass (numba).

The compiled dof=4 branch of `sgloc.acceptance.runner_up`: each drawn pair of candidates fixes
a rotation about z and a translation (as `sgloc.estimation.yaw_from_pairs`); hypotheses within
the distinctness bounds of the estimate are skipped, the others are scored by their inliers
among the free candidates, and the first best one is kept. Residuals are computed directly
(the numpy reference, kept with the tests, expands them into one matrix product): equal to
rounding.
"""

from __future__ import annotations

import numpy as np

from sgloc.kernels import watch_compiles
from sgloc.kernels.dispatch import kernel


@kernel
def support_centre(src: np.ndarray, free: np.ndarray) -> np.ndarray:
    """(3,) the mean of the rows of `src` (m,3) outside `free` (m,) bool, summed in order (of
    every row when all are free)."""
    centre = np.zeros(3)
    n = 0
    for k in range(src.shape[0]):
        if not free[k]:
            n += 1
            for a in range(3):
                centre[a] += src[k, a]
    if n == 0:
        for k in range(src.shape[0]):
            for a in range(3):
                centre[a] += src[k, a]
        n = src.shape[0]
    for a in range(3):
        centre[a] /= max(n, 1)
    return centre


@kernel
def best_yaw_alternative(
    src: np.ndarray,
    dst: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    free: np.ndarray,
    T: np.ndarray,
    distinct_translation: float,
    distinct_rotation: float,
    radius: float,
) -> tuple[int, np.ndarray, bool]:
    """(inliers, 4x4 transform, found) of the best hypothesis from the pairs (i[n], j[n]) of
    candidates src/dst (m,3): pairs less than 1e-6 m apart in xy in either map are skipped, and
    hypotheses moving the centre of T's support (`support_centre`) less than
    `distinct_translation` metres from where T moves it while rotating less than
    `distinct_rotation` degrees from T; inliers: the candidates in `free` (m,) bool with
    squared residual < radius^2. Ties: the first pair drawn."""
    centre = support_centre(src, free)
    R = np.zeros((3, 3))
    R[2, 2] = 1.0
    t = np.zeros(3)
    best_R, best_t = np.eye(3), np.zeros(3)
    best_count, found = -1, False
    r2 = radius * radius
    moved_c = np.zeros(3)
    for a in range(3):
        moved_c[a] = T[a, 0] * centre[0] + T[a, 1] * centre[1] + T[a, 2] * centre[2] + T[a, 3]
    for n in range(i.shape[0]):
        p, q = i[n], j[n]
        es0, es1 = src[q, 0] - src[p, 0], src[q, 1] - src[p, 1]
        ed0, ed1 = dst[q, 0] - dst[p, 0], dst[q, 1] - dst[p, 1]
        if not min(np.sqrt(es0 * es0 + es1 * es1), np.sqrt(ed0 * ed0 + ed1 * ed1)) > 1e-6:
            continue
        theta = np.arctan2(ed1, ed0) - np.arctan2(es1, es0)
        c, s = np.cos(theta), np.sin(theta)
        R[0, 0], R[0, 1], R[1, 0], R[1, 1] = c, -s, s, c
        m0, m1 = (src[p, 0] + src[q, 0]) / 2.0, (src[p, 1] + src[q, 1]) / 2.0
        m2 = (src[p, 2] + src[q, 2]) / 2.0
        for a in range(3):  # the pair's target midpoint minus its rotated source midpoint
            t[a] = (dst[p, a] + dst[q, a]) / 2.0 - (R[a, 0] * m0 + R[a, 1] * m1 + R[a, 2] * m2)
        d2 = 0.0
        for a in range(3):
            e = R[a, 0] * centre[0] + R[a, 1] * centre[1] + R[a, 2] * centre[2] + t[a]
            e -= moved_c[a]
            d2 += e * e
        cosang = 0.0
        for a in range(3):
            for b in range(3):
                cosang += R[a, b] * T[a, b]
        cosang = min(max((cosang - 1.0) / 2.0, -1.0), 1.0)
        turn = np.degrees(np.arccos(cosang))
        if not (np.sqrt(d2) > distinct_translation or turn > distinct_rotation):
            continue
        count = 0
        for k in range(src.shape[0]):
            if free[k]:
                e0 = R[0, 0] * src[k, 0] + R[0, 1] * src[k, 1] + t[0] - dst[k, 0]
                e1 = R[1, 0] * src[k, 0] + R[1, 1] * src[k, 1] + t[1] - dst[k, 1]
                e2 = src[k, 2] + t[2] - dst[k, 2]
                count += e0 * e0 + e1 * e1 + e2 * e2 < r2
        if count > best_count:
            best_count, found = count, True
            # Element by element: a slice assignment compiles numba's shape-mismatch error
            # formatting (seconds of first-use compile).
            for a in range(3):
                best_t[a] = t[a]
                for b in range(3):
                    best_R[a, b] = R[a, b]
    T2 = np.eye(4)
    for a in range(3):
        T2[a, 3] = best_t[a]
        for b in range(3):
            T2[a, b] = best_R[a, b]
    return max(best_count, 0), T2, found


watch_compiles()  # an install's first compile is said (sgloc.kernels)
