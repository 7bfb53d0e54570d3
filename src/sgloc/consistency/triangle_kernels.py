"""Counts on a bit-packed consistency graph (numba): its edges and its triangles.

For the acceptance test, which needs the consistent pairs (i < j) and the number of triangles
(triples whose three pairs are all consistent): `np.nonzero(np.triu(M))` and a popcount over
`M[i] & M[j]` in numpy, here straight from the packed rows of `consistency_bits`.
"""

from __future__ import annotations

import numpy as np

from sgloc.kernels import watch_compiles
from sgloc.kernels.bits import WORD, cttz, popcount
from sgloc.kernels.dispatch import kernel


@kernel
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


@kernel
def common_counts(bits: np.ndarray, ii: np.ndarray, jj: np.ndarray) -> int:
    """Sum over the pairs (ii[k], jj[k]) of the number of matches consistent with both (the
    popcount of row ii[k] AND row jj[k]); over all edges i < j it is 3 x the triangles."""
    total = 0
    for k in range(ii.shape[0]):
        a, b = ii[k], jj[k]
        for w in range(bits.shape[1]):
            total += np.int64(popcount(bits[a, w] & bits[b, w]))
    return total


@kernel
def upper_counts(bits: np.ndarray, keep_words: np.ndarray, keep_rows: np.ndarray) -> np.ndarray:
    """(m,) per row i, its consistent partners j > i among the kept ones (`keep_words`: the
    kept columns as one packed row; rows outside `keep_rows` count 0)."""
    m = bits.shape[0]
    counts = np.zeros(m, dtype=np.int64)
    for i in range(m):
        if not keep_rows[i]:
            continue
        first = (i + 1) // WORD
        c = 0
        for w in range(first, bits.shape[1]):
            x = bits[i, w] & keep_words[w]
            if w == first:
                shift = np.uint64((i + 1) % WORD)
                x = (x >> shift) << shift
            c += np.int64(popcount(x))
        counts[i] = c
    return counts


@kernel
def kept_starts(bits: np.ndarray, keep_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(keep_words, row_start): the kept matches `keep_rows` (m,) bool as one packed row (the
    layout of the rows of `bits`), and the running sum of their `upper_counts` from 0 (m+1,)."""
    m = bits.shape[0]
    keep_words = np.zeros(bits.shape[1], dtype=np.uint64)
    for i in range(m):
        if keep_rows[i]:
            keep_words[i // WORD] |= np.uint64(1) << np.uint64(i % WORD)
    counts = upper_counts(bits, keep_words, keep_rows)
    row_start = np.zeros(m + 1, dtype=np.int64)
    for i in range(m):
        row_start[i + 1] = row_start[i] + counts[i]
    return keep_words, row_start


@kernel
def _last_at_most(sorted_values: np.ndarray, value: int) -> int:
    """The last position of sorted_values holding a value <= `value` (-1 if none): numpy's
    searchsorted(side="right") - 1, as a plain binary search (see the `sgloc.kernels` rule on
    numba's sort and search helpers)."""
    lo, hi = 0, sorted_values.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if sorted_values[mid] <= value:
            lo = mid + 1
        else:
            hi = mid
    return lo - 1


@kernel
def edges_at(
    bits: np.ndarray, keep_words: np.ndarray, row_start: np.ndarray, ks: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(ii, jj) of the kept consistent pairs i < j at the row-major positions `ks` (sorted,
    each < row_start[-1]; row_start: the running sum of `upper_counts`, from 0), without
    listing the others: one sweep, each row scanned at most once."""
    ii = np.empty(ks.shape[0], dtype=np.int64)
    jj = np.empty(ks.shape[0], dtype=np.int64)
    row, w, seen = -1, 0, 0
    x = np.uint64(0)
    for n in range(ks.shape[0]):
        k = ks[n]
        r = _last_at_most(row_start, k)
        if r != row:  # the first kept partner of row r: its lowest set bit right of r
            row, w, seen = r, (r + 1) // WORD, 0
            shift = np.uint64((r + 1) % WORD)
            x = ((bits[r, w] & keep_words[w]) >> shift) << shift
            while x == 0:
                w += 1
                x = bits[r, w] & keep_words[w]
        while seen < k - row_start[r]:  # on to the next set bit
            x &= x - np.uint64(1)
            while x == 0:
                w += 1
                x = bits[r, w] & keep_words[w]
            seen += 1
        ii[n] = r
        jj[n] = w * WORD + np.int64(cttz(x))
    return ii, jj


watch_compiles()  # an install's first compile is said (sgloc.kernels)
