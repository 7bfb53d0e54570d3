"""Random-walk descriptor (Gawel et al., X-View, RA-L 2018)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from sgloc.descriptors.base import Descriptor
from sgloc.kernels import use_compiled
from sgloc.maps.graph import SemanticGraph
from sgloc.validation import MAX_WALK_LENGTH, integer, setting


@dataclass
class RandomWalkDescriptor(Descriptor):
    """`n_walks` random walks of `walk_length` steps from every vertex; the next vertex is
    uniform over the current one's neighbours (a vertex without neighbours stays put).

    X-View keeps the multiset of label sequences; we embed it as a histogram over the
    L**walk_length possible sequences (the start vertex's own label is implied, as only
    same-class vertices are compared), so the paper's cosine similarity applies. A compiled
    kernel walks and counts (`sgloc.descriptors.walk_kernels`); `reference` is its numpy twin.
    """

    #: 1000: a walk of 3 steps over L = 11 classes falls in one of 1331 sequences; 200 walks
    #: left each histogram mostly sampling noise (the Airsim maps then localized in 2 of 10
    #: random poses, against 10 of 10 accepted with 1000; 3x the time, ~0.1 s per map).
    n_walks: int = setting(1000, check=integer(1, 100_000))
    walk_length: int = setting(3, check=integer(1, MAX_WALK_LENGTH))
    name = "random_walk"

    def __call__(self, graph: SemanticGraph, n_classes: int, rng: np.random.Generator):
        """(n, n_classes**walk_length) float64 CSR of walk counts per label sequence (codes
        descending within a row); draws walk_length * n * n_walks uniforms from `rng`. The
        compiled kernel when `sgloc.kernels.use_compiled` says so, else `reference` (the same
        bits, and the same state of `rng` afterwards)."""
        if self.n_walks < 1 or self.walk_length < 1:
            raise ValueError("random_walk needs n_walks >= 1 and walk_length >= 1")
        n = len(graph)
        if not use_compiled(n):
            return self.reference(graph, n_classes, rng)
        from sgloc.descriptors.walk_kernels import walk_histograms

        A = graph.adjacency
        # One draw of all the uniforms consumes the stream as the reference's one per step.
        u = rng.random(self.walk_length * n * self.n_walks)
        indptr, indices, data = walk_histograms(
            A.indptr.astype(np.int64), A.indices.astype(np.int64),
            np.ascontiguousarray(graph.labels, dtype=np.int64), u, self.n_walks,
            self.walk_length, n_classes,
        )  # fmt: skip
        shape = (n, n_classes**self.walk_length)
        if not data.size:  # no vertex with a neighbour: scipy's empty CSR, as the reference's
            return sparse.csr_array(shape)
        return sparse.csr_array((data, indices, indptr), shape=shape)

    def reference(self, graph: SemanticGraph, n_classes: int, rng: np.random.Generator):
        """The numpy reference of `__call__`: all walks of all vertices advance together, one
        vectorised step at a time."""
        n, L = len(graph), n_classes
        A = graph.adjacency
        indptr, indices = A.indptr, A.indices
        deg = np.diff(indptr)
        current = np.repeat(np.arange(n), self.n_walks)
        code = np.zeros(current.size, dtype=np.int64)
        for _ in range(self.walk_length):
            d = deg[current]
            step = (rng.random(current.size) * d).astype(np.int64)
            moved = (
                indices[np.minimum(indptr[current] + step, max(indices.size - 1, 0))]
                if indices.size
                else current
            )
            current = np.where(d > 0, moved, current)
            code = code * L + graph.labels[current]
        rows = np.repeat(np.arange(n), self.n_walks)
        dim = L**self.walk_length
        out = sparse.csr_array((np.ones(rows.size), (rows, code)), shape=(n, dim))
        out.sum_duplicates()
        # A vertex with no neighbour has no structure to describe: no descriptor.
        out = sparse.csr_array(sparse.diags_array((deg > 0).astype(float)) @ out)
        return out
