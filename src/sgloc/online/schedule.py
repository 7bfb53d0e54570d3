"""Which robot pairs to (re)try: a pair is due when one of its two maps has grown enough since
the pair's last attempt. `PairSizes` remembers the sizes at each pair's last attempt in arrays
as well as a dict, so that `due_pairs` scores every pair at once (no loop over pairs)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np


class PairSizes(dict):
    """{(i, j): (size of i, size of j)} at a pair's last attempt or refit (robot indices,
    i < j), mirrored in two (n, n) arrays (-1: never) that `due_pairs` reads."""

    def __init__(self, items: Mapping | None = None) -> None:
        super().__init__()
        self._a = np.full((0, 0), -1, np.int64)
        self._b = np.full((0, 0), -1, np.int64)
        for key, value in (items or {}).items():
            self[key] = value

    def _grow(self, n: int) -> None:
        if n > len(self._a):
            m = max(n, 2 * len(self._a), 8)
            a, b = np.full((m, m), -1, np.int64), np.full((m, m), -1, np.int64)
            k = len(self._a)
            a[:k, :k], b[:k, :k] = self._a, self._b
            self._a, self._b = a, b

    def __setitem__(self, key: tuple[int, int], value: tuple[int, int]) -> None:
        i, j = key
        self._grow(max(i, j) + 1)
        self._a[i, j], self._b[i, j] = value
        super().__setitem__((i, j), (int(value[0]), int(value[1])))

    def pop(self, key, *default):  # noqa: D102 - dict.pop, the arrays kept in step
        if key in self:
            self._a[key], self._b[key] = -1, -1
        return super().pop(key, *default)

    def arrays(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(n, n) sizes of i and of j at each pair's last attempt (-1: never)."""
        self._grow(n)
        return self._a[:n, :n], self._b[:n, :n]


def due_pairs(
    sizes: Sequence[int],
    last: Mapping[tuple[int, int], tuple[int, int]],
    min_objects: int,
    growth_ratio: float,
    growth_objects: int,
    robot: int | None = None,
) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j (robot indices), that should be attempted, most grown first.

    sizes: confirmed objects per robot; last: the sizes (i's, j's) at each pair's last attempt
    (a `PairSizes`, or any mapping). A pair is due when both maps have >= min_objects and it
    was never tried, or one map grew by >= growth_ratio (fraction) or >= growth_objects since.
    Only the pairs of robot index `robot` when given. Ties: the lower pair first.
    """
    n = len(sizes)
    s = np.asarray(sizes, np.int64).reshape(n)
    if robot is None:
        i, j = np.triu_indices(n, 1)
    else:
        other = np.delete(np.arange(n), robot)
        i, j = np.minimum(other, robot), np.maximum(other, robot)
    keep = (s[i] >= min_objects) & (s[j] >= min_objects)
    i, j = i[keep], j[keep]
    if isinstance(last, PairSizes):
        A, B = last.arrays(n)
        pa, pb = A[i, j], B[i, j]
    else:
        prev = [last.get((int(a), int(b)), (-1, -1)) for a, b in zip(i, j, strict=True)]
        pa, pb = (np.array([p[k] for p in prev], np.int64).reshape(-1) for k in (0, 1))
    tried = pa >= 0
    grow = np.maximum((s[i] - pa) / np.maximum(pa, 1), (s[j] - pb) / np.maximum(pb, 1))
    new = np.maximum(s[i] - pa, s[j] - pb)
    due = ~tried | (grow >= growth_ratio) | (new >= growth_objects)
    score = np.where(tried, grow, np.inf)[due]
    i, j = i[due], j[due]
    order = np.lexsort((j, i, -score))
    return [(int(a), int(b)) for a, b in zip(i[order], j[order], strict=True)]
