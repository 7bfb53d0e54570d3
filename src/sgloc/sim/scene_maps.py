"""What the forest and room generators hand back: two robots' object maps and the ground truth
between their frames (`MapPair`), and the planar frame helpers they share."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sgloc.maps.graph import SemanticGraph


@dataclass
class MapPair:
    """Two object maps of one place and the ground truth p_target = T_target_query @ p_query.

    shared: the true objects both maps hold (each map has its own noisy copy), the overlap
        a localizer can use. A pair whose alignment is ambiguous by construction (a room of
        a floor of identical rooms) says so in `info["ambiguous"]`.
    query_truth, target_truth: (n,) index of each map object's true object (-1: spurious).
    info: what the generator chose (seed-dependent sizes, overlap, drift).
    """

    query: SemanticGraph
    target: SemanticGraph
    T_target_query: np.ndarray
    shared: int
    query_truth: np.ndarray
    target_truth: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


def planar_transform(yaw_rad: float, xyz: np.ndarray) -> np.ndarray:
    """(4,4) rotation by `yaw_rad` about z followed by the translation `xyz` (metres)."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = xyz
    return T


def shared_count(truth_a: np.ndarray, truth_b: np.ndarray) -> int:
    """Number of true objects (indices >= 0) present in both maps."""
    a, b = truth_a[truth_a >= 0], truth_b[truth_b >= 0]
    return int(np.intersect1d(a, b).size)
