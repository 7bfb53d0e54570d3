"""Semantic histogram descriptor (Guo et al., RA-L 2021)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.descriptors.base import Descriptor, one_hot
from sgloc.maps.graph import SemanticGraph


@dataclass
class HistogramDescriptor(Descriptor):
    """Counts of every 2-hop label path i -> j -> k (j a neighbour of i, k a neighbour of j,
    k = i allowed), binned by (l_j, l_k): raw counts, L*L bins.

    Guo bins at `l_i*L^2 + l_j*L + l_k`; the `l_i` block is fixed by the vertex's own class, and
    only same-class vertices are ever compared, so we store only that block (the cosine
    similarity is identical). Computed as two sparse products: N = A @ onehot gives each vertex's
    neighbour-label counts; H = A @ E with E[j, l_j*L + k] = N[j, k].
    """

    name = "histogram"

    def __call__(self, graph: SemanticGraph, n_classes: int, rng: np.random.Generator):
        A = graph.adjacency
        L = n_classes
        N = (A @ one_hot(graph.labels, L)).toarray()  # (n, L) neighbour label counts
        E = np.zeros((len(graph), L * L))
        cols = graph.labels[:, None] * L + np.arange(L)[None, :]
        np.put_along_axis(E, cols, N, axis=1)
        return A @ E
