"""Distance-aware descriptors on the weighted graph (object-to-object distances)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from sgloc.descriptors.base import Descriptor
from sgloc.kernels import use_compiled
from sgloc.maps.graph import SemanticGraph
from sgloc.validation import MAX_COORDINATE, integer, real, setting

#: Descriptor weights are multiples of this (`sgloc.maps.neighbor_kernels.WEIGHT_QUANTUM`).
WEIGHT_QUANTUM = 2.0**-24

def neighbour_pairs(positions: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(pairs (e,2) int i<j, distances (e,) m) of the vertices closer than `radius` metres
    (KD-tree; memory linear in the number of pairs)."""
    if len(positions) < 2:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    from scipy.spatial import cKDTree  # deferred: scipy.spatial loads in ~0.2 s

    pairs = cKDTree(positions).query_pairs(radius, output_type="ndarray")
    if pairs.size == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    v = positions[pairs[:, 0]] - positions[pairs[:, 1]]
    # Summed as x, y, z in turn: the rounding of the compiled descriptor kernel.
    d = np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2])
    keep = d < radius
    return pairs[keep].astype(np.int64), d[keep]


def soft_bins(values: np.ndarray, per_bin: float, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Linear (tent) soft binning of `values` >= 0 into `n_bins` bins of width 1 / per_bin,
    bin b centred at (b + 0.5) / per_bin: (bins (v,2) int, weights (v,2)), weights summing to 1
    per value. Values below the first centre or beyond the last fall wholly in the end bin."""
    u = np.clip(values * per_bin - 0.5, 0.0, n_bins - 1.0)
    lo = u.astype(np.int64)  # u >= 0: truncation is floor
    frac = u - lo
    hi = np.minimum(lo + 1, n_bins - 1)
    return np.stack([lo, hi], axis=1), np.stack([1.0 - frac, frac], axis=1)


@dataclass
class DistanceHistogramDescriptor(Descriptor):
    """Per vertex, a soft-binned histogram over (neighbour class, distance to it) of every
    other vertex within `radius` metres: n_classes * n_bins bins, bin width radius / n_bins,
    linear interpolation between the two nearest bin centres (so a distance measured 1 m
    differently in the other map moves weight between neighbouring bins instead of jumping).

    taper: a neighbour at distance d weighs 1 - taper * d / radius, so near neighbours, which
    two partly overlapping maps more likely share, count more (0: all weigh 1).

    Depends only on distances, so it is invariant to any rotation, translation and to the
    direction the robot drove through the place. Uses the weighted graph (metric distances),
    not only the adjacency; built from KD-tree pairs, memory linear in the pairs.
    """

    radius: float = setting(40.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    n_bins: int = setting(16, check=integer(1, 1024))
    taper: float = setting(0.8, check=real(0.0, 1.0))
    name = "distance_histogram"

    def __call__(self, graph: SemanticGraph, n_classes: int, rng: np.random.Generator):
        # Deterministic (rng unused): a map described once is kept by the caller (a prepared
        # map, `sgloc.pipeline.prepared`). Read-only, as the rows a prepared map holds.
        H = self.rows(graph.positions, graph.labels, n_classes)
        H.flags.writeable = False
        return H

    def rows(
        self,
        positions: np.ndarray,
        labels: np.ndarray,
        n_classes: int,
        rows: np.ndarray | None = None,
    ) -> np.ndarray:
        """The descriptors of the objects `rows` (default all) of the map (positions (n,3) m,
        labels (n,) class ids < n_classes): (len(rows), n_classes * n_bins). The same bits by
        the compiled kernel and the numpy reference (`histogram_reference`)."""
        every = rows is None
        rows = np.arange(len(positions)) if every else np.asarray(rows, dtype=np.int64)
        if use_compiled(len(positions)):
            from sgloc.maps.neighbor_kernels import distance_histograms

            positions = np.ascontiguousarray(positions, dtype=np.float64)
            return distance_histograms(
                positions if every else positions[rows], rows, positions,
                np.asarray(labels, dtype=np.int64), n_classes, float(self.radius),
                int(self.n_bins), float(self.taper),
            )  # fmt: skip
        return self.histogram_reference(positions, labels, n_classes)[rows]

    def histogram_reference(
        self, positions: np.ndarray, labels: np.ndarray, n_classes: int
    ) -> np.ndarray:
        """All rows by KD-tree pairs in numpy (the compiled kernel's reference)."""
        n, nb, R = len(positions), int(self.n_bins), float(self.radius)
        pairs, d = neighbour_pairs(positions, R)
        bins, w = soft_bins(d, nb / R, nb)
        w = w * (1.0 - d * (float(self.taper) / R))[:, None]
        # Multiples of WEIGHT_QUANTUM: every bin's sum is exact, in any order of its terms.
        w = np.floor(w * (1.0 / WEIGHT_QUANTUM) + 0.5) * WEIGHT_QUANTUM
        i, j, lab = pairs[:, 0], pairs[:, 1], labels
        # Each pair counts in both endpoints' histograms, under the other endpoint's class.
        # Dense: n x (classes x bins) floats, linear in the vertices (cheaper than CSR here).
        row_i = (i * n_classes + lab[j]) * nb
        row_j = (j * n_classes + lab[i]) * nb
        flat = np.concatenate([row_i[:, None] + bins, row_j[:, None] + bins]).ravel()
        H = np.bincount(flat, np.concatenate([w, w]).ravel(), minlength=n * n_classes * nb)
        return H.reshape(n, n_classes * nb)


@dataclass
class TriangleDescriptor(Descriptor):
    """Per vertex, a histogram of the triangles it forms with pairs of its neighbours within
    `radius` metres, binned by (class of the two others, sorted as a pair; the two sides at the
    vertex, sorted, each in `n_bins` bins of radius / n_bins). At most `max_neighbours` nearest
    neighbours per vertex enter (so the cost is bounded: n * max_neighbours^2 / 2 triangles).

    A triangle's side lengths do not change with rotation or travel direction; adding the
    classes makes a signature far rarer than a single distance.
    """

    radius: float = setting(30.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    n_bins: int = setting(6, check=integer(1, 64))
    max_neighbours: int = setting(12, check=integer(2, 1000))
    name = "triangles"

    def __call__(self, graph: SemanticGraph, n_classes: int, rng: np.random.Generator):
        n, nb, L = len(graph), int(self.n_bins), n_classes
        k = int(min(self.max_neighbours, max(n - 1, 0)))
        n_cols = L * L * nb * nb
        if n < 3 or k < 2:
            return sparse.csr_array((n, n_cols))
        from scipy.spatial import cKDTree

        d, j = cKDTree(graph.positions).query(
            graph.positions, k + 1, distance_upper_bound=float(self.radius)
        )
        d, j = d[:, 1:], j[:, 1:]  # drop the vertex itself
        valid = np.isfinite(d) & (d < self.radius)
        a, b = np.triu_indices(k, 1)
        ok = valid[:, a] & valid[:, b]
        vi, pi = np.nonzero(ok)
        ja, jb = j[vi, a[pi]], j[vi, b[pi]]
        da, db = d[vi, a[pi]], d[vi, b[pi]]
        la, lb = graph.labels[ja], graph.labels[jb]
        # Canonical order: by class, then by side length, so the signature is symmetric.
        swap = (la > lb) | ((la == lb) & (da > db))
        la, lb = np.where(swap, lb, la), np.where(swap, la, lb)
        da, db = np.where(swap, db, da), np.where(swap, da, db)
        width = float(self.radius) / nb
        ba = np.minimum((da / width).astype(np.int64), nb - 1)
        bb = np.minimum((db / width).astype(np.int64), nb - 1)
        cols = ((la * L + lb) * nb + ba) * nb + bb
        H = sparse.coo_array((np.ones(vi.size), (vi, cols)), shape=(n, n_cols)).tocsr()
        H.sum_duplicates()
        return H
