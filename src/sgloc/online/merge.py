"""Merge placed robots' object maps into one graph, fusing same-class duplicates."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from sgloc.geometry import apply
from sgloc.maps.graph import SemanticGraph


def merge_graphs(
    graphs: Sequence[SemanticGraph],
    T_fleet_robot: dict[int, np.ndarray],
    fuse_radius: float,
    name: str = "fleet",
) -> tuple[SemanticGraph, np.ndarray, np.ndarray, np.ndarray]:
    """Placed robots' objects in the world frame, same-class objects of different robots closer
    than `fuse_radius` metres fused (mean position, single-linkage groups).

    Returns (merged graph, robot of each merged object (first contributor), all objects' world
    positions (N,3), robot of each of those (N,))."""
    ids = sorted(T_fleet_robot)
    if not ids:
        return SemanticGraph(np.zeros((0, 3)), np.zeros(0, np.int64), name=name), *(
            np.zeros(0, np.int64),
        ) * 3
    pos = np.concatenate([apply(T_fleet_robot[i], graphs[i].positions) for i in ids])
    lab = np.concatenate([graphs[i].labels for i in ids])
    rob = np.concatenate([np.full(len(graphs[i]), i) for i in ids])
    radius = graphs[ids[0]].edge_radius
    offset = 4.0 * (np.abs(pos).max() + fuse_radius) + 1.0 if len(pos) else 1.0
    from scipy.spatial import cKDTree  # deferred: scipy.spatial loads in ~0.2 s

    pairs = cKDTree(np.column_stack([pos, lab * offset])).query_pairs(
        fuse_radius, output_type="ndarray"
    )
    # Fuse only objects of different robots (a robot's own map already merged its duplicates).
    pairs = pairs[rob[pairs[:, 0]] != rob[pairs[:, 1]]] if len(pairs) else pairs
    n = len(pos)
    adj = (
        sparse.coo_array((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        if len(pairs)
        else sparse.coo_array((n, n))
    )
    k, group = connected_components(adj, directed=False)
    counts = np.bincount(group, minlength=k).astype(np.float64)
    mpos = (
        np.stack([np.bincount(group, pos[:, d], minlength=k) for d in range(3)], axis=1)
        / counts[:, None]
    )
    first = np.full(k, n)
    np.minimum.at(first, group, np.arange(n))
    merged = SemanticGraph(mpos, lab[first], radius, name=name)
    return merged, rob[first], pos, rob
