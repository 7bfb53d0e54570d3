"""Numpy references of `sgloc.maps.canonical`'s kernels: the canonical order, the duplicate
search and the pairs mapped back to the caller's vertex order."""

from __future__ import annotations

import numpy as np

from sgloc.maps.canonical import DUPLICATE_RADIUS
from sgloc.maps.graph import SemanticGraph


def canonical_order(graph: SemanticGraph) -> np.ndarray:
    """Vertex indices sorted by (label, x, y, z), ties in input order (np.lexsort)."""
    p = graph.positions
    return np.lexsort((p[:, 2], p[:, 1], p[:, 0], graph.labels))


def without_duplicates(graph: SemanticGraph, order: np.ndarray) -> np.ndarray:
    """`sgloc.maps.canonical.without_duplicates` in numpy: the same-class pairs within
    DUPLICATE_RADIUS (squared distance <= its square) by a KD-tree, joined into groups
    (connected components), the first of each group in `order` kept."""
    from scipy.sparse import coo_array
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    p, lab = graph.positions[order], graph.labels[order]
    pairs = cKDTree(p).query_pairs(DUPLICATE_RADIUS * (1 + 1e-9), output_type="ndarray")
    close = np.sum((p[pairs[:, 1]] - p[pairs[:, 0]]) ** 2, axis=1) <= DUPLICATE_RADIUS**2
    pairs = pairs[close & (lab[pairs[:, 0]] == lab[pairs[:, 1]])]
    if len(pairs) == 0:
        return order
    n = len(order)
    links = coo_array((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, group = connected_components(links, directed=False)
    return order[np.sort(np.unique(group, return_index=True)[1])]


def canonical_form(graph: SemanticGraph, classes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(order, labels) of `CanonicalPair._form`: the order without duplicates, and the class
    ids of those vertices renumbered by `classes`."""
    order = without_duplicates(graph, canonical_order(graph))
    return order, np.searchsorted(classes, graph.labels[order])


def restored_pairs(
    pairs: np.ndarray, scores: np.ndarray, qo: np.ndarray, to: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`sgloc.maps.canonical_kernels.restored_pairs`: pairs mapped back by the orders qo, to,
    sorted by (query, score descending, target) (without scores: by (query, target))."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    pairs = np.stack([qo[pairs[:, 0]], to[pairs[:, 1]]], axis=1)
    keys = (pairs[:, 1], -scores, pairs[:, 0]) if len(scores) else (pairs[:, 1], pairs[:, 0])
    order = np.lexsort(keys)
    return pairs[order], order


def restore(pair, result):
    """`CanonicalPair.restore` with `restored_pairs` in numpy."""
    scores = np.asarray(result.scores)
    qo, to = pair.query_order, pair.target_order
    result.candidates, order = restored_pairs(result.candidates, np.asarray(scores, np.float64),
                                              qo, to)  # fmt: skip
    result.scores = scores[order]
    for name in ("survivors", "matches"):
        setattr(result, name, restored_pairs(getattr(result, name), np.zeros(0), qo, to)[0])
    return result
