"""Numpy reference of the neighbor rejector's pruning (`sgloc.rejection.prune_kernels`): Alg. 1
step 2 with the "remaining" bound on a dense consistency matrix."""

from __future__ import annotations

import numpy as np

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
