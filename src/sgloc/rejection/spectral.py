"""Spectral outlier rejection (Leordeanu and Hebert, ICCV 2005), on pairwise distance consistency.

The matches form a graph whose edge weights say how well two matches agree on their pair's
distance: A_ij = exp(-(D(q_i,q_j) - D(t_i,t_j))^2 / (2 sigma^2)) when the difference is below
tau, else 0 (A_ii = 1). The correct matches form a strongly connected cluster, which the leading
eigenvector of A picks out (large entries). Matches are then accepted greedily by decreasing
entry, skipping any that disagrees (difference >= tau) with too many already accepted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from sgloc.consistency.pairwise import consistency_bits, consistent_blocks
from sgloc.rejection.base import Rejector
from sgloc.validation import MAX_COORDINATE, real, setting

#: Above this many matches the affinity is held as a sparse matrix instead of a dense float32.
DENSE_LIMIT = 3000


def affinity_and_consistency(
    src: np.ndarray, dst: np.ndarray, tau: float, sigma: float
) -> tuple[np.ndarray | sparse.csr_array, np.ndarray]:
    """(A, M): the soft affinity (m,m) with a unit diagonal (dense float32, or CSR when
    m > DENSE_LIMIT) and the hard consistency M (m,m) bool, diagonal False."""
    m = len(src)
    M = np.empty((m, m), dtype=bool)
    dense = m <= DENSE_LIMIT
    A = np.zeros((m, m), dtype=np.float32) if dense else None
    parts_i, parts_j, parts_w = [], [], []
    inv = np.float32(-0.5 / sigma**2)
    for rows, cols, ok, diff in consistent_blocks(src, dst, tau, "distance"):
        M[rows, cols] = ok
        M[cols, rows] = ok.T
        w = np.where(ok, np.exp(inv * diff * diff), np.float32(0.0))
        if dense:
            A[rows, cols] = w
            A[cols, rows] = w.T
        else:
            bi, bj = np.nonzero(ok)
            gi, gj = bi + rows.start, bj + cols.start
            off = gi != gj
            if rows.start == cols.start:  # diagonal tile: both orientations are already in it
                parts_i.append(gi[off])
                parts_j.append(gj[off])
                parts_w.append(w[bi, bj][off])
            else:
                parts_i += [gi, gj]
                parts_j += [gj, gi]
                parts_w += [w[bi, bj]] * 2
    np.fill_diagonal(M, False)
    if dense:
        np.fill_diagonal(A, 1.0)
        return A, M
    diag = np.arange(m)
    i = np.concatenate([*parts_i, diag])
    j = np.concatenate([*parts_j, diag])
    w = np.concatenate([*parts_w, np.ones(m, dtype=np.float32)])
    return sparse.csr_array((w, (i, j)), shape=(m, m)), M


def leading_eigenvector(
    A: np.ndarray | sparse.csr_array, iterations: int = 200, tol: float = 1e-6
) -> np.ndarray:
    """Leading eigenvector (unit norm, non-negative) of a symmetric non-negative matrix by power
    iteration from the all-ones vector."""
    m = A.shape[0]
    x = np.full(m, 1.0 / np.sqrt(m), dtype=np.float32)
    for _ in range(iterations):
        y = A @ x
        n = np.linalg.norm(y)
        if n == 0:
            return x
        y /= n
        if np.abs(y - x).max() < tol:
            return y
        x = y
    return x


def greedy_select(
    x: np.ndarray, M: np.ndarray, min_ratio: float, min_agreement: float
) -> np.ndarray:
    """Accept matches by decreasing x while x_i >= min_ratio * max(x), skipping a match that
    agrees (M) with fewer than min_agreement of those already accepted. Sorted indices."""
    m = len(x)
    if m == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.argsort(-x, kind="stable")
    floor = min_ratio * float(x[order[0]])
    agree = np.zeros(m, dtype=np.int32)
    kept: list[int] = []
    for i in order.tolist():
        if x[i] < floor:
            break
        if agree[i] >= min_agreement * len(kept) - 1e-9:
            kept.append(i)
            agree += M[i]
    return np.sort(np.asarray(kept, dtype=np.int64))


@dataclass
class SpectralRejector(Rejector):
    """Leading-eigenvector (spectral matching) rejection of inconsistent matches.

    tau: metres; pairs whose distances differ by tau or more get no affinity and count as
        disagreeing in the greedy selection.
    sigma: metres, width of the Gaussian affinity on the distance difference.
    min_ratio: stop the greedy selection when the eigenvector entry drops below this fraction
        of the largest one.
    min_agreement: a match is accepted when it agrees with at least this fraction of the matches
        accepted before it (1.0: with all of them, the classic mutual consistency).
    """

    tau: float = setting(5.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    sigma: float = setting(2.5, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    min_ratio: float = setting(0.1, check=real(0.0, 1.0))
    min_agreement: float = setting(0.9, check=real(0.0, 1.0))
    name = "spectral"

    def __call__(self, src, dst, scores=None):
        """Compiled (`sgloc.rejection.spectral_kernels`); `reference` is the plain numpy version."""
        if len(src) == 0:
            return np.zeros(0, dtype=np.int64)
        from sgloc.rejection import spectral_kernels as kernels

        src = np.ascontiguousarray(src, dtype=np.float64)
        dst = np.ascontiguousarray(dst, dtype=np.float64)
        bits, degree = consistency_bits(src, dst, self.tau, "distance")
        csr = kernels.affinity_csr(src, dst, bits, degree, float(self.sigma))
        x = kernels.leading_eigenvector(*csr, 200, 1e-6)
        order = np.argsort(-x, kind="stable")
        return kernels.greedy_select(x, order, bits, self.min_ratio, self.min_agreement)

    def reference(self, src, dst, scores=None):
        """The same selection in numpy (float32 affinities from the tiles)."""
        if len(src) == 0:
            return np.zeros(0, dtype=np.int64)
        A, M = affinity_and_consistency(src, dst, self.tau, self.sigma)
        x = leading_eigenvector(A)
        return greedy_select(x, M, self.min_ratio, self.min_agreement)
