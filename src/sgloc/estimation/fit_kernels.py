"""Small rigid fits without BLAS or LAPACK calls (numba): weighted Kabsch and the Tukey IRLS
(also with per-class residual scales and the anisotropic Gauss-Newton fit).

They compute what `sgloc.estimation.weighted_kabsch` (less its input checks) and
`sgloc.estimation.irls_refine` compute, with the same decisions, in compiled loops: no numpy
dispatch per step, no BLAS thread pool for 3-column products. The 3x3 SVD is a cyclic Jacobi
eigen-decomposition of H^T H (fast to compile, unlike numba's LAPACK bindings).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sgloc.kernels import watch_compiles
from sgloc.kernels.constants import COLLINEAR_WIDTH, MAD_SCALE, TUKEY_C
from sgloc.kernels.dispatch import kernel


@njit(cache=True, nogil=True, inline="always")
def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])  # fmt: skip


@kernel
def median(x: np.ndarray) -> float:
    """np.median of a 1-d float64 array (Hoare quickselect on a copy)."""
    a = x.copy()
    n = a.shape[0]
    hi_k = n // 2
    _select(a, hi_k)
    if n % 2:
        return a[hi_k]
    lo = a[0]
    for i in range(hi_k):  # the lower middle: the largest of the left part
        lo = max(lo, a[i])
    return (lo + a[hi_k]) / 2.0


@kernel(writes=("a",))
def _select(a: np.ndarray, k: int) -> None:
    """Reorder a so that a[k] is its k-th smallest, smaller ones before, larger after."""
    lo, hi = 0, a.shape[0] - 1
    while lo < hi:
        pivot = a[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return


@kernel
def _symmetric_eigen(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (descending) and eigenvectors (columns) of a symmetric 3x3 A (cyclic
    Jacobi rotations until the off-diagonal vanishes to rounding)."""
    A = A.copy()
    V = np.eye(3)
    for _ in range(50):
        off = A[0, 1] ** 2 + A[0, 2] ** 2 + A[1, 2] ** 2
        if off <= 1e-36 * (A[0, 0] ** 2 + A[1, 1] ** 2 + A[2, 2] ** 2) or off == 0.0:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if A[p, q] == 0.0:
                continue
            theta = (A[q, q] - A[p, p]) / (2.0 * A[p, q])
            t = np.sign(theta) / (abs(theta) + np.sqrt(theta * theta + 1.0))
            if theta == 0.0:
                t = 1.0
            c = 1.0 / np.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):  # A <- J^T A J, V <- V J
                akp, akq = A[k, p], A[k, q]
                A[k, p], A[k, q] = c * akp - s * akq, s * akp + c * akq
            for k in range(3):
                apk, aqk = A[p, k], A[q, k]
                A[p, k], A[q, k] = c * apk - s * aqk, s * apk + c * aqk
            for k in range(3):
                vkp, vkq = V[k, p], V[k, q]
                V[k, p], V[k, q] = c * vkp - s * vkq, s * vkp + c * vkq
    w = np.array([A[0, 0], A[1, 1], A[2, 2]])
    order = np.array([0, 1, 2])
    for a, b in ((0, 1), (1, 2), (0, 1)):  # sort 3 values, descending
        if w[order[b]] > w[order[a]]:
            order[a], order[b] = order[b], order[a]
    return w[order], V[:, order]


@kernel
def rotation_from_covariance(H: np.ndarray) -> np.ndarray:
    """The rotation R maximising trace(R H) (Kabsch: H = sum w (s - cs)(d - cd)^T), as
    V diag(1, 1, det) U^T from H = U S V^T. It is unique when H has rank >= 2 (non-collinear
    points); otherwise one of the rotations that fit equally well (identity when H = 0).

    With proper bases (third columns the cross products of the first two) the reflection
    guard is implicit: R = V' U'^T."""
    HtH = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            HtH[a, b] = H[0, a] * H[0, b] + H[1, a] * H[1, b] + H[2, a] * H[2, b]
    _, V = _symmetric_eigen(HtH)
    v1, v2 = V[:, 0].copy(), V[:, 1].copy()
    u1, u2 = np.zeros(3), np.zeros(3)
    for a in range(3):
        u1[a] = H[a, 0] * v1[0] + H[a, 1] * v1[1] + H[a, 2] * v1[2]
        u2[a] = H[a, 0] * v2[0] + H[a, 1] * v2[1] + H[a, 2] * v2[2]
    n1 = np.sqrt(np.sum(u1 * u1))
    if not n1 > 0.0:  # H = 0 (e.g. every match on one target point): any rotation fits
        return np.eye(3)
    u1 /= n1
    u2 -= np.sum(u1 * u2) * u1
    n2 = np.sqrt(np.sum(u2 * u2))
    if not n2 > 1e-12 * n1:  # rank 1: the rotation about u1 is free; complete the basis
        u2[:] = 0.0
        u2[np.argmin(np.abs(u1))] = 1.0
        u2 -= np.sum(u1 * u2) * u1
        n2 = np.sqrt(np.sum(u2 * u2))
    u2 /= n2
    v2 -= np.sum(v1 * v2) * v1
    v2 /= np.sqrt(np.sum(v2 * v2))
    v3, u3 = _cross(v1, v2), _cross(u1, u2)
    R = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            R[a, b] = v1[a] * u1[b] + v2[a] * u2[b] + v3[a] * u3[b]
    return R


@kernel
def _centroids(
    src: np.ndarray, dst: np.ndarray, weights: np.ndarray, total: float
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted centroids of src and dst (m,3), weights (m,) summing to `total` (the caller's
    sum: kabsch and yaw_fit each keep their own summation order, hence their rounding)."""
    cs, cd = np.zeros(3), np.zeros(3)
    for i in range(src.shape[0]):
        wi = weights[i] / total
        for a in range(3):
            cs[a] += wi * src[i, a]
            cd[a] += wi * dst[i, a]
    return cs, cd


@kernel
def kabsch(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """T_dst_src (4x4) minimising sum_i w_i ||R src_i + t - dst_i||^2 (reflection guarded);
    src, dst (m,3) float64, weights (m,) with a positive sum."""
    m = src.shape[0]
    total = 0.0
    for i in range(m):
        total += weights[i]
    cs, cd = _centroids(src, dst, weights, total)
    H = np.zeros((3, 3))
    for i in range(m):
        wi = weights[i] / total
        for a in range(3):
            sa = (src[i, a] - cs[a]) * wi
            for b in range(3):
                H[a, b] += sa * (dst[i, b] - cd[b])
    R = rotation_from_covariance(H)
    T = np.zeros((4, 4))
    for a in range(3):
        for b in range(3):
            T[a, b] = R[a, b]
        T[a, 3] = cd[a] - (R[a, 0] * cs[0] + R[a, 1] * cs[1] + R[a, 2] * cs[2])
    T[3, 3] = 1.0
    return T


@kernel
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


@kernel
def collinear(points: np.ndarray, ratio: float) -> bool:
    """`sgloc.estimation._collinear`: fewer than 3 points, or the second principal extent
    under `ratio` times the first and its standard deviation under COLLINEAR_WIDTH metres."""
    m = points.shape[0]
    if m < 3:
        return True
    mean = np.zeros(3)
    for i in range(m):
        for a in range(3):
            mean[a] += points[i, a]
    mean /= m
    C = np.zeros((3, 3))
    for i in range(m):
        for a in range(3):
            for b in range(3):
                C[a, b] += (points[i, a] - mean[a]) * (points[i, b] - mean[b])
    ev, _ = _symmetric_eigen(C)
    second = max(ev[1], 0.0)
    thin = second < COLLINEAR_WIDTH * COLLINEAR_WIDTH * m
    return ev[0] <= 0.0 or (np.sqrt(second / ev[0]) < ratio and thin)


@kernel
def yaw_fit(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """`sgloc.estimation.yaw_fit`: the weighted least-squares rotation about z and shift."""
    m = src.shape[0]
    total = weights.sum()
    cs, cd = _centroids(src, dst, weights, total)
    cross, dot = 0.0, 0.0
    for i in range(m):
        wi = weights[i] / total
        ax, ay = (src[i, 0] - cs[0]) * wi, (src[i, 1] - cs[1]) * wi
        bx, by = dst[i, 0] - cd[0], dst[i, 1] - cd[1]
        cross += ax * by - ay * bx
        dot += ax * bx + ay * by
    theta = np.arctan2(cross, dot)
    c, s = np.cos(theta), np.sin(theta)
    T = np.eye(4)
    T[0, 0], T[0, 1], T[1, 0], T[1, 1] = c, -s, s, c
    T[0, 3] = cd[0] - (c * cs[0] - s * cs[1])
    T[1, 3] = cd[1] - (s * cs[0] + c * cs[1])
    T[2, 3] = cd[2] - cs[2]
    return T


@kernel
def fit_model(
    src: np.ndarray, dst: np.ndarray, weights: np.ndarray, dof: int, max_tilt: float
) -> np.ndarray:
    """`sgloc.estimation.fit_rigid` (no input checks); max_tilt <= 0 stands for None / 0:
    dof=4 then fits the yaw only."""
    if dof != 4:
        return kabsch(src, dst, weights)
    if max_tilt > 0.0 and not collinear(src, 1e-3):
        T = kabsch(src, dst, weights)
        if np.degrees(np.arccos(min(max(T[2, 2], -1.0), 1.0))) <= max_tilt:
            return T
    return yaw_fit(src, dst, weights)


@kernel
def _biweight_step(
    u: np.ndarray, prior: np.ndarray, w_prev: np.ndarray, have_prev: bool
) -> tuple[np.ndarray, bool]:
    """One IRLS reweighting: Tukey biweights prior * (1 - u^2)^2 of the scaled residuals u, and
    whether to stop (fewer than 3 positive weights, or no weight moved by more than 1e-6)."""
    m = u.shape[0]
    w = np.empty(m)
    n_pos = 0
    for i in range(m):
        w[i] = prior[i] * ((1.0 - u[i] * u[i]) ** 2 if u[i] < 1.0 else 0.0)
        n_pos += w[i] != 0.0
    if n_pos < 3:
        return w, True
    if not have_prev:
        return w, False
    for i in range(m):
        if not abs(w[i] - w_prev[i]) <= 1e-6:
            return w, False
    return w, True


@kernel
def irls_model(
    src: np.ndarray,
    dst: np.ndarray,
    T: np.ndarray,
    prior: np.ndarray,
    iterations: int,
    dof: int,
    max_tilt: float,
) -> np.ndarray:
    """`irls` under the motion model of `fit_model` (`sgloc.estimation.irls_refine` with
    dof and max_tilt, without per-class scales)."""
    T = T.copy()  # the loop's estimate (the argument may be read-only)
    m = src.shape[0]
    w_prev = np.zeros(m)
    have_prev = False
    for _ in range(iterations):
        r = residual_norms(src, dst, T)
        sigma = MAD_SCALE * median(r)
        if sigma <= 1e-12:
            break
        w, stop = _biweight_step(r / (TUKEY_C * sigma), prior, w_prev, have_prev)
        if stop:
            break
        w_prev, have_prev = w, True
        T_new = fit_model(src, dst, w, dof, max_tilt)
        change = 0.0
        for a in range(4):
            for b in range(4):
                change = max(change, abs(T_new[a, b] - T[a, b]))
        T = T_new
        if change < 1e-9:
            break
    return T


@kernel
def irls(
    src: np.ndarray, dst: np.ndarray, T: np.ndarray, prior: np.ndarray, iterations: int
) -> np.ndarray:
    """Tukey-biweight IRLS refit of T_dst_src from T (the rule of
    `sgloc.estimation.irls_refine`: c = 4.685 sigma, sigma = 1.4826 median residual): the
    6-dof case of `irls_model`."""
    return irls_model(src, dst, T, prior, iterations, 6, 0.0)


@kernel
def class_scales(
    d: np.ndarray, cls: np.ndarray, n_cls: int, sigma: float, height_only: bool,
    min_matches: int, min_ratio: float,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """`sgloc.estimation.class_scales` with classes given as 0..n_cls-1 (`cls`, (m,))."""
    m = d.shape[0]
    h, v = np.empty(m), np.empty(m)
    for i in range(m):
        h[i] = np.sqrt((d[i, 0] ** 2 + d[i, 1] ** 2) / 2.0)
        v[i] = abs(d[i, 2])
    floor = max(min_ratio * sigma, 1e-9)
    all_xy, all_z = MAD_SCALE * median(h), MAD_SCALE * median(v)
    counts = np.zeros(n_cls, np.int64)
    for i in range(m):
        counts[cls[i]] += 1
    sxy_c, sz_c = np.empty(n_cls), np.empty(n_cls)
    for c in range(n_cls):
        sxy_c[c], sz_c[c] = all_xy, all_z
        if counts[c] >= min_matches:
            hc, vc = np.empty(counts[c]), np.empty(counts[c])
            k = 0
            for i in range(m):
                if cls[i] == c:
                    hc[k], vc[k] = h[i], v[i]
                    k += 1
            if not height_only:
                sxy_c[c] = MAD_SCALE * median(hc)
            sz_c[c] = MAD_SCALE * median(vc)
    s_xy, s_z = np.empty(m), np.empty(m)
    for i in range(m):
        s_xy[i] = max(sxy_c[cls[i]], floor)
        s_z[i] = max(sz_c[cls[i]], floor)
    return s_xy, s_z


@kernel
def _solve(H: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, bool]:
    """x with H x = g (k x k, Gaussian elimination with partial pivoting); ok False when H is
    singular to working precision."""
    k = H.shape[0]
    A = H.copy()
    b = g.copy()
    scale = 0.0
    for a in range(k):
        for c in range(k):
            scale = max(scale, abs(A[a, c]))
    for col in range(k):
        p = col
        for r in range(col + 1, k):
            if abs(A[r, col]) > abs(A[p, col]):
                p = r
        if abs(A[p, col]) <= 1e-14 * scale or scale == 0.0:
            return b, False
        if p != col:
            for c in range(k):
                A[col, c], A[p, c] = A[p, c], A[col, c]
            b[col], b[p] = b[p], b[col]
        for r in range(col + 1, k):
            f = A[r, col] / A[col, col]
            for c in range(col, k):
                A[r, c] -= f * A[col, c]
            b[r] -= f * b[col]
    x = np.zeros(k)
    for r in range(k - 1, -1, -1):
        s = b[r]
        for c in range(r + 1, k):
            s -= A[r, c] * x[c]
        x[r] = s / A[r, r]
    return x, True


@kernel
def _rotvec_matrix(v: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation (3,3) by angle |v| about v / |v| (the compiled form of
    `sgloc.lie.so3_exp`, equal to rounding; no module outside the kernels is imported here)."""
    a = np.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    R = np.eye(3)
    if a < 1e-15:
        return R
    k = v / a
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return R + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)


@kernel
def anisotropic_fit(
    src: np.ndarray, dst: np.ndarray, T: np.ndarray, w_xy: np.ndarray, w_z: np.ndarray,
    dof: int, max_tilt: float, steps: int,
) -> np.ndarray:  # fmt: skip
    """`sgloc.estimation.anisotropic_fit`; max_tilt <= 0 stands for None."""
    m = src.shape[0]
    full = dof != 4 or max_tilt > 0.0
    first = 0 if full else 2  # dof=4 without a tolerance: yaw (column 2) and translation
    k = 6 - first
    T = T.copy()
    for _ in range(steps):
        p = np.empty((m, 3))
        for i in range(m):
            for a in range(3):
                p[i, a] = T[a, 0] * src[i, 0] + T[a, 1] * src[i, 1] + T[a, 2] * src[i, 2]
                p[i, a] += T[a, 3]
        wsum, c = 0.0, np.zeros(3)
        for i in range(m):
            wsum += w_xy[i]
            for a in range(3):
                c[a] += w_xy[i] * p[i, a]
        c /= max(wsum, 1e-300)
        H, g = np.zeros((k, k)), np.zeros(k)
        J = np.zeros((3, 6))
        for i in range(m):
            q0, q1, q2 = p[i, 0] - c[0], p[i, 1] - c[1], p[i, 2] - c[2]
            J[0, 1], J[0, 2], J[1, 0], J[1, 2], J[2, 0], J[2, 1] = q2, -q1, -q2, q0, q1, -q0
            J[0, 3] = J[1, 4] = J[2, 5] = 1.0
            for a in range(3):
                wa = w_z[i] if a == 2 else w_xy[i]
                ra = dst[i, a] - p[i, a]
                for r in range(k):
                    jr = J[a, first + r] * wa
                    g[r] += jr * ra
                    for s in range(k):
                        H[r, s] += jr * J[a, first + s]
        xk, ok = _solve(H, g)
        if not ok:
            break
        x = np.zeros(6)
        x[first:] = xk
        dR = _rotvec_matrix(x[:3])
        R = dR @ np.ascontiguousarray(T[:3, :3])
        tilt = np.degrees(np.arccos(min(max(R[2, 2], -1.0), 1.0)))
        if full and max_tilt > 0.0 and tilt > max_tilt:
            break
        t_new = dR @ (T[:3, 3] - c) + c + x[3:]
        T[:3, :3] = R
        T[:3, 3] = t_new
        if np.abs(x).max() < 1e-12:
            break
    return T


@kernel
def irls_class_scaled(
    src: np.ndarray, dst: np.ndarray, T: np.ndarray, prior: np.ndarray, cls: np.ndarray,
    n_cls: int, height_only: bool, iterations: int, dof: int, max_tilt: float,
    min_matches: int, min_ratio: float,
) -> np.ndarray:  # fmt: skip
    """`sgloc.estimation.irls_refine` with per-class residual scales (`classes` as 0..n_cls-1
    in `cls`; max_tilt <= 0 stands for None)."""
    T = T.copy()  # the loop's estimate (the argument may be read-only)
    m = src.shape[0]
    w_prev = np.zeros(m)
    have_prev = False
    for _ in range(iterations):
        d = np.empty((m, 3))
        r = np.empty(m)
        for i in range(m):
            for a in range(3):
                d[i, a] = (T[a, 0] * src[i, 0] + T[a, 1] * src[i, 1] + T[a, 2] * src[i, 2]
                           + T[a, 3] - dst[i, a])  # fmt: skip
            r[i] = np.sqrt(d[i, 0] ** 2 + d[i, 1] ** 2 + d[i, 2] ** 2)
        sigma = MAD_SCALE * median(r)
        if sigma <= 1e-12:
            break
        s_xy, s_z = class_scales(d, cls, n_cls, sigma, height_only, min_matches, min_ratio)
        u = np.sqrt((d[:, 0] ** 2 + d[:, 1] ** 2) / s_xy**2 + d[:, 2] ** 2 / s_z**2) / TUKEY_C
        w, stop = _biweight_step(u, prior, w_prev, have_prev)
        if stop:
            break
        w_prev, have_prev = w, True
        T_new = anisotropic_fit(src, dst, T, w / s_xy**2, w / s_z**2, dof, max_tilt, 5)
        change = np.abs(T_new - T).max()
        T = T_new
        if change < 1e-9:
            break
    return T


watch_compiles()  # an install's first compile is said (sgloc.kernels)
