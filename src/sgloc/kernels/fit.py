"""Small rigid fits without BLAS calls (numba): weighted Kabsch and the Tukey IRLS refit.

They compute what `sgloc.estimation.weighted_kabsch` (less its input checks) and
`sgloc.estimation.irls_refine` compute, with the same decisions, in compiled loops: no numpy
dispatch per step and no BLAS thread pool for 3-column products.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def kabsch(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """T_dst_src (4x4) minimising sum_i w_i ||R src_i + t - dst_i||^2 (reflection guarded);
    src, dst (m,3) float64, weights (m,) with a positive sum."""
    m = src.shape[0]
    total = 0.0
    for i in range(m):
        total += weights[i]
    w = weights / total
    cs, cd = np.zeros(3), np.zeros(3)
    for i in range(m):
        for a in range(3):
            cs[a] += w[i] * src[i, a]
            cd[a] += w[i] * dst[i, a]
    H = np.zeros((3, 3))
    for i in range(m):
        for a in range(3):
            sa = (src[i, a] - cs[a]) * w[i]
            for b in range(3):
                H[a, b] += sa * (dst[i, b] - cd[b])
    U, _, Vt = np.linalg.svd(H)
    V, Ut = Vt.T.copy(), U.T.copy()
    d = np.sign(np.linalg.det(V @ Ut))
    if d == 0.0:
        d = 1.0
    V[:, 2] *= d
    R = V @ Ut
    T = np.eye(4)
    T[:3, :3] = R
    for a in range(3):
        T[a, 3] = cd[a] - (R[a, 0] * cs[0] + R[a, 1] * cs[1] + R[a, 2] * cs[2])
    return T


@njit(cache=True, nogil=True)
def residual_norms(src: np.ndarray, dst: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(m,) ||R src_i + t - dst_i|| in metres."""
    m = src.shape[0]
    r = np.empty(m)
    for i in range(m):
        s = 0.0
        for a in range(3):
            e = T[a, 0] * src[i, 0] + T[a, 1] * src[i, 1] + T[a, 2] * src[i, 2] + T[a, 3]
            e -= dst[i, a]
            s += e * e
        r[i] = np.sqrt(s)
    return r


@njit(cache=True, nogil=True)
def irls(
    src: np.ndarray, dst: np.ndarray, T: np.ndarray, prior: np.ndarray, iterations: int
) -> np.ndarray:
    """Tukey-biweight IRLS refit of T_dst_src from T (the rule of
    `sgloc.estimation.irls_refine`: c = 4.685 sigma, sigma = 1.4826 median residual)."""
    m = src.shape[0]
    w_prev = np.full(m, np.nan)
    have_prev = False
    for _ in range(iterations):
        r = residual_norms(src, dst, T)
        sigma = 1.4826 * np.median(r)
        if sigma <= 1e-12:
            break
        c = 4.685 * sigma
        w = np.empty(m)
        n_pos = 0
        for i in range(m):
            u = r[i] / c
            w[i] = prior[i] * ((1.0 - u * u) ** 2 if u < 1.0 else 0.0)
            n_pos += w[i] != 0.0
        if n_pos < 3:
            break
        if have_prev:
            same = True
            for i in range(m):
                if not abs(w[i] - w_prev[i]) <= 1e-6:
                    same = False
                    break
            if same:
                break
        w_prev, have_prev = w, True
        T_new = kabsch(src, dst, w)
        done = np.abs(T_new - T).max() < 1e-9
        T = T_new
        if done:
            break
    return T
