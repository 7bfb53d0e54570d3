"""RANSAC's hot loops (numba): hypotheses from triplets or pairs, scoring, inliers.

The compiled scorer of `sgloc.estimation.ransac_compiled` (whose adaptive loop, samples and
refits are those of `ransac_reference`): each block of hypotheses is fitted and scored in one
compiled call (no (B,m) residual matrix, no BLAS), for any rigid motion without a gravity gate
(dof=6, max_tilt=None: triplets) and for the ground vehicle's model (dof=4: x, y, z, yaw from
pairs). """

from __future__ import annotations

import numpy as np
from numba import njit

from sgloc.kernels import watch_compiles
from sgloc.kernels.dispatch import kernel


@njit(cache=True, nogil=True, inline="always")
def _non_collinear(p: np.ndarray, ratio: float) -> bool:
    """`sgloc.estimation.non_collinear` for one triplet p (3,3)."""
    e1, e2 = p[1] - p[0], p[2] - p[0]
    c0 = e1[1] * e2[2] - e1[2] * e2[1]
    c1 = e1[2] * e2[0] - e1[0] * e2[2]
    c2 = e1[0] * e2[1] - e1[1] * e2[0]
    area2 = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    longest = max(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2],
                  e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2])  # fmt: skip
    return area2 > ratio * max(longest, 1e-12)


@njit(cache=True, nogil=True, inline="always")
def _frame(p: np.ndarray) -> np.ndarray:
    """Orthonormal frame of a triplet (columns: first edge, normal x edge, normal)."""
    e1 = p[1] - p[0]
    e2 = p[2] - p[0]
    e3 = np.array([e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                   e1[0] * e2[1] - e1[1] * e2[0]])  # fmt: skip
    e1 = e1 / np.sqrt(np.sum(e1 * e1))
    e3 = e3 / np.sqrt(np.sum(e3 * e3))
    F = np.empty((3, 3))
    F[:, 0], F[:, 2] = e1, e3
    F[0, 1] = e3[1] * e1[2] - e3[2] * e1[1]
    F[1, 1] = e3[2] * e1[0] - e3[0] * e1[2]
    F[2, 1] = e3[0] * e1[1] - e3[1] * e1[0]
    return F


@njit(cache=True, nogil=True, inline="always")
def _score(
    R: np.ndarray, t: np.ndarray, src: np.ndarray, dst: np.ndarray, thr2: float, msac: bool
) -> tuple[float, float, int]:
    """(primary, secondary, inlier count) of one hypothesis, ordered as in `ransac`."""
    count, cost, inlier_sum = 0, 0.0, 0.0
    for i in range(src.shape[0]):
        r2 = 0.0
        for a in range(3):
            e = R[a, 0] * src[i, 0] + R[a, 1] * src[i, 1] + R[a, 2] * src[i, 2] + t[a]
            e -= dst[i, a]
            r2 += e * e
        if r2 < thr2:
            count += 1
            cost += r2
            inlier_sum += r2
        else:
            cost += thr2
    if msac:
        return cost, float(-count), count
    return float(-count), inlier_sum, count


@njit(cache=True, nogil=True, inline="always")
def _set_pose(T: np.ndarray, R: np.ndarray, t: np.ndarray) -> None:
    """T[:3, :3], T[:3, 3] = R, t, element by element (a slice assignment compiles numba's
    shape-mismatch error formatting: seconds of first-use compile for nothing)."""
    for a in range(3):
        for b in range(3):
            T[a, b] = R[a, b]
        T[a, 3] = t[a]


@kernel
def score_block(
    src: np.ndarray, dst: np.ndarray, samples: np.ndarray, thr2: float, msac: bool, ratio: float
) -> tuple[bool, float, float, np.ndarray, int]:
    """Fit and score the hypotheses of `samples` (n,3) on centred src, dst (m,3).

    Returns (found, primary, secondary, T, max_count): the best hypothesis by (primary,
    secondary), first on ties, as `sgloc.estimation.ransac` orders them (msac: truncated cost,
    then -count; count: -count, then inlier residual), its 4x4 T, and the largest inlier count
    of the block (for the adaptive stop); found=False when every sample is collinear (twice
    its area at most `ratio` times its longest side squared, in source or target).
    """
    best_p, best_s, found, max_count = np.inf, np.inf, False, 0
    best_T = np.eye(4)
    S, D = np.empty((3, 3)), np.empty((3, 3))
    for b in range(samples.shape[0]):
        for k in range(3):
            S[k], D[k] = src[samples[b, k]], dst[samples[b, k]]
        if not (_non_collinear(S, ratio) and _non_collinear(D, ratio)):
            continue
        Fd, Fs = _frame(D), _frame(S)
        R = np.empty((3, 3))
        for a in range(3):
            for c in range(3):
                R[a, c] = Fd[a, 0] * Fs[c, 0] + Fd[a, 1] * Fs[c, 1] + Fd[a, 2] * Fs[c, 2]
        cs, cd = (S[0] + S[1] + S[2]) / 3.0, (D[0] + D[1] + D[2]) / 3.0
        t = np.empty(3)
        for a in range(3):
            t[a] = cd[a] - (R[a, 0] * cs[0] + R[a, 1] * cs[1] + R[a, 2] * cs[2])
        primary, secondary, count = _score(R, t, src, dst, thr2, msac)
        max_count = max(max_count, count)
        if not found or primary < best_p or (primary == best_p and secondary < best_s):
            best_p, best_s, found = primary, secondary, True
            _set_pose(best_T, R, t)
    return found, best_p, best_s, best_T, max_count


@kernel
def score_pair_block(
    src: np.ndarray, dst: np.ndarray, pairs: np.ndarray, thr2: float, msac: bool, max_gap: float
) -> tuple[bool, float, float, np.ndarray, int]:
    """`score_block` for 4-dof hypotheses from the match pairs `pairs` (n,2): the yaw turns
    the source pair's xy direction onto the target pair's, the translation maps the source
    pair's midpoint onto the target's (`sgloc.estimation.yaw_from_pairs`). Pairs closer than
    1e-6 m in xy, or whose xy lengths differ by `max_gap` or more, give no hypothesis."""
    best_p, best_s, found, max_count = np.inf, np.inf, False, 0
    best_T = np.eye(4)
    R = np.zeros((3, 3))
    R[2, 2] = 1.0
    t, ms, md = np.empty(3), np.empty(3), np.empty(3)
    for b in range(pairs.shape[0]):
        i, j = pairs[b, 0], pairs[b, 1]
        esx, esy = src[j, 0] - src[i, 0], src[j, 1] - src[i, 1]
        edx, edy = dst[j, 0] - dst[i, 0], dst[j, 1] - dst[i, 1]
        ls, ld = np.sqrt(esx * esx + esy * esy), np.sqrt(edx * edx + edy * edy)
        if not (min(ls, ld) > 1e-6 and abs(ls - ld) < max_gap):
            continue
        theta = np.arctan2(edy, edx) - np.arctan2(esy, esx)
        c, s = np.cos(theta), np.sin(theta)
        R[0, 0], R[0, 1], R[1, 0], R[1, 1] = c, -s, s, c
        for a in range(3):
            ms[a], md[a] = (src[i, a] + src[j, a]) / 2.0, (dst[i, a] + dst[j, a]) / 2.0
        for a in range(3):
            t[a] = md[a] - (R[a, 0] * ms[0] + R[a, 1] * ms[1] + R[a, 2] * ms[2])
        primary, secondary, count = _score(R, t, src, dst, thr2, msac)
        max_count = max(max_count, count)
        if not found or primary < best_p or (primary == best_p and secondary < best_s):
            best_p, best_s, found = primary, secondary, True
            _set_pose(best_T, R, t)
    return found, best_p, best_s, best_T, max_count


@kernel
def inliers(T: np.ndarray, src: np.ndarray, dst: np.ndarray, thr2: float) -> np.ndarray:
    """Sorted indices i with ||R src_i + t - dst_i||^2 < thr2."""
    keep = np.zeros(src.shape[0], dtype=np.bool_)
    for i in range(src.shape[0]):
        r2 = 0.0
        for a in range(3):
            e = T[a, 0] * src[i, 0] + T[a, 1] * src[i, 1] + T[a, 2] * src[i, 2] + T[a, 3]
            e -= dst[i, a]
            r2 += e * e
        keep[i] = r2 < thr2
    return np.flatnonzero(keep)


watch_compiles()  # an install's first compile is said (sgloc.kernels)
