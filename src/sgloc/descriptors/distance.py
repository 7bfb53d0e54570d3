"""Distance-aware descriptors on the weighted graph (object-to-object distances)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from sgloc.descriptors.base import Descriptor
from sgloc.maps.graph import SemanticGraph
from sgloc.validation import MAX_COORDINATE, integer, real, setting


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
    not only the adjacency; built by a compiled search on a grid of cells
    (`sgloc.maps.neighbor_kernels.distance_histograms`), memory linear in the objects. Each
    weight is rounded to a multiple of `sgloc.maps.neighbor_kernels.WEIGHT_QUANTUM`, so every
    bin's sum is exact in any order (an update of a few rows gives the same bits).
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
        labels (n,) class ids < n_classes): (len(rows), n_classes * n_bins). Compiled
        (`sgloc.maps.neighbor_kernels.distance_histograms`)."""
        every = rows is None
        rows = np.arange(len(positions)) if every else np.asarray(rows, dtype=np.int64)
        if len(positions) == 0:
            return np.zeros((len(rows), n_classes * int(self.n_bins)))
        from sgloc.maps.neighbor_kernels import distance_histograms

        positions = np.ascontiguousarray(positions, dtype=np.float64)
        return distance_histograms(
            positions if every else positions[rows], rows, positions,
            np.asarray(labels, dtype=np.int64), n_classes, float(self.radius),
            int(self.n_bins), float(self.taper),
        )  # fmt: skip


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
