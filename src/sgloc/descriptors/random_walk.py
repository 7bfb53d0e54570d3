"""Random-walk descriptor (Gawel et al., X-View, RA-L 2018)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from sgloc.descriptors.base import Descriptor
from sgloc.maps.graph import SemanticGraph
from sgloc.validation import MAX_WALK_LENGTH, integer, setting


@dataclass
class RandomWalkDescriptor(Descriptor):
    """`n_walks` random walks of `walk_length` steps from every vertex; the next vertex is
    uniform over the current one's neighbours (a vertex without neighbours stays put).

    X-View keeps the multiset of label sequences; we embed it as a histogram over the
    L**walk_length possible sequences (the start vertex's own label is implied, as only
    same-class vertices are compared), so the paper's cosine similarity applies. A compiled
    kernel walks and counts (`sgloc.descriptors.walk_kernels`).
    """

    #: 1000: a walk of 3 steps over L = 11 classes falls in one of 1331 sequences; 200 walks
    #: left each histogram mostly sampling noise (the Airsim maps then localized in 2 of 10
    #: random poses, against 10 of 10 accepted with 1000; 3x the time, ~0.1 s per map).
    n_walks: int = setting(1000, check=integer(1, 100_000))
    walk_length: int = setting(3, check=integer(1, MAX_WALK_LENGTH))
    name = "random_walk"

    def __call__(self, graph: SemanticGraph, n_classes: int, rng: np.random.Generator):
        """(n, n_classes**walk_length) float64 CSR of walk counts per label sequence (codes
        descending within a row); draws walk_length * n * n_walks uniforms from `rng`, walk w
        of vertex v using uniform s * n * n_walks + v * n_walks + w at step s. Compiled."""
        if self.n_walks < 1 or self.walk_length < 1:
            raise ValueError("random_walk needs n_walks >= 1 and walk_length >= 1")
        n = len(graph)
        shape = (n, n_classes**self.walk_length)
        if n == 0:
            return sparse.csr_array(shape)
        from sgloc.descriptors.walk_kernels import walk_histograms

        A = graph.adjacency
        # One draw of all the uniforms (the stream as one draw per step would consume it).
        u = rng.random(self.walk_length * n * self.n_walks)
        indptr, indices, data = walk_histograms(
            A.indptr.astype(np.int64), A.indices.astype(np.int64),
            np.ascontiguousarray(graph.labels, dtype=np.int64), u, self.n_walks,
            self.walk_length, n_classes,
        )  # fmt: skip
        if not data.size:  # no vertex with a neighbour: scipy's empty CSR
            return sparse.csr_array(shape)
        return sparse.csr_array((data, indices, indptr), shape=shape)
