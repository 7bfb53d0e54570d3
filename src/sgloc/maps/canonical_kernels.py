"""The canonical vertex order of a graph and its duplicate search in one compiled pass
(`sgloc.maps.canonical`): the same order as numpy's `lexsort` of (class, x, y, z) (stable: ties
keep input order) and the same duplicate groups as a KD-tree search (the numpy reference, kept
with the tests), without a dozen small numpy calls per graph.

The sort is a merge sort written out (the package's rule: no numba sort in a cached kernel).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sgloc.kernels import watch_compiles
from sgloc.kernels.dispatch import kernel
from sgloc.maps.neighbor_kernels import first_at_least


@njit(cache=True, nogil=True, inline="always")
def _before(a, b, labels, positions) -> bool:
    """Whether row a sorts strictly before row b by (label, x, y, z)."""
    if labels[a] != labels[b]:
        return labels[a] < labels[b]
    for k in range(3):
        if positions[a, k] != positions[b, k]:
            return positions[a, k] < positions[b, k]
    return False


@njit(cache=True, nogil=True)
def _stable_order(labels, positions):
    """(n,) the rows 0..n-1 sorted by (labels (n,), then the columns of positions (n,3)),
    ties in row order: np.lexsort((z, y, x, labels)) (a bottom-up merge sort)."""
    n = labels.shape[0]
    order = np.arange(n)
    spare = np.empty(n, dtype=np.int64)
    width = 1
    while width < n:
        for lo in range(0, n, 2 * width):
            mid, hi = min(lo + width, n), min(lo + 2 * width, n)
            a, b = lo, mid
            for out in range(lo, hi):
                # From the right run only when strictly before the left one: stable.
                if b < hi and (a >= mid or _before(order[b], order[a], labels, positions)):
                    spare[out] = order[b]
                    b += 1
                else:
                    spare[out] = order[a]
                    a += 1
        order, spare = spare, order
        width *= 2
    return order


@kernel
def canonical_order_kernel(positions: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(n,) vertex indices sorted by (label, x, y, z), ties in input order: np.lexsort((z, y,
    x, labels)) (the same comparisons)."""
    return _stable_order(labels, positions)


@kernel
def restored_keys(
    pairs: np.ndarray, scores: np.ndarray, query_order: np.ndarray, target_order: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(pairs (k,2), keys (k,3)): `pairs` (k,2) of canonical (query, target) indices mapped
    through query_order / target_order to the caller's indices, and the sort keys after the
    query index: (-score, target, 0) (`scores` (k,); empty: (0, target, 0))."""
    k = pairs.shape[0]
    out = np.empty((k, 2), dtype=np.int64)
    keys = np.zeros((k, 3))
    for r in range(k):
        out[r, 0] = query_order[pairs[r, 0]]
        out[r, 1] = target_order[pairs[r, 1]]
        if scores.shape[0] > 0:
            keys[r, 0] = -scores[r]
        keys[r, 1] = out[r, 1]  # exact: indices < 2**53
    return out, keys


def restored_pairs(
    pairs: np.ndarray, scores: np.ndarray, query_order: np.ndarray, target_order: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(pairs (k,2), rows (k,)): `restored_keys`' pairs sorted by (query, score descending,
    target), stable; rows: which input row each output row is (np.lexsort of those keys).
    The sort is `canonical_order_kernel`'s, called here so that it sees the read-only arrays
    the kernels get (one compiled specialisation of the merge sort)."""
    out, keys = restored_keys(pairs, scores, query_order, target_order)
    rows = canonical_order_kernel(keys, np.ascontiguousarray(out[:, 0]))
    return out[rows], rows


@kernel
def first_of_duplicates(
    order: np.ndarray, positions: np.ndarray, labels: np.ndarray, radius: float, run: int
) -> tuple[np.ndarray, bool]:
    """(kept, long): `order` (canonical) without the vertices that repeat an earlier one of
    it (same class, squared distance <= radius**2, groups joined through any chain of such
    pairs, the first of each kept), searched along the canonical order: pairs
    only along runs of consecutive same-class steps of at most `radius` in x, compared up to
    `run` places apart. `long`: a run of `run` steps was met; then `kept` is empty, not
    computed (the caller searches that map by a KD-tree)."""
    # A writable copy: `canonical_form` hands the search the order it computed, so both
    # callers give it the same types (one compiled specialisation).
    return _first_of_groups(order.copy(), positions, labels, radius, run)


@kernel
def canonical_form(
    positions: np.ndarray, labels: np.ndarray, classes: np.ndarray, radius: float, run: int
) -> tuple[np.ndarray, np.ndarray, bool]:
    """(order, labels, long): `canonical_order_kernel` then `first_of_duplicates` (`long`:
    that search needs the caller's KD-tree; `order` is then the whole canonical order and
    `labels` empty), and the kept vertices' class ids renumbered to their index in `classes`
    (sorted, holding every label: np.searchsorted's index)."""
    order = _stable_order(labels, positions)
    kept, long = _first_of_groups(order, positions, labels, radius, run)
    if long:
        return order, np.zeros(0, dtype=np.int64), True
    out = np.empty(kept.shape[0], dtype=np.int64)
    for i in range(kept.shape[0]):
        out[i] = first_at_least(classes, labels[kept[i]])
    return kept, out, False


@njit(cache=True, nogil=True)
def _first_of_groups(order, positions, labels, radius, run):
    """`first_of_duplicates`."""
    n = order.shape[0]
    r2 = radius * radius
    step = np.zeros(n, dtype=np.bool_)  # step[i]: positions i - 1 and i may be duplicates
    length = 0
    for i in range(1, n):
        a, b = order[i - 1], order[i]
        step[i] = labels[a] == labels[b] and positions[b, 0] - positions[a, 0] <= radius
        length = length + 1 if step[i] else 0
        if length >= run:
            return np.zeros(0, dtype=np.int64), True
    root = np.arange(n)
    for i in range(n):
        a = order[i]
        for j in range(i + 1, n):
            if not step[j]:
                break
            b = order[j]
            dx = positions[b, 0] - positions[a, 0]
            dy = positions[b, 1] - positions[a, 1]
            dz = positions[b, 2] - positions[a, 2]
            if dx * dx + dy * dy + dz * dz <= r2:
                _join(root, i, j)
    n_kept = 0
    for i in range(n):
        n_kept += _find(root, i) == i
    kept = np.empty(n_kept, dtype=np.int64)
    n_kept = 0
    for i in range(n):
        if _find(root, i) == i:
            kept[n_kept] = order[i]
            n_kept += 1
    return kept, False


@njit(cache=True, nogil=True, inline="always")
def _find(root, i) -> int:
    """The smallest position of i's group (path halving)."""
    while root[i] != i:
        root[i] = root[root[i]]
        i = root[i]
    return i


@njit(cache=True, nogil=True, inline="always")
def _join(root, i, j) -> None:
    """Joins the groups of positions i and j under the smaller root."""
    a, b = _find(root, i), _find(root, j)
    if a < b:
        root[b] = a
    elif b < a:
        root[a] = b


watch_compiles()  # an install's first compile is said (sgloc.kernels)
