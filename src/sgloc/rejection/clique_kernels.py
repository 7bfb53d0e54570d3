"""The clique rejector's loops on packed consistency rows (numba): k-core numbers and the
greedy clique growth."""

from __future__ import annotations

import numpy as np

from sgloc.kernels import watch_compiles
from sgloc.kernels.bits import WORD, cttz, popcount
from sgloc.kernels.dispatch import kernel


@kernel
def core_numbers(bits: np.ndarray, degree: np.ndarray) -> np.ndarray:
    """k-core number of every vertex (Batagelj and Zaversnik's O(edges) bucket peeling)."""
    m = degree.shape[0]
    deg = degree.copy()
    max_deg = 0
    for i in range(m):
        max_deg = max(max_deg, deg[i])
    bin_start = np.zeros(max_deg + 2, dtype=np.int64)
    for i in range(m):
        bin_start[deg[i] + 1] += 1
    for d in range(1, max_deg + 2):
        bin_start[d] += bin_start[d - 1]
    vert = np.empty(m, dtype=np.int64)
    pos = np.empty(m, dtype=np.int64)
    fill = bin_start.copy()
    for i in range(m):
        pos[i] = fill[deg[i]]
        vert[pos[i]] = i
        fill[deg[i]] += 1
    for k in range(m):
        v = vert[k]
        for w in range(bits.shape[1]):
            x = bits[v, w]
            while x:
                u = w * WORD + np.int64(cttz(x))
                x &= x - np.uint64(1)
                if deg[u] > deg[v]:  # move u to the front of its bucket, then lower it
                    du, pu = deg[u], pos[u]
                    pw = bin_start[du]
                    other = vert[pw]
                    if other != u:
                        vert[pu], vert[pw] = other, u
                        pos[u], pos[other] = pw, pu
                    bin_start[du] += 1
                    deg[u] -= 1
    return deg


@kernel
def greedy_clique(bits: np.ndarray, rank: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """The clique rejector's greedy growth on packed rows: the largest clique grown from
    each seed by adding the candidate of highest rank (first on ties). Sorted indices."""
    n_words = bits.shape[1]
    best = np.zeros(0, dtype=np.int64)
    cand = np.empty(n_words, dtype=np.uint64)
    clique = np.empty(bits.shape[0], dtype=np.int64)
    for s in seeds:
        cand[:] = bits[s]
        clique[0] = s
        size = 1
        while True:
            n_cand = 0
            for w in range(n_words):
                n_cand += np.int64(popcount(cand[w]))
            if n_cand == 0 or size + n_cand <= best.shape[0]:
                break
            u, ru = -1, 0
            for w in range(n_words):
                x = cand[w]
                while x:
                    j = w * WORD + np.int64(cttz(x))
                    x &= x - np.uint64(1)
                    if u < 0 or rank[j] > ru:
                        u, ru = j, rank[j]
            clique[size] = u
            size += 1
            for w in range(n_words):
                cand[w] &= bits[u, w]
        if size > best.shape[0]:
            best = _sorted_members(clique[:size], bits.shape[0])
    return best


@kernel
def _sorted_members(members: np.ndarray, m: int) -> np.ndarray:
    """The distinct vertices `members` (< m) in ascending order, by marking them (no sort:
    see the `sgloc.kernels` rule on numba's sort helpers)."""
    mark = np.zeros(m, dtype=np.bool_)
    for v in members:
        mark[v] = True
    out = np.empty(members.shape[0], dtype=np.int64)
    n = 0
    for v in range(m):
        if mark[v]:
            out[n] = v
            n += 1
    return out


watch_compiles()  # an install's first compile is said (sgloc.kernels)
