"""Canonical form of a graph pair at the localizer's entry: vertices sorted by (class, x, y, z),
an object listed twice (same class, within DUPLICATE_RADIUS) kept once, and the classes present
renumbered 0..L-1. The pipeline then gives the same answer for any
vertex order of either graph, and no array is sized by a large class id. `restore` maps the
result's vertex indices back to the caller's order.

Built for every call; a target localized against again and again is prepared once instead
(`sgloc.pipeline.prepared.PreparedMap` keeps its canonical form,
`CanonicalPair.with_canonical_target`).

The orders, the duplicate search and `restore` run compiled kernels
(`sgloc.maps.canonical_kernels`); their numpy references live with the tests
(`tests/references/`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from scipy import sparse

from sgloc.maps.graph import SemanticGraph

#: Objects of one class closer than this (metres) are one object listed twice: kept once (the
#: first in canonical order), else every copy would be a rival of its twin in the ratio tests.
DUPLICATE_RADIUS = 1e-3


def canonical_order(graph: SemanticGraph) -> np.ndarray:
    """Vertex indices sorted by (label, x, y, z); ties (duplicate objects) keep input order."""
    if len(graph.positions) == 0:
        return np.zeros(0, dtype=np.int64)
    from sgloc.maps.canonical_kernels import canonical_order_kernel

    return canonical_order_kernel(*_kernel_arrays(graph))


def _kernel_arrays(graph: SemanticGraph) -> tuple[np.ndarray, np.ndarray]:
    """The graph's positions and labels as the kernels take them (C-ordered float64, int64)."""
    return (np.ascontiguousarray(graph.positions, dtype=np.float64),
            np.ascontiguousarray(graph.labels, dtype=np.int64))  # fmt: skip


#: Objects of one class each within DUPLICATE_RADIUS of the next in x, in canonical order,
#: are compared pairwise up to runs this long (longer runs: a KD-tree search).
_RUN_SEARCH = 8


def _close_pairs(graph: SemanticGraph, order: np.ndarray) -> np.ndarray:
    """(k,2) positions i < j in `order` (`canonical_order`) of same-class objects within
    DUPLICATE_RADIUS. Such a pair is at most that far apart in x, so in the order (class, then
    x) every step between them is too: only runs of such steps hold candidates."""
    lab, p = graph.labels[order], graph.positions[order]
    step = (lab[1:] == lab[:-1]) & (p[1:, 0] - p[:-1, 0] <= DUPLICATE_RADIUS)
    if not step.any():
        return np.zeros((0, 2), np.int64)
    steps = np.concatenate([[0], np.cumsum(step)])
    found = []
    for s in range(1, _RUN_SEARCH + 1):  # candidates s places apart
        i = np.flatnonzero(steps[s:] - steps[:-s] == s)
        if i.size == 0:
            return np.concatenate(found) if found else np.zeros((0, 2), np.int64)
        close = np.sum((p[i + s] - p[i]) ** 2, axis=1) <= DUPLICATE_RADIUS**2
        found.append(np.stack([i[close], i[close] + s], axis=1))
    from scipy.spatial import cKDTree  # long runs (objects on a line of one x)

    pairs = cKDTree(p).query_pairs(DUPLICATE_RADIUS, output_type="ndarray")
    return pairs[lab[pairs[:, 0]] == lab[pairs[:, 1]]]


def without_duplicates(graph: SemanticGraph, order: np.ndarray) -> np.ndarray:
    """`order` (`canonical_order(graph)`) without the vertices that repeat an earlier one of it
    (same class, closer than DUPLICATE_RADIUS); without duplicates it comes back unchanged
    (or equal)."""
    if len(order) == 0:
        return order
    from sgloc.maps.canonical_kernels import first_of_duplicates

    kept, long = first_of_duplicates(order, *_kernel_arrays(graph), DUPLICATE_RADIUS,
                                     _RUN_SEARCH)  # fmt: skip
    return _first_of_close_groups(graph, order) if long else kept


def _first_of_close_groups(graph: SemanticGraph, order: np.ndarray) -> np.ndarray:
    """`without_duplicates` in numpy, for runs of close objects longer than _RUN_SEARCH (the
    compiled search leaves those to a KD-tree)."""
    pairs = _close_pairs(graph, order)
    if len(pairs) == 0:
        return order
    from scipy.sparse.csgraph import connected_components

    n = len(order)
    links = sparse.coo_array((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, group = connected_components(links, directed=False)
    first = np.unique(group, return_index=True)[1]
    return order[np.sort(first)]


def _class_table(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.union1d of two int64 label arrays: marked in a table when the ids are small (the
    same ids, sorted, without a sort)."""
    top = max(int(a.max(initial=-1)), int(b.max(initial=-1)))
    if top >= 4 * (len(a) + len(b)) + 64:
        return np.union1d(a, b)
    present = np.zeros(top + 1, dtype=bool)
    present[a], present[b] = True, True
    return np.flatnonzero(present)


class CanonicalPair:
    """(query, target) in canonical form, the config with class weights renumbered to match,
    and the maps back to the caller's vertex indices and class ids."""

    #: The canonical target's `PreparedGraph` (descriptors, matching blocks, grids) when the
    #: target comes prepared (`sgloc.pipeline.prepared.PreparedMap.pair`), else None.
    prepared_target = None

    def __init__(self, query: SemanticGraph, target: SemanticGraph, config: Any) -> None:
        self.classes = _class_table(query.labels, target.labels)  # original id of each new id
        self.query_order, self.query = self._canonical(query)
        self.target_order, self.target = self._canonical(target)
        self._set_config(config)

    @classmethod
    def with_canonical_target(
        cls,
        query: SemanticGraph,
        classes: np.ndarray,
        target_order: np.ndarray,
        target: SemanticGraph,
        config: Any,
    ) -> CanonicalPair:
        """The pair of `query` and a target already in canonical form under `classes` (which
        hold every class of the query): nothing of the target's size is computed."""
        pair = cls.__new__(cls)
        pair.classes = classes
        pair.query_order, pair.query = pair._canonical(query)
        pair.target_order, pair.target = target_order, target
        pair._set_config(config)
        return pair

    def _set_config(self, config: Any) -> None:
        self.original_config = config
        self.config = config
        if getattr(config, "class_weights", None):
            weights = {
                int(np.searchsorted(self.classes, c)): w
                for c, w in config.class_weights.items()
                if np.isin(int(c), self.classes)
            }
            self.config = dataclasses.replace(config, class_weights=weights)

    def _canonical(self, graph: SemanticGraph) -> tuple[np.ndarray, SemanticGraph]:
        """(order, canonical graph) of `graph` under this pair's class table."""
        order, labels = self._form(graph)
        order.flags.writeable = False
        return order, self._rebuilt(graph, order, labels)

    def _form(self, graph: SemanticGraph) -> tuple[np.ndarray, np.ndarray]:
        """(order, labels): `without_duplicates(graph, canonical_order(graph))` and the class
        ids of those vertices renumbered by this pair's class table (one compiled pass)."""
        if len(graph) == 0:
            order = np.zeros(0, dtype=np.int64)
            return order, np.searchsorted(self.classes, graph.labels[order])
        from sgloc.maps.canonical_kernels import canonical_form

        classes = np.ascontiguousarray(self.classes, dtype=np.int64)
        order, labels, long = canonical_form(*_kernel_arrays(graph), classes,
                                             DUPLICATE_RADIUS, _RUN_SEARCH)  # fmt: skip
        if not long:
            return order, labels
        order = _first_of_close_groups(graph, order)  # `order`: the whole canonical order
        return order, np.searchsorted(self.classes, graph.labels[order])

    def _rebuilt(
        self, graph: SemanticGraph, order: np.ndarray, labels: np.ndarray
    ) -> SemanticGraph:
        out = graph.reordered(order, labels)
        # Carry over what the caller's graph has already computed, permuted (cheaper than anew).
        cache = graph.__dict__
        if "adjacency" in cache:
            adjacency = sparse.csr_array(cache["adjacency"][order][:, order])
            adjacency.sort_indices()
            out.__dict__["adjacency"] = adjacency
        if "distances" in cache:
            distances = cache["distances"][np.ix_(order, order)]
            distances.flags.writeable = False
            out.__dict__["distances"] = distances
        return out

    def restore(self, result: Any) -> Any:
        """The result with every (query index, target index) array in the caller's indices,
        rows sorted by them (candidates keep their scores)."""
        qo, to = self.query_order, self.target_order
        scores = np.asarray(result.scores)
        from sgloc.maps.canonical_kernels import restored_pairs

        def back(pairs: np.ndarray, scores: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            pairs = np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2)
            if len(pairs) == 0:  # nothing to map back
                return np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.int64)
            return restored_pairs(pairs, scores, qo, to)

        result.candidates, order = back(result.candidates, np.asarray(scores, np.float64))
        result.scores = scores[order]
        for name in ("survivors", "matches"):
            setattr(result, name, back(getattr(result, name), np.zeros(0))[0])
        return result

