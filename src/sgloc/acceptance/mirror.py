"""Whether the query looks mirrored against the target (a left-handed frame, x -> -x).

No rigid fit produces a reflection (det -1), but a part of a map that is nearly its own mirror
image (objects along a straight street) aligns rigidly with the mirrored map: the inliers then
lie along one line, and the rest of the query lands off the target. Reflecting the query across
the vertical plane through the inliers' line leaves those inliers in place; if the reflected
query then lands on the target's objects far more often than the accepted alignment does, the
query is mirrored and the alignment is a coincidence of that line."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from sgloc.geometry import apply
from sgloc.graph import SemanticGraph

#: The reflected query must land this fraction of the query's objects more than the
#: alignment does (on Guo's Airsim maps, crops of 4-120 objects: true pairs land 14 % or more
#: *fewer* when reflected, mirrored ones 28 % or more *more*) ...
MIRROR_EXCESS = 0.15
#: ... and at least this many objects more.
MIRROR_MARGIN = 3


#: Class ids as a 4th coordinate this far apart: objects of two classes are never near
#: (coordinates are within +-MAX_COORDINATE = 1e7 m).
_CLASS_GAP = 1e8


def _with_class(points: np.ndarray, labels: np.ndarray) -> np.ndarray:
    return np.column_stack([points, labels.astype(np.float64) * _CLASS_GAP])


def landed(query_points: np.ndarray, query_labels: np.ndarray, tree: cKDTree,
           radius: float) -> int:  # fmt: skip
    """How many query objects (already in the target frame, metres) lie within `radius` of a
    target object of their class (`tree`: the target's positions with `_with_class`)."""
    d, _ = tree.query(_with_class(query_points, query_labels), distance_upper_bound=radius)
    return int(np.count_nonzero(np.isfinite(d)))


def reflect_across_line(points: np.ndarray, on_line: np.ndarray) -> np.ndarray:
    """`points` (n,3) reflected across the vertical plane through the xy principal line of
    `on_line` (k,3), in the same frame."""
    xy = on_line[:, :2]
    centre = xy.mean(axis=0)
    _, _, vt = np.linalg.svd(xy - centre, full_matrices=False)
    normal = np.array([-vt[0, 1], vt[0, 0]])  # across the line, horizontal
    out = points.copy()
    out[:, :2] -= 2.0 * ((points[:, :2] - centre) @ normal)[:, None] * normal
    return out


def _near_box(points: np.ndarray, around: np.ndarray, radius: float) -> np.ndarray:
    """(n,) bool: which `points` lie in the bounding box of `around` grown by `radius` (the
    only target objects a moved query object can land on: a large map is not searched whole)."""
    low, high = around.min(axis=0) - radius, around.max(axis=0) + radius
    return np.all((points >= low) & (points <= high), axis=1)


def looks_mirrored(
    query: SemanticGraph, target: SemanticGraph, T_target_query: np.ndarray,
    inlier_objects: np.ndarray, radius: float,
) -> tuple[bool, int, int]:  # fmt: skip
    """(mirrored, objects the alignment lands on the target, objects the query reflected across
    its inliers' line lands): query objects within `radius` metres of a same-class target
    object, the reflection tried in the query frame (module docstring)."""
    if len(inlier_objects) < 2:
        return False, 0, 0
    moved = apply(T_target_query, query.positions)
    flipped = apply(T_target_query, reflect_across_line(query.positions,
                                                        query.positions[inlier_objects]))
    near = _near_box(target.positions, np.vstack([moved, flipped]), radius)
    tree = cKDTree(_with_class(target.positions[near], target.labels[near]))
    plain = landed(moved, query.labels, tree, radius)
    mirror = landed(flipped, query.labels, tree, radius)
    mirrored = mirror - plain >= max(MIRROR_MARGIN, MIRROR_EXCESS * len(query))
    return bool(mirrored), plain, mirror
