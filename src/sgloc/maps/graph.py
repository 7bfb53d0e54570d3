"""SemanticGraph: objects (3D centre + semantic class) joined by edges within a radius."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np
from scipy import sparse

from sgloc.errors import InvalidGraphError, SglocError
from sgloc.maps.files import GRAPH_FILES
from sgloc.validation import check_graph_arrays, check_real

DEFAULT_EDGE_RADIUS = 20.0
#: Most vertices for which `SemanticGraph.distances` builds the dense matrix (3.2 GB here).
DENSE_LIMIT = 20_000


class SemanticGraph:
    """A robot's object map as a weighted graph.

    Args:
        positions: (n,3) object centres in metres, in the robot's map frame.
        labels: (n,) non-negative integer class ids.
        Limits (sgloc.validation): at most MAX_VERTICES objects and MAX_CLASSES distinct classes,
        coordinates within +-MAX_COORDINATE metres; InvalidGraphError beyond them.
        edge_radius: two vertices are neighbours when closer than this (metres, Guo: 20 m).
        name: optional name used in messages.

    The full distance matrix (the paper's weighted graph) and the adjacency are computed
    lazily and cached; the graph is immutable. The pipeline never builds the distance matrix
    (n^2 floats): it queries neighbours within a radius (KD-trees, grids).
    """

    def __init__(
        self,
        positions: np.ndarray,
        labels: np.ndarray,
        edge_radius: float = DEFAULT_EDGE_RADIUS,
        name: str | None = None,
    ) -> None:
        self.name = name or "graph"
        pos, lab = check_graph_arrays(self.name, positions, labels)
        try:
            edge_radius = check_real("edge_radius", edge_radius, 0.0, low_open=True, unit="m")
        except SglocError as e:
            raise InvalidGraphError(f"{self.name}: {e}") from None
        pos.flags.writeable = False
        lab.flags.writeable = False
        self.positions = pos
        self.labels = lab
        self.edge_radius = float(edge_radius)

    # -- basic properties -------------------------------------------------------------------
    def __len__(self) -> int:
        return self.positions.shape[0]

    @property
    def n_vertices(self) -> int:
        return len(self)

    @cached_property
    def n_classes(self) -> int:
        """One more than the largest class id (0 for an empty graph); computed once (a pass
        over the labels: a large map's is asked on every query)."""
        return int(self.labels.max()) + 1 if len(self) else 0

    def __repr__(self) -> str:
        return (
            f"SemanticGraph(name={self.name!r}, n={len(self)}, edges={self.n_edges}, "
            f"classes={len(np.unique(self.labels))}, edge_radius={self.edge_radius})"
        )

    @cached_property
    def distances(self) -> np.ndarray:
        """(n,n) Euclidean distances between all vertices, metres: 8 n^2 bytes, for small
        graphs (at most DENSE_LIMIT vertices; InvalidGraphError beyond)."""
        if len(self) > DENSE_LIMIT:
            raise InvalidGraphError(
                f"{self.name}: the dense distance matrix of {len(self):,} objects would take "
                f"{8e-9 * len(self) ** 2:.1f} GB (at most {DENSE_LIMIT:,} objects); query "
                "neighbours within a radius instead (scipy.spatial.cKDTree of graph.positions)."
            )
        from scipy.spatial.distance import cdist  # deferred: scipy.spatial loads in ~0.2 s

        d = cdist(self.positions, self.positions)
        d.flags.writeable = False
        return d

    @cached_property
    def adjacency(self) -> sparse.csr_array:
        """(n,n) symmetric 0/1 adjacency (float64 CSR): distance < edge_radius, no self loops."""
        from scipy.spatial import cKDTree

        tree = cKDTree(self.positions)
        pairs = tree.query_pairs(self.edge_radius, output_type="ndarray", p=2.0)
        # query_pairs uses <=; the paper's rule is strict <.
        if pairs.size:
            d = np.linalg.norm(self.positions[pairs[:, 0]] - self.positions[pairs[:, 1]], axis=1)
            pairs = pairs[d < self.edge_radius]
        n = len(self)
        rows = np.concatenate([pairs[:, 0], pairs[:, 1]]) if pairs.size else np.zeros(0, int)
        cols = np.concatenate([pairs[:, 1], pairs[:, 0]]) if pairs.size else np.zeros(0, int)
        a = sparse.csr_array((np.ones(rows.size), (rows, cols)), shape=(n, n))
        a.sort_indices()
        return a

    @property
    def n_edges(self) -> int:
        return int(self.adjacency.nnz // 2)

    @cached_property
    def degrees(self) -> np.ndarray:
        """(n,) number of neighbours of each vertex."""
        return np.diff(self.adjacency.indptr)

    # -- derived graphs ---------------------------------------------------------------------
    def transformed(self, T: np.ndarray, name: str | None = None) -> SemanticGraph:
        """The same graph with positions mapped by the 4x4 rigid transform T (p' = R p + t)."""
        T = np.asarray(T, dtype=np.float64)
        pos = self.positions @ T[:3, :3].T + T[:3, 3]
        return SemanticGraph(pos, self.labels, self.edge_radius, name or self.name)

    def subgraph(self, index: np.ndarray, name: str | None = None) -> SemanticGraph:
        """The graph on the vertices selected by `index` (boolean mask or integer indices)."""
        idx = np.asarray(index)
        return SemanticGraph(
            self.positions[idx], self.labels[idx], self.edge_radius, name or self.name
        )

    def reordered(self, order: np.ndarray, labels: np.ndarray) -> SemanticGraph:
        """The graph on the vertices `order` (integer indices, in that order; a permutation or
        a subset) with the class ids `labels` (len(order),) in place of theirs: a renumbering
        of this graph's classes (non-negative integers; not checked again, nor the positions,
        checked when this graph was built)."""
        out = SemanticGraph.__new__(SemanticGraph)
        pos, lab = self.positions[order], np.asarray(labels, dtype=np.int64)
        if lab.shape != (len(pos),):
            raise InvalidGraphError(f"{self.name}: {lab.shape} labels for {len(pos)} vertices.")
        pos.flags.writeable = False
        lab = lab if lab.base is None and lab is not labels else lab.copy()
        lab.flags.writeable = False
        out.name, out.positions, out.labels, out.edge_radius = (
            self.name,
            pos,
            lab,
            self.edge_radius,
        )
        return out

    def with_edge_radius(self, edge_radius: float) -> SemanticGraph:
        """A copy with another edge radius (metres)."""
        return SemanticGraph(self.positions, self.labels, edge_radius, self.name)

    # -- files ------------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path, edge_radius: float = DEFAULT_EDGE_RADIUS) -> SemanticGraph:
        """Read a graph from `.pcd` (Guo's packed-rgb Airsim classes), `.json`, `.npz`, `.ply`,
        `.csv` or `.txt` (docs/formats.md)."""
        positions, labels = GRAPH_FILES.read(path)
        return cls(positions, labels, edge_radius, name=Path(path).name)

    def save(self, path: str | Path) -> Path:
        """Write the graph as `.pcd`, `.json`, `.npz`, `.ply`, `.csv` or `.txt` (chosen by the
        suffix; `load` reads each back)."""
        return GRAPH_FILES.write(path, self.positions, self.labels, edge_radius=self.edge_radius)
