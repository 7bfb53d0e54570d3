"""Same-class neighbour search: one KD-tree over objects of every class, the class id as a
fourth coordinate spaced beyond any distance asked for, so a query only ever reaches objects
of its own class (one tree instead of one per class)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def class_offset(extent: float, reach: float) -> float:
    """Spacing of the class coordinate: more than any distance between two points within
    `extent` (largest coordinate magnitude, metres) plus the search `reach` (metres)."""
    return 4.0 * (float(extent) + float(reach)) + 1.0


class ClassKDTree:
    """A KD-tree over `positions` (n,3) with `labels` (n,) as a fourth coordinate; coordinates
    multiplied by `scale` (e.g. (1, 1, 0.25) to count heights less) before any distance.
    `reach`: the largest distance that will be asked for; `extent`: the largest coordinate
    magnitude of any point that will be queried (default: that of `positions`, scaled)."""

    def __init__(
        self,
        positions: np.ndarray,
        labels: np.ndarray,
        reach: float,
        *,
        extent: float | None = None,
        scale: Sequence[float] = (1.0, 1.0, 1.0),
    ) -> None:
        from scipy.spatial import cKDTree  # deferred: scipy.spatial loads in ~0.2 s

        self.scale = tuple(float(s) for s in scale)
        p = np.asarray(positions, dtype=np.float64) * self.scale
        if extent is None:
            extent = float(np.abs(p).max(initial=0.0))
        self.offset = class_offset(extent, reach)
        self.points = self.lift(positions, labels)
        self.tree = cKDTree(self.points)

    def lift(self, points: np.ndarray, labels: np.ndarray) -> np.ndarray:
        """points (..., n, 3) and labels (n,) as (..., n, 4) tree coordinates."""
        points = np.asarray(points, dtype=np.float64)
        shape = points.shape[:-1]
        lab = np.broadcast_to(np.asarray(labels) * self.offset, shape)[..., None]
        return np.concatenate([points * self.scale, lab], axis=-1)

    def query(
        self, points: np.ndarray, labels: np.ndarray, upper: float = np.inf
    ) -> tuple[np.ndarray, np.ndarray]:
        """The nearest same-class point of each of `points` (..., n, 3) with `labels` (n,):
        (distance (..., n), inf beyond `upper`; index (..., n), len(tree) beyond it)."""
        q = self.lift(points, labels)
        shape = q.shape[:-1]
        d, j = self.tree.query(q.reshape(-1, 4), distance_upper_bound=upper)
        return d.reshape(shape), j.reshape(shape)

    def pairs(self, radius: float) -> np.ndarray:
        """(k,2) index pairs i < j of same-class points closer than `radius` (scaled metres)."""
        return self.tree.query_pairs(radius, output_type="ndarray")


def _nearest_in_group(key: np.ndarray, group: np.ndarray, d: np.ndarray,
                      other: np.ndarray) -> np.ndarray:
    """Mask of the entries nearest (d; ties: lower `other`) within their (key, group)."""
    order = np.lexsort((other, d, group, key))
    first = np.ones(len(order), bool)
    first[1:] = (key[order][1:] != key[order][:-1]) | (group[order][1:] != group[order][:-1])
    mask = np.zeros(len(order), bool)
    mask[order[first]] = True
    return mask


def mutual_nearest_pairs(
    points: np.ndarray, labels: np.ndarray, groups: np.ndarray, radius: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(i, j), sorted: points i and j ((n,3), metres, one frame) of two groups
    groups[i] < groups[j] (e.g. robots) and one class, each the other's nearest point of that
    class in the other's group (ties: the lower index), closer than `radius`."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    groups = np.asarray(groups)
    if len(points) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    p = ClassKDTree(points, labels, radius).pairs(radius)
    p = p[groups[p[:, 0]] != groups[p[:, 1]]]
    i, j = p[:, 0].copy(), p[:, 1].copy()
    swap = groups[i] > groups[j]
    i[swap], j[swap] = j[swap], i[swap]
    d = np.linalg.norm(points[i] - points[j], axis=1)
    ok = _nearest_in_group(i, groups[j], d, j) & _nearest_in_group(j, groups[i], d, i)
    order = np.lexsort((j[ok], i[ok]))
    return i[ok][order].astype(np.int64), j[ok][order].astype(np.int64)
