"""Random-walk descriptor (Gawel et al., X-View, RA-L 2018)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from sgloc.descriptors.base import Descriptor
from sgloc.graph import SemanticGraph
from sgloc.validation import MAX_WALK_LENGTH, integer, setting


@dataclass
class RandomWalkDescriptor(Descriptor):
    """`n_walks` random walks of `walk_length` steps from every vertex; the next vertex is
    uniform over the current one's neighbours (a vertex without neighbours stays put).

    X-View keeps the multiset of label sequences; we embed it as a histogram over the
    L**walk_length possible sequences (the start vertex's own label is implied, as only
    same-class vertices are compared), so the paper's cosine similarity applies. All walks of
    all vertices advance together, one vectorised step at a time. Returns a CSR matrix.
    """

    #: 1000: a walk of 3 steps over L = 11 classes falls in one of 1331 sequences; 200 walks
    #: left each histogram mostly sampling noise (the Airsim maps then localized in 2 of 10
    #: random poses, against 10 of 10 accepted with 1000; 3x the time, ~0.1 s per map).
    n_walks: int = setting(1000, check=integer(1, 100_000))
    walk_length: int = setting(3, check=integer(1, MAX_WALK_LENGTH))
    name = "random_walk"

    def __call__(self, graph: SemanticGraph, n_classes: int, rng: np.random.Generator):
        n, L = len(graph), n_classes
        if self.n_walks < 1 or self.walk_length < 1:
            raise ValueError("random_walk needs n_walks >= 1 and walk_length >= 1")
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
