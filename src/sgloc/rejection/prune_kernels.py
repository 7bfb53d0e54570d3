"""The removal loop of Alg. 1 on bit-packed consistency rows (numba)."""

from __future__ import annotations

import numpy as np

from sgloc.kernels import watch_compiles
from sgloc.kernels.bits import WORD, cttz
from sgloc.kernels.dispatch import kernel

#: Keys are support << 32 | index: the least key is the least support and, among equal
#: supports, the lowest index (Alg. 1's tie rule).
_SHIFT = np.int64(32)
_ONE = np.int64(1) << _SHIFT
#: Key of a removed match: above any real key.
_GONE = np.int64(1) << np.int64(62)


@kernel
def prune_bits(bits: np.ndarray, degree: np.ndarray, eta: float) -> np.ndarray:
    """Survivors (sorted int64 indices) of Alg. 1 step 2 on packed rows `bits` (m, ceil(m/64))
    with row counts `degree` (m,): while the least supported remaining match (ties: lowest
    index) has support V_i < eta * (r - 1), r matches remaining, remove it and lower the
    support of its remaining consistent partners by one.

    Keys are kept with the minimum of every block of 64: supports only decrease, so a decrement
    updates its block's minimum in O(1); a step costs a scan of the m / 64 block minima, one
    block rescan and the set bits of one row (partners still remaining only).
    """
    m = degree.shape[0]
    n_words = bits.shape[1]
    keys = np.empty(n_words * WORD, dtype=np.int64)
    keys[:] = _GONE
    for i in range(m):
        keys[i] = (np.int64(degree[i]) << _SHIFT) | i
    alive = np.zeros(n_words, dtype=np.uint64)
    block_min = np.empty(n_words, dtype=np.int64)
    for w in range(n_words):
        block_min[w] = keys[w * WORD : (w + 1) * WORD].min()
        for b in range(min(WORD, m - w * WORD)):
            alive[w] |= np.uint64(1) << np.uint64(b)
    r = m
    while r > 1:
        kmin, wmin = block_min[0], 0
        for w in range(n_words):
            if block_min[w] < kmin:
                kmin, wmin = block_min[w], w
        if (kmin >> _SHIFT) >= eta * (r - 1):
            break
        i = kmin & (_ONE - 1)
        keys[i] = _GONE
        alive[wmin] &= ~(np.uint64(1) << np.uint64(i - wmin * WORD))
        r -= 1
        for w in range(n_words):
            x = bits[i, w] & alive[w]
            while x:
                j = w * WORD + np.int64(cttz(x))
                x &= x - np.uint64(1)
                keys[j] -= _ONE
                block_min[w] = min(block_min[w], keys[j])
        block_min[wmin] = keys[wmin * WORD : (wmin + 1) * WORD].min()
    out = np.empty(r, dtype=np.int64)
    n = 0
    for i in range(m):
        if keys[i] < _GONE:
            out[n] = i
            n += 1
    return out


watch_compiles()  # an install's first compile is said (sgloc.kernels)
