"""Per-class counts of the points near each query point (numba): the acceptance test's
chance model without a KD-tree per call.

The points are bucketed on an xy grid of cells at least the radius wide (sorted cell keys), so
each query point scans the 3 x 3 cells around its own. A pair counts when its squared distance
dx*dx + dy*dy + dz*dz <= radius * radius, in float64, the test (and the rounding) of
scipy's cKDTree.sparse_distance_matrix.

`distance_histograms` uses the same grid for the default vertex descriptor
(`sgloc.descriptors.distance`): per object, soft-binned counts of the other objects within the
radius by (class, distance). Its weights are rounded to multiples of 2**-24 (`WEIGHT_QUANTUM`),
so every bin's sum is exact in float64 whatever the order of its terms: the kernel, the numpy
reference and an incremental update of a few rows give the same bits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from sgloc.kernels import watch_compiles
from sgloc.kernels.dispatch import kernel

#: Cells are this much wider than the radius, so that rounding in the cell index never puts
#: two points within the radius more than one cell apart.
_CELL_MARGIN = 1.0 + 2.0**-10
#: Largest number of cells per axis (cell keys stay far inside int64).
_MAX_CELLS = 2**30
#: Descriptor weights are multiples of this (sums of up to 2**29 of them are exact).
WEIGHT_QUANTUM = 2.0**-24


def near_class_counts(
    query: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    n_classes: int,
    radius: float,
    weights: np.ndarray,
    grid: CellGrid | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(counts, weighted), each (n_query, n_classes) float64: per query point (n_query,3) and
    class c, the number of `points` (n,3) of label c within `radius` (distance <= radius), and
    the sum of their `weights` (n,) (an empty `weights`: the second array stays zero).

    grid: the points' `cell_grid` at this radius when the caller keeps it (a prepared graph's,
    `sgloc.maps.prepared_graph`: searched by every query, so a search then costs O(n_query x the
    points around them), not O(n)); None: built for this call."""
    if len(points) == 0 or len(query) == 0:
        return np.zeros((len(query), n_classes)), np.zeros((len(query), n_classes))
    g = cell_grid(points, labels, radius) if grid is None else grid
    w = weights[g.order] if len(weights) == len(points) else np.zeros(0)
    return _counts_in_cells(np.ascontiguousarray(query, dtype=np.float64), g.xyz, g.labels,
                            n_classes, radius, w, g.sorted_keys, g.start, g.x0, g.y0, g.cell,
                            g.n_y)  # fmt: skip


@dataclass(frozen=True)
class CellGrid:
    """Points bucketed on an xy grid of cells at least the radius wide (`_cell_keys`): `order`
    (n,) sorts them by cell; `sorted_keys` (n,) their cell keys, `xyz` (3, n) their
    coordinates and `labels` (n,) their labels in that order; `start` (n_cells + 1,) the
    first position of each cell's run when the grid is small (else (1,): binary search)."""

    order: np.ndarray
    sorted_keys: np.ndarray
    xyz: np.ndarray
    labels: np.ndarray
    start: np.ndarray
    x0: float
    y0: float
    cell: float
    n_y: int


def cell_grid(points: np.ndarray, labels: np.ndarray, radius: float) -> CellGrid:
    """The `CellGrid` of points (n,3) with labels (n,) int64 for `radius` metres (a caller
    that searches the same points again keeps it:
    `sgloc.maps.prepared_graph.PreparedGraph.grid`)."""
    keys, x0, y0, cell, n_y = _cell_keys(points, radius)
    n_cells = (int(keys.max()) // n_y + 3) * n_y
    # A table of runs when it costs at most a few entries per point, else binary searches.
    if n_cells <= 2 * len(keys) + 4096:  # a stable counting sort: np.argsort's order
        points = np.ascontiguousarray(points, dtype=np.float64)
        grid = _counting_grid(points, np.ascontiguousarray(labels, dtype=np.int64), keys, n_cells)
        return CellGrid(*grid, x0, y0, cell, n_y)
    # numpy's sort: numba's sort and search helpers are better kept out of cached kernels
    # (their generated symbols can clash with another cached kernel's in one process).
    order = np.argsort(keys, kind="stable")
    return CellGrid(order, keys[order], np.ascontiguousarray(points[order].T),
                    np.ascontiguousarray(labels[order], dtype=np.int64), np.zeros(1, np.int64),
                    x0, y0, cell, n_y)  # fmt: skip


@kernel
def _counting_grid(
    points: np.ndarray, labels: np.ndarray, keys: np.ndarray, n_cells: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(order, sorted_keys, xyz (3,n), labels, start) of a `CellGrid` of points (n,3) with
    cell `keys` (n,) < n_cells (`_counting_order`)."""
    # A writable copy: `_all_pair_histograms` sorts keys it computed, so both callers give
    # `_counting_order` the same types (one compiled specialisation).
    order, sorted_keys, start = _counting_order(keys.copy(), n_cells)
    n = keys.shape[0]
    xyz = np.empty((3, n))
    sorted_labels = np.empty(n, dtype=np.int64)
    for s in range(n):
        j = order[s]
        sorted_labels[s] = labels[j]
        xyz[0, s], xyz[1, s], xyz[2, s] = points[j, 0], points[j, 1], points[j, 2]
    return order, sorted_keys, xyz, sorted_labels, start


@njit(cache=True, nogil=True)
def _counting_order(keys, n_cells):
    """(order, sorted_keys, start) of cell `keys` (n,) < n_cells by a stable counting sort
    (np.argsort(kind="stable")'s order); `start`: `_cell_starts`."""
    n = keys.shape[0]
    start = _cell_starts(keys, n_cells)  # the runs do not depend on the order
    fill = start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    sorted_keys = np.empty(n, dtype=np.int64)
    for j in range(n):
        s = fill[keys[j]]
        fill[keys[j]] += 1
        order[s], sorted_keys[s] = j, keys[j]
    return order, sorted_keys, start


@kernel
def _cell_keys(points: np.ndarray, radius: float) -> tuple[np.ndarray, float, float, float, int]:
    """(keys, x0, y0, cell, n_y): each point's xy cell as cx * n_y + cy (cells `cell` >= radius
    wide from (x0, y0), one spare row and column on each side)."""
    n = points.shape[0]
    x0, y0 = points[:, 0].min(), points[:, 1].min()
    extent = max(points[:, 0].max() - x0, points[:, 1].max() - y0)
    cell = max(radius * _CELL_MARGIN, extent / _MAX_CELLS)
    n_y = np.int64(np.floor((points[:, 1].max() - y0) / cell)) + 3
    keys = np.empty(n, dtype=np.int64)
    for j in range(n):
        cx = np.int64(np.floor((points[j, 0] - x0) / cell)) + 1
        cy = np.int64(np.floor((points[j, 1] - y0) / cell)) + 1
        keys[j] = cx * n_y + cy
    return keys, x0, y0, cell, n_y


@kernel
def _cell_starts(sorted_keys: np.ndarray, n_cells: int) -> np.ndarray:
    """(n_cells + 1,) the first position in sorted_keys of each cell key's run."""
    start = np.zeros(n_cells + 1, dtype=np.int64)
    for s in range(sorted_keys.shape[0]):
        start[sorted_keys[s] + 1] += 1
    for c in range(n_cells):
        start[c + 1] += start[c]
    return start


@kernel
def first_at_least(sorted_keys: np.ndarray, key: int) -> int:
    """The first position of sorted_keys holding a value >= key (binary search)."""
    lo, hi = 0, sorted_keys.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if sorted_keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@kernel
def _counts_in_cells(
    query: np.ndarray,
    xyz: np.ndarray,
    lab: np.ndarray,
    n_classes: int,
    radius: float,
    w: np.ndarray,
    sorted_keys: np.ndarray,
    start: np.ndarray,
    x0: float,
    y0: float,
    cell: float,
    n_y: int,
) -> tuple[np.ndarray, np.ndarray]:
    """`near_class_counts` on a `CellGrid` (points, labels and weights `w` in cell order; `w`
    empty: no weights)."""
    n_q, n = query.shape[0], sorted_keys.shape[0]
    counts = np.zeros((n_q, n_classes))
    weighted = np.zeros((n_q, n_classes))
    n_x = sorted_keys[-1] // n_y + 2
    px, py, pz = xyz[0], xyz[1], xyz[2]
    use_weights = w.shape[0] == n
    dense = start.shape[0] > 1
    r2 = radius * radius
    for i in range(n_q):
        qx, qy, qz = query[i, 0], query[i, 1], query[i, 2]
        fx, fy = np.floor((qx - x0) / cell) + 1, np.floor((qy - y0) / cell) + 1
        if not (fx >= 0 and fx <= n_x and fy >= 0 and fy <= n_y - 1):
            continue  # a cell away from every point: nothing within the radius (or NaN)
        cx, cy = np.int64(fx), np.int64(fy)
        for dx_cell in range(-1, 2):
            if cx + dx_cell < 0 or cx + dx_cell > n_x:
                continue
            lo_key = (cx + dx_cell) * n_y + max(cy - 1, 0)
            hi_key = (cx + dx_cell) * n_y + min(cy + 1, n_y - 1)
            if dense:
                lo, hi = start[lo_key], start[hi_key + 1]
            else:
                lo = first_at_least(sorted_keys, lo_key)
                hi = first_at_least(sorted_keys, hi_key + 1)
            for s in range(lo, hi):
                dx, dy, dz = qx - px[s], qy - py[s], qz - pz[s]
                if dx * dx + dy * dy + dz * dz <= r2:
                    counts[i, lab[s]] += 1.0
                    if use_weights:
                        weighted[i, lab[s]] += w[s]
    return counts, weighted


def distance_histograms(
    centres: np.ndarray,
    self_index: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    n_classes: int,
    radius: float,
    n_bins: int,
    taper: float,
) -> np.ndarray:
    """(n_centres, n_classes * n_bins) float64: at each of `centres` (n_centres,3), the
    distance histogram of `sgloc.descriptors.distance.DistanceHistogramDescriptor` over the
    `points` (n,3) of `labels` (n,) int64 closer than `radius` metres, leaving out the point
    `self_index[i]` of centre i (-1: none; a centre that is itself one of the points). When
    the centres are the points themselves, in order, each pair is measured once."""
    out = np.zeros((len(centres), n_classes * n_bins))
    if len(points) == 0 or len(centres) == 0:
        return out
    # Multiplications, not divisions, per pair (the reference's arithmetic is the same).
    r = float(radius)
    weights = (r, int(n_bins), int(n_bins) / r, float(taper) / r)
    # Each pair once, for both ends (the sums are exact: the same bits as twice).
    pairs = len(centres) == len(points) and np.array_equal(self_index, np.arange(len(points)))
    if pairs and _all_pair_histograms(out, points, labels, *weights):
        return out  # the grid built in the kernel
    keys, x0, y0, cell, n_y = _cell_keys(points, radius)
    order = np.argsort(keys, kind="stable")  # numpy's sort (module docstring of the package)
    grid = (order, keys[order], x0, y0, cell, n_y)
    if pairs:
        _pair_histograms(out, points, labels, *weights, *grid)
    else:
        _histograms_in_cells(out, centres, self_index, points, labels, *weights, *grid)
    return out


@kernel(writes=("out",))
def _all_pair_histograms(
    out: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    radius: float,
    n_bins: int,
    per_bin: float,
    slope: float,
) -> bool:
    """`_pair_histograms` with its grid built here (the cells sorted by a stable counting
    sort: numpy's stable argsort of the keys) when the grid is small (a table of runs of at
    most 8 entries per point); False, nothing done, when it is not."""
    keys, _, _, _, n_y = _cell_keys(points, radius)
    n = keys.shape[0]
    n_cells = (keys.max() // n_y + 3) * n_y
    if n_cells > 8 * n + 4096:
        return False
    order, sorted_keys, start = _counting_order(keys, n_cells)
    _pairs_on_grid(out, points, labels, radius, n_bins, per_bin, slope, order, sorted_keys,
                   start, n_y)  # fmt: skip
    return True


@kernel(writes=("out",))
def _pair_histograms(
    out: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    radius: float,
    n_bins: int,
    per_bin: float,
    slope: float,
    order: np.ndarray,
    sorted_keys: np.ndarray,
    x0: float,
    y0: float,
    cell: float,
    n_y: int,
) -> None:
    """`distance_histograms` of every point over the others, each pair measured once
    (`_pairs_on_grid`), on the grid of `_cell_keys` (`order` sorts the keys)."""
    n = points.shape[0]
    n_cells = (sorted_keys[-1] // n_y + 3) * n_y
    dense = n_cells <= 8 * n + 4096
    start = np.zeros(n_cells + 1 if dense else 1, dtype=np.int64)
    if dense:
        for s in range(n):
            start[sorted_keys[s] + 1] += 1
        for c in range(n_cells):
            start[c + 1] += start[c]
    _pairs_on_grid(out, points, labels, radius, n_bins, per_bin, slope, order, sorted_keys,
                   start, n_y)  # fmt: skip


@njit(cache=True, nogil=True)
def _pairs_on_grid(out, points, labels, radius, n_bins, per_bin, slope, order, sorted_keys,
                   start, n_y) -> None:  # fmt: skip
    """The pairs of `_pair_histograms`: from each point (in cell order) only the points after
    it in its own and the next cell of its column, and the three cells of the next column
    (the other half of the 3 x 3 block sees it from there); `start`: the table of cell runs,
    or (1,) for binary searches of sorted_keys."""
    n = points.shape[0]
    px, py, pz = points[order, 0], points[order, 1], points[order, 2]
    lab = labels[order]
    dense = start.shape[0] > 1
    for a in range(n):
        key = sorted_keys[a]
        cy = key % n_y
        # This cell after a, then the next cell of the column (keys are consecutive).
        hi_key = key + 1 if cy + 1 <= n_y - 1 else key
        hi = start[hi_key + 1] if dense else first_at_least(sorted_keys, hi_key + 1)
        _pair_run(out, a, a + 1, hi, order, px, py, pz, lab, radius, n_bins, per_bin, slope)
        lo_key = key + n_y - 1 if cy >= 1 else key + n_y
        hi_key = key + n_y + 1 if cy + 1 <= n_y - 1 else key + n_y
        if dense:
            lo, hi = start[lo_key], start[hi_key + 1]
        else:
            lo = first_at_least(sorted_keys, lo_key)
            hi = first_at_least(sorted_keys, hi_key + 1)
        _pair_run(out, a, lo, hi, order, px, py, pz, lab, radius, n_bins, per_bin, slope)


@njit(cache=True, nogil=True, inline="always")
def _pair_run(out, a, lo, hi, order, px, py, pz, lab, radius, n_bins, per_bin, slope) -> None:
    """The pairs (a, s) for s in [lo, hi) of the cell-sorted points, counted at both ends."""
    scale = 1.0 / WEIGHT_QUANTUM
    top = n_bins - 1.0
    near2 = radius * radius * (1.0 + 1e-9)
    i = order[a]
    for s in range(lo, hi):
        dx, dy, dz = px[a] - px[s], py[a] - py[s], pz[a] - pz[s]
        d2 = dx * dx + dy * dy + dz * dz
        if not d2 <= near2:
            continue
        d = np.sqrt(d2)
        if not d < radius:
            continue
        u = min(max(d * per_bin - 0.5, 0.0), top)
        b = np.int64(u)
        frac = u - b
        t = 1.0 - d * slope
        w_lo = np.floor((1.0 - frac) * t * scale + 0.5) * WEIGHT_QUANTUM
        w_hi = np.floor(frac * t * scale + 0.5) * WEIGHT_QUANTUM
        b_hi = min(b + 1, n_bins - 1)
        j = order[s]
        col = lab[s] * n_bins
        out[i, col + b] += w_lo
        out[i, col + b_hi] += w_hi
        col = lab[a] * n_bins
        out[j, col + b] += w_lo
        out[j, col + b_hi] += w_hi


@kernel(writes=("out",))
def _histograms_in_cells(
    out: np.ndarray,
    centres: np.ndarray,
    self_index: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    radius: float,
    n_bins: int,
    per_bin: float,
    slope: float,
    order: np.ndarray,
    sorted_keys: np.ndarray,
    x0: float,
    y0: float,
    cell: float,
    n_y: int,
) -> None:
    """`distance_histograms` on the grid of `_cell_keys` (`order` sorts the keys), into out.
    The arithmetic of each weight is the numpy reference's, operation for operation."""
    n = points.shape[0]
    n_x = sorted_keys[-1] // n_y + 2
    px, py, pz = points[order, 0], points[order, 1], points[order, 2]
    lab = labels[order]
    n_cells = (n_x + 1) * n_y
    dense = n_cells <= 8 * n + 4096
    start = np.zeros(n_cells + 1 if dense else 1, dtype=np.int64)
    if dense:
        for s in range(n):
            start[sorted_keys[s] + 1] += 1
        for c in range(n_cells):
            start[c + 1] += start[c]
    scale = 1.0 / WEIGHT_QUANTUM
    top = n_bins - 1.0
    near2 = radius * radius * (1.0 + 1e-9)  # a loose first test; the exact one is d < radius
    for r in range(centres.shape[0]):
        qx, qy, qz = centres[r, 0], centres[r, 1], centres[r, 2]
        fx, fy = np.floor((qx - x0) / cell) + 1, np.floor((qy - y0) / cell) + 1
        if not (fx >= 0 and fx <= n_x and fy >= 0 and fy <= n_y - 1):
            continue  # a cell away from every point: nothing within the radius
        cx, cy = np.int64(fx), np.int64(fy)
        for dx_cell in range(-1, 2):
            if cx + dx_cell < 0 or cx + dx_cell > n_x:
                continue
            lo_key = (cx + dx_cell) * n_y + max(cy - 1, 0)
            hi_key = (cx + dx_cell) * n_y + min(cy + 1, n_y - 1)
            if dense:
                lo, hi = start[lo_key], start[hi_key + 1]
            else:
                lo = first_at_least(sorted_keys, lo_key)
                hi = first_at_least(sorted_keys, hi_key + 1)
            for s in range(lo, hi):
                if order[s] == self_index[r]:
                    continue
                dx, dy, dz = qx - px[s], qy - py[s], qz - pz[s]
                d2 = dx * dx + dy * dy + dz * dz
                if not d2 <= near2:
                    continue
                d = np.sqrt(d2)
                if not d < radius:
                    continue
                u = min(max(d * per_bin - 0.5, 0.0), top)
                b = np.int64(u)
                frac = u - b
                t = 1.0 - d * slope
                w_lo = np.floor((1.0 - frac) * t * scale + 0.5) * WEIGHT_QUANTUM
                w_hi = np.floor(frac * t * scale + 0.5) * WEIGHT_QUANTUM
                b_hi = min(b + 1, n_bins - 1)
                col = lab[s] * n_bins
                out[r, col + b] += w_lo
                out[r, col + b_hi] += w_hi


watch_compiles()  # an install's first compile is said (sgloc.kernels)
