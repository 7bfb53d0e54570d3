"""Which robot pairs to (re)try: a pair is due when one of its two maps has grown enough since
the pair's last attempt."""

from __future__ import annotations

from collections.abc import Sequence


def due_pairs(
    sizes: Sequence[int],
    last: dict[tuple[int, int], tuple[int, int]],
    min_objects: int,
    growth_ratio: float,
    growth_objects: int,
) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j (robot indices), that should be attempted, most grown first.

    sizes: confirmed objects per robot; last: the sizes (i's, j's) at each pair's last attempt.
    A pair is due when both maps have >= min_objects and it was never tried, or one map grew by
    >= growth_ratio (fraction) or >= growth_objects since. Ties: the lower pair first.
    """
    scored = []
    for j in range(len(sizes)):
        if sizes[j] < min_objects:
            continue
        for i in range(j):
            if sizes[i] < min_objects:
                continue
            prev = last.get((i, j))
            if prev is None:
                scored.append((float("inf"), i, j))
                continue
            grow = max(_growth(sizes[i], prev[0]), _growth(sizes[j], prev[1]))
            new = max(sizes[i] - prev[0], sizes[j] - prev[1])
            if grow >= growth_ratio or new >= growth_objects:
                scored.append((grow, i, j))
    scored.sort(key=lambda s: (-s[0], s[1], s[2]))
    return [(i, j) for _, i, j in scored]


def _growth(now: int, then: int) -> float:
    return (now - then) / max(then, 1)
