"""Numpy references of the descriptors' kernels: the distance histograms by KD-tree pairs
(`sgloc.maps.neighbor_kernels.distance_histograms`) and the random walks
(`sgloc.descriptors.walk_kernels`)."""

from __future__ import annotations

import numpy as np
from scipy import sparse

from sgloc.descriptors.distance import DistanceHistogramDescriptor
from sgloc.descriptors.random_walk import RandomWalkDescriptor
from sgloc.maps.graph import SemanticGraph

#: `sgloc.maps.neighbor_kernels.WEIGHT_QUANTUM` (not imported: a reference loads no kernel module).
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


def distance_histograms(
    desc: DistanceHistogramDescriptor, positions: np.ndarray, labels: np.ndarray, n_classes: int
) -> np.ndarray:
    """`desc.rows(positions, labels, n_classes)`: all rows by KD-tree pairs in numpy."""
    n, nb, R = len(positions), int(desc.n_bins), float(desc.radius)
    pairs, d = neighbour_pairs(positions, R)
    bins, w = soft_bins(d, nb / R, nb)
    w = w * (1.0 - d * (float(desc.taper) / R))[:, None]
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


def random_walks(
    desc: RandomWalkDescriptor, graph: SemanticGraph, n_classes: int, rng: np.random.Generator
):
    """`desc(graph, n_classes, rng)` in numpy: all walks of all vertices advance together, one
    vectorised step at a time (the same bits, and the same state of `rng` afterwards)."""
    n, L = len(graph.labels), n_classes
    A = graph.adjacency
    indptr, indices = A.indptr, A.indices
    deg = np.diff(indptr)
    current = np.repeat(np.arange(n), desc.n_walks)
    code = np.zeros(current.size, dtype=np.int64)
    for _ in range(desc.walk_length):
        d = deg[current]
        step = (rng.random(current.size) * d).astype(np.int64)
        moved = (
            indices[np.minimum(indptr[current] + step, max(indices.size - 1, 0))]
            if indices.size
            else current
        )
        current = np.where(d > 0, moved, current)
        code = code * L + graph.labels[current]
    rows = np.repeat(np.arange(n), desc.n_walks)
    dim = L**desc.walk_length
    out = sparse.csr_array((np.ones(rows.size), (rows, code)), shape=(n, dim))
    out.sum_duplicates()
    # A vertex with no neighbour has no structure to describe: no descriptor.
    out = sparse.csr_array(sparse.diags_array((deg > 0).astype(float)) @ out)
    return out


def histograms_at(
    centres: np.ndarray, self_index: np.ndarray, points: np.ndarray, labels: np.ndarray,
    n_classes: int, radius: float, n_bins: int, taper: float,
) -> np.ndarray:  # fmt: skip
    """`sgloc.maps.neighbor_kernels.distance_histograms` by KD-tree pairs: at each centre, the
    descriptor's histogram over the `points` closer than `radius`, leaving out point
    `self_index[i]` of centre i (-1: none). Each pair's weight is that of `distance_histograms`
    above (the same bits)."""
    nb, R = int(n_bins), float(radius)
    out = np.zeros((len(centres), n_classes * nb))
    if len(centres) == 0 or len(points) == 0:
        return out
    from scipy.spatial import cKDTree

    near = cKDTree(centres).sparse_distance_matrix(cKDTree(points), R * (1 + 1e-9) + 1e-12,
                                                   output_type="ndarray")  # fmt: skip
    i, j = near["i"].astype(np.int64), near["j"].astype(np.int64)
    keep = j != np.asarray(self_index)[i]
    i, j = i[keep], j[keep]
    v = centres[i] - points[j]
    d = np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2])
    keep = d < R
    i, j, d = i[keep], j[keep], d[keep]
    bins, w = soft_bins(d, nb / R, nb)
    w = w * (1.0 - d * (float(taper) / R))[:, None]
    w = np.floor(w * (1.0 / WEIGHT_QUANTUM) + 0.5) * WEIGHT_QUANTUM
    flat = (((i * n_classes + labels[j]) * nb)[:, None] + bins).ravel()
    H = np.bincount(flat, w.ravel(), minlength=len(centres) * n_classes * nb)
    return H.reshape(len(centres), n_classes * nb)
