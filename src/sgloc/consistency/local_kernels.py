"""Alg. 1 within a radius: supports counted among spatial neighbours only (numba).

Candidates are bucketed on a grid of the query positions (`sgloc.consistency.local.RadiusGrid`,
cells at least the radius wide: every neighbour lies in one of the 27 cells around a
candidate's). Nothing of size neighbours x candidates is stored: a candidate's neighbours are
found again from the grid when it is removed, so memory is linear in the candidates and time
grows with candidates x neighbourhood. Distances and consistency decisions are float64
sqrt(dx*dx + dy*dy + dz*dz), as in `sgloc.consistency.pairwise_kernels` (scipy cdist's values).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sgloc.kernels import watch_compiles
from sgloc.kernels.dispatch import kernel


@njit(cache=True, nogil=True, inline="always")
def _dist(p: np.ndarray, i: int, j: int) -> float:
    """Float64 |p_i - p_j|, summed in scipy cdist's order."""
    dx, dy, dz = p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, nogil=True, inline="always")
def _consistent(src: np.ndarray, dst: np.ndarray, i: int, j: int, tau: float, nb: bool) -> bool:
    """Matches i, j consistent: |D_q - D_t| < tau, or (nb) (D_q < tau) == (D_t < tau)."""
    ds, dt = _dist(src, i, j), _dist(dst, i, j)
    return ((ds < tau) == (dt < tau)) if nb else (abs(ds - dt) < tau)


@kernel
def local_counts(
    src: np.ndarray,
    dst: np.ndarray,
    order: np.ndarray,
    cell_start: np.ndarray,
    point_cell: np.ndarray,
    near_cells: np.ndarray,
    radius: float,
    tau: float,
    neighbor: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """(r, V) int64 (m,): per candidate i, the other candidates whose query points lie closer
    than `radius` to src_i (r), and those of them consistent with i (V).

    Grid: `order` the candidates sorted by cell, `cell_start` (n_cells + 1,) each cell's run in
    `order`, `point_cell` (m,) each candidate's cell, `near_cells` (n_cells, 27) the cells
    around each cell (-1: none)."""
    m = src.shape[0]
    r = np.zeros(m, dtype=np.int64)
    V = np.zeros(m, dtype=np.int64)
    for i in range(m):
        c = point_cell[i]
        for a in range(near_cells.shape[1]):
            cc = near_cells[c, a]
            if cc < 0:
                continue
            for p in range(cell_start[cc], cell_start[cc + 1]):
                j = order[p]
                if j != i and _dist(src, i, j) < radius:
                    r[i] += 1
                    V[i] += _consistent(src, dst, i, j, tau, neighbor)
    return r, V


@njit(cache=True, nogil=True, inline="always")
def _less(key: np.ndarray, a: int, b: int) -> bool:
    """Heap order: smaller key first, then the lower index (Alg. 1's tie rule)."""
    return key[a] < key[b] or (key[a] == key[b] and a < b)


@kernel(writes=("heap", "pos"))
def _sift_up(heap: np.ndarray, pos: np.ndarray, key: np.ndarray, k: int) -> None:
    x = heap[k]
    while k > 0:
        parent = (k - 1) >> 1
        y = heap[parent]
        if not _less(key, x, y):
            break
        heap[k], pos[y] = y, k
        k = parent
    heap[k], pos[x] = x, k


@kernel(writes=("heap", "pos"))
def _sift_down(heap: np.ndarray, pos: np.ndarray, key: np.ndarray, k: int, n: int) -> None:
    x = heap[k]
    while True:
        c = 2 * k + 1
        if c >= n:
            break
        if c + 1 < n and _less(key, heap[c + 1], heap[c]):
            c += 1
        y = heap[c]
        if not _less(key, y, x):
            break
        heap[k], pos[y] = y, k
        k = c
    heap[k], pos[x] = x, k


@njit(cache=True, nogil=True, inline="always")
def _ratio(V: int, r: int, s: int) -> float:
    """Support fraction (V + s) / (r + s); +inf without neighbours (never removed)."""
    return (V + s) / (r + s) if r + s > 0 else np.inf


@kernel
def local_prune(
    src: np.ndarray,
    dst: np.ndarray,
    order: np.ndarray,
    cell_start: np.ndarray,
    point_cell: np.ndarray,
    near_cells: np.ndarray,
    radius: float,
    tau: float,
    neighbor: bool,
    eta: float,
    self_vote: int,
) -> np.ndarray:
    """Survivors (sorted int64) of Alg. 1 on local supports: while the remaining candidate
    with the least support fraction (V_i + s) / (r_i + s) (ties: the lowest index) has
    V_i + s < eta * (r_i + s), remove it; r_i / V_i count the remaining candidates within
    `radius` of i's query point / those consistent with i (`local_counts`), s = `self_vote`
    (1: a match counts itself, the literal bound). A removal updates the counts of its
    remaining neighbours (an indexed heap keeps the order, O(log m) per update)."""
    m = src.shape[0]
    r, V = local_counts(src, dst, order, cell_start, point_cell, near_cells, radius, tau, neighbor)
    key = np.empty(m)
    for i in range(m):
        key[i] = _ratio(V[i], r[i], self_vote)
    heap = np.arange(m)
    pos = np.arange(m)
    for k in range(m // 2 - 1, -1, -1):
        _sift_down(heap, pos, key, k, m)
    alive = np.ones(m, dtype=np.bool_)
    n = m
    while n > 0:
        i = heap[0]
        if not (V[i] + self_vote < eta * (r[i] + self_vote)):
            break
        alive[i] = False
        n -= 1
        if n > 0:
            heap[0] = heap[n]
            pos[heap[0]] = 0
            _sift_down(heap, pos, key, 0, n)
        c = point_cell[i]
        for a in range(near_cells.shape[1]):
            cc = near_cells[c, a]
            if cc < 0:
                continue
            for p in range(cell_start[cc], cell_start[cc + 1]):
                j = order[p]
                if not alive[j] or j == i or not _dist(src, i, j) < radius:
                    continue
                r[j] -= 1
                V[j] -= _consistent(src, dst, i, j, tau, neighbor)
                old = key[j]
                key[j] = _ratio(V[j], r[j], self_vote)
                if key[j] < old:
                    _sift_up(heap, pos, key, pos[j])
                else:
                    _sift_down(heap, pos, key, pos[j], n)
    out = np.empty(n, dtype=np.int64)
    k = 0
    for i in range(m):
        if alive[i]:
            out[k] = i
            k += 1
    return out


watch_compiles()  # an install's first compile is said (sgloc.kernels)
