"""The spectral rejector's loops (numba): sparse affinities from packed consistency rows, power
iteration, greedy selection."""

from __future__ import annotations

import numpy as np

from sgloc.kernels import watch_compiles
from sgloc.kernels.bits import WORD, cttz
from sgloc.kernels.dispatch import kernel


@kernel
def affinity_csr(
    src: np.ndarray, dst: np.ndarray, bits: np.ndarray, degree: np.ndarray, sigma: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR rows (indptr int64, indices int32, data float32) of the affinity A: 1 on the diagonal,
    exp(-(D(q_i,q_j) - D(t_i,t_j))^2 / (2 sigma^2)) for consistent pairs (set bits), 0 else.
    Distances in float64, column indices ascending."""
    m = src.shape[0]
    indptr = np.zeros(m + 1, dtype=np.int64)
    for i in range(m):
        indptr[i + 1] = indptr[i] + degree[i] + 1
    indices = np.empty(indptr[m], dtype=np.int32)
    data = np.empty(indptr[m], dtype=np.float32)
    inv = -0.5 / (sigma * sigma)
    for i in range(m):
        k = indptr[i]
        diag_done = False
        for w in range(bits.shape[1]):
            x = bits[i, w]
            while x:
                j = w * WORD + np.int64(cttz(x))
                x &= x - np.uint64(1)
                if not diag_done and j > i:
                    indices[k], data[k], k, diag_done = i, 1.0, k + 1, True
                dx, dy, dz = src[i, 0] - src[j, 0], src[i, 1] - src[j, 1], src[i, 2] - src[j, 2]
                ds = np.sqrt(dx * dx + dy * dy + dz * dz)
                ex, ey, ez = dst[i, 0] - dst[j, 0], dst[i, 1] - dst[j, 1], dst[i, 2] - dst[j, 2]
                d = ds - np.sqrt(ex * ex + ey * ey + ez * ez)
                indices[k], data[k] = j, np.exp(inv * d * d)
                k += 1
        if not diag_done:
            indices[k], data[k] = i, 1.0
    return indptr, indices, data


@kernel
def leading_eigenvector(
    indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, iterations: int, tol: float
) -> np.ndarray:
    """Unit leading eigenvector of the symmetric non-negative CSR matrix by power iteration from
    the all-ones vector (the rule of `sgloc.rejection.spectral.leading_eigenvector`)."""
    m = indptr.shape[0] - 1
    x = np.full(m, 1.0 / np.sqrt(m))
    y = np.empty(m)
    for _ in range(iterations):
        norm = 0.0
        for i in range(m):
            s = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                s += data[k] * x[indices[k]]
            y[i] = s
            norm += s * s
        norm = np.sqrt(norm)
        if norm == 0.0:
            return x
        change = 0.0
        for i in range(m):
            y[i] /= norm
            change = max(change, abs(y[i] - x[i]))
        x, y = y, x
        if change < tol:
            return x
    return x


@kernel
def greedy_select(
    x: np.ndarray, order: np.ndarray, bits: np.ndarray, min_ratio: float, min_agreement: float
) -> np.ndarray:
    """The spectral rejector's greedy selection on packed rows: accept by decreasing x (`order`)
    while x_i >= min_ratio * max(x), skipping a match that agrees with fewer than min_agreement
    of those accepted so far. Sorted indices."""
    m = x.shape[0]
    agree = np.zeros(m, dtype=np.int64)
    kept = np.zeros(m, dtype=np.bool_)
    n_kept = 0
    floor = min_ratio * x[order[0]]
    for i in order:
        if x[i] < floor:
            break
        if agree[i] >= min_agreement * n_kept - 1e-9:
            kept[i] = True
            n_kept += 1
            for w in range(bits.shape[1]):
                y = bits[i, w]
                while y:
                    agree[w * WORD + np.int64(cttz(y))] += 1
                    y &= y - np.uint64(1)
    return np.flatnonzero(kept)


watch_compiles()  # an install's first compile is said (sgloc.kernels)
