"""Numpy references of the rejectors' kernels: the neighbor rejector's pruning
(`sgloc.rejection.prune_kernels`: Alg. 1 step 2 with the "remaining" bound on a dense
consistency matrix), the spectral rejector (`sgloc.rejection.spectral_kernels`: float32
affinities from the tiles of `references.consistency.consistent_blocks`) and the clique
rejector's core numbers and greedy growth (`sgloc.rejection.clique_kernels`)."""

from __future__ import annotations

import numpy as np
from scipy import sparse

from references.consistency import consistent_blocks
from sgloc.rejection.clique import CliqueRejector, exact_clique
from sgloc.rejection.spectral import SpectralRejector

#: Removed matches get this support, far above any real count (V_i <= m - 1) and immune to
#: the decrements of later removals.
_REMOVED = 1 << 30

#: Up to this many remaining matches, M is widened to int16 rows so that each update is a plain
#: int16 subtraction (2 x m^2 bytes: 32 MB at this size); above, uint8 rows are cast on the fly.
_WIDE_LIMIT = 4096


def prune_by_support(M: np.ndarray, eta: float) -> np.ndarray:
    """Alg. 1 step 2 in numpy on a consistency matrix M (m,m) with a False diagonal (the
    reference of `sgloc.rejection.neighbor.prune_by_support`, bound="remaining").

    While the remaining match with the least support V_i (number of other remaining matches it
    agrees with) has V_i < eta * (r - 1), r the number of matches still remaining, remove it and
    update V -= M[i] (O(r) per removal). Ties go to the lowest index. Returns the sorted indices
    of the survivors.

    The bound shrinks with r: against the original m every match ends up removed.
    M_ii does not count: a match does not vouch for itself, so V_i ranges over 0..r-1.
    Supports are int32 (int16 once at most 4096 remain, with M as int16 rows; uint8 rows before)
    and M is compacted to the survivors whenever half of the rows it holds are gone, so a
    removal costs O(r), not O(m).
    """
    m = M.shape[0]
    if m == 0:
        return np.zeros(0, dtype=np.int64)
    M = M.view(np.uint8) if M.dtype == np.bool_ else (M != 0).view(np.uint8)
    V = M.sum(axis=1, dtype=np.int32)
    ids = np.arange(m)
    r = m
    # (Bound methods and .item(): this loop is Python-overhead bound.)
    argmin, item = V.argmin, V.item
    while r > 1 and len(V) > _WIDE_LIMIT:
        i = argmin()
        if item(i) >= eta * (r - 1):
            return ids[V < _REMOVED // 2]
        np.subtract(V, M[i], out=V, casting="unsafe")
        V[i] = _REMOVED
        r -= 1
        if r <= len(V) // 2:
            keep = np.flatnonzero(V < _REMOVED // 2)
            M, V, ids = M[np.ix_(keep, keep)], V[keep], ids[keep]
            argmin, item = V.argmin, V.item
    # int16 rows and supports from here on (m <= _WIDE_LIMIT < 2^13): removed ones sit at 2^14
    # and stay above 2^13 whatever is subtracted later.
    W = M.astype(np.int16)
    del M
    gone = np.int16(1 << 14)
    V = np.where(V < _REMOVED // 2, V, gone).astype(np.int16)
    argmin, item, subtract = V.argmin, V.item, np.subtract
    while r > 1:
        i = argmin()
        if item(i) >= eta * (r - 1):
            break
        subtract(V, W[i], out=V)
        V[i] = gone
        r -= 1
        if r <= len(V) // 2 and len(V) > 64:
            keep = np.flatnonzero(V < gone // 2)
            W, V, ids = W[np.ix_(keep, keep)], V[keep], ids[keep]
            argmin, item = V.argmin, V.item
    return ids[V < gone // 2]


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


def spectral(rej: SpectralRejector, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """`rej(src, dst)` in numpy (float32 affinities from the tiles)."""
    if len(src) == 0:
        return np.zeros(0, dtype=np.int64)
    A, M = affinity_and_consistency(src, dst, rej.tau, rej.sigma)
    x = leading_eigenvector(A)
    return greedy_select(x, M, rej.min_ratio, rej.min_agreement)


def core_numbers(M: np.ndarray) -> np.ndarray:
    """k-core number of every vertex of the graph with bool adjacency M (m,m), diagonal False.

    Peels all vertices of the current least degree at once (vectorised rounds)."""
    m = len(M)
    Mu = M.view(np.uint8)
    deg = Mu.sum(axis=1, dtype=np.int64)
    core = np.zeros(m, dtype=np.int64)
    alive = np.ones(m, dtype=bool)
    k = 0
    while alive.any():
        k = max(k, int(deg[alive].min()))
        peel = np.flatnonzero(alive & (deg <= k))
        while len(peel):
            core[peel] = k
            alive[peel] = False
            deg -= Mu[peel].sum(axis=0, dtype=np.int64)
            peel = np.flatnonzero(alive & (deg <= k))
    return core


def greedy_clique(M: np.ndarray, rank: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """Largest clique grown greedily from each seed: repeatedly add the candidate (adjacent to
    every member so far) of highest `rank`. Returns sorted vertex indices."""
    best = np.zeros(0, dtype=np.int64)
    for s in seeds.tolist():
        cand = M[s].copy()
        clique = [s]
        while True:
            idx = np.flatnonzero(cand)
            if len(idx) == 0:
                break
            if len(clique) + len(idx) <= len(best):
                break  # cannot beat the best any more
            u = int(idx[np.argmax(rank[idx])])
            clique.append(u)
            cand &= M[u]
        if len(clique) > len(best):
            best = np.sort(np.asarray(clique, dtype=np.int64))
    return best


def max_clique(rej: CliqueRejector, M: np.ndarray) -> np.ndarray:
    """`rej` on the consistency graph M (m,m) bool in numpy: sorted vertex indices of the
    (near-)maximum clique."""
    m = len(M)
    core = core_numbers(M)
    deg = M.sum(axis=1)
    rank = core * (m + 1) + deg
    seeds = np.argsort(-rank, kind="stable")[: rej.n_seeds]
    best = greedy_clique(M, rank, seeds)
    # A clique of size s > |best| needs core number >= s - 1 >= |best|.
    pool = np.flatnonzero(core >= len(best))
    if 0 < len(pool) <= rej.exact_limit:
        found, _ = exact_clique(M[np.ix_(pool, pool)], len(best), rej.max_nodes)
        if len(found) > len(best):
            best = np.sort(pool[found])
    return best
