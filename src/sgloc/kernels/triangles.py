"""Counts on a bit-packed consistency graph (numba): its edges and its triangles.

For the acceptance test, which needs the consistent pairs (i < j) and the number of triangles
(triples whose three pairs are all consistent): `np.nonzero(np.triu(M))` and a popcount over
`M[i] & M[j]` in numpy, here straight from the packed rows of `consistency_bits`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sgloc.kernels.bits import WORD, cttz, popcount


@njit(cache=True, nogil=True)
def upper_edges(bits: np.ndarray, degree: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ii, jj): every consistent pair with ii < jj, in row-major order (as
    np.nonzero(np.triu(M)))."""
    n_edges = degree.sum() // 2
    ii = np.empty(n_edges, dtype=np.int64)
    jj = np.empty(n_edges, dtype=np.int64)
    k = 0
    for i in range(bits.shape[0]):
        first = (i + 1) // WORD
        for w in range(first, bits.shape[1]):
            x = bits[i, w]
            if w == first:  # drop columns <= i
                shift = np.uint64((i + 1) % WORD)
                x = (x >> shift) << shift
            while x:
                ii[k] = i
                jj[k] = w * WORD + np.int64(cttz(x))
                x &= x - np.uint64(1)
                k += 1
    return ii, jj


@njit(cache=True, nogil=True)
def common_counts(bits: np.ndarray, ii: np.ndarray, jj: np.ndarray) -> int:
    """Sum over the pairs (ii[k], jj[k]) of the number of matches consistent with both (the
    popcount of row ii[k] AND row jj[k]); over all edges i < j it is 3 x the triangles."""
    total = 0
    for k in range(ii.shape[0]):
        a, b = ii[k], jj[k]
        for w in range(bits.shape[1]):
            total += np.int64(popcount(bits[a, w] & bits[b, w]))
    return total
