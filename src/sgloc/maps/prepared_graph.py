"""A graph with what the pipeline derives from it and reuses: its descriptors, the neighbour
grids of the acceptance test's chance model (per radius), its class counts and the candidate-
search indexes of its descriptors' classes.

State held in the open: `Localizer.__call__` makes one per graph of a call (the prepared query,
and the prepared target unless the target comes as a `sgloc.PreparedMap`, which keeps its own
for every query) and hands it to the stages, which read or fill it instead of a module-level
cache. So a result never depends on what ran before in the process, and the state lives
exactly as long as the object the caller holds.

    prepared = PreparedGraph(graph)
    prepared.grid(5.0)         # built on first use, then kept (`sgloc.maps.neighbor_kernels`)
    prepared.class_indexes     # {class: (rows, index)}, filled by `matching_index.class_index`
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sgloc.maps.graph import SemanticGraph


class PreparedGraph:
    """One graph (in the pipeline's canonical form) and the structures built from it.

    graph: the SemanticGraph; positions (n,3) float64 and labels (n,) int64: its arrays as
        the kernels take them; descriptors: its descriptor rows when computed (dense (n, d)
        or CSR), else None; blocks: the matching kernel's class blocks when kept
        (`sgloc.matching.candidates.TargetBlocks`, a prepared map's), else None; class_indexes: the
        candidate-search index of each class of `descriptors` built so far
        (`sgloc.matching.index.class_index` fills it).
    """

    def __init__(self, graph: SemanticGraph, descriptors: Any = None, blocks: Any = None) -> None:
        self.graph = graph
        self.positions = np.ascontiguousarray(graph.positions, dtype=np.float64)
        self.labels = np.ascontiguousarray(graph.labels, dtype=np.int64)
        self.descriptors = descriptors
        self.blocks = blocks
        self.class_indexes: dict[int, tuple[np.ndarray, Any]] = {}
        self._grids: dict[float, Any] = {}
        self._counts: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.graph)

    def grid(self, radius: float):
        """The neighbour grid (`sgloc.maps.neighbor_kernels.CellGrid`) of the graph's objects for
        searches within `radius` metres: built on first use, kept for later ones."""
        radius = float(radius)
        grid = self._grids.get(radius)
        if grid is None:
            from sgloc.maps.neighbor_kernels import cell_grid

            grid = self._grids[radius] = cell_grid(self.positions, self.labels, radius)
        return grid

    @property
    def class_counts(self) -> np.ndarray:
        """(labels.max() + 1,) float64, read-only: the number of objects of each class."""
        if self._counts is None:
            counts = np.bincount(self.labels).astype(np.float64)
            counts.flags.writeable = False
            self._counts = counts
        return self._counts


__all__ = ["PreparedGraph"]
