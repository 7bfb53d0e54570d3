"""Whether the query looks mirrored against the target (a left-handed frame, x -> -x).

No rigid fit produces a reflection (det -1), but a part of a map that is nearly its own mirror
image (objects along a straight street) aligns rigidly with the mirrored map: the inliers then
lie along one line, and the rest of the query lands off the target. Reflecting the query across
the vertical plane through the inliers' line leaves those inliers in place; if the reflected
query then lands on the target's objects far more often than the accepted alignment does, the
query is mirrored and the alignment is a coincidence of that line."""

from __future__ import annotations

import numpy as np

from sgloc.acceptance.chance import ChanceModel
from sgloc.geometry import apply
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.prepared_graph import PreparedGraph

#: The reflected query must land this fraction of the query's objects more than the
#: alignment does (on Guo's Airsim maps, crops of 4-120 objects: true pairs land 14 % or more
#: *fewer* when reflected, mirrored ones 28 % or more *more*) ...
MIRROR_EXCESS = 0.15
#: ... and at least this many objects more.
MIRROR_MARGIN = 3


def landed(moved: np.ndarray, labels: np.ndarray, chance: ChanceModel) -> np.ndarray:
    """(n,) bool: which query objects, already moved into the target frame (`moved` (n,3),
    metres, classes `labels`), lie within the chance model's radius (distance <= radius) of a
    target object of their class (one neighbour search of `ChanceModel.near_counts`)."""
    (counts,) = chance.near_counts(moved)
    return counts[np.arange(len(moved)), labels] > 0


def reflect_across_line(points: np.ndarray, on_line: np.ndarray) -> np.ndarray:
    """`points` (n,3) reflected across the vertical plane through the xy principal line of
    `on_line` (k >= 1,3), in the same frame (the principal axis in closed form, compiled)."""
    from sgloc.acceptance.evidence_kernels import reflect_xy

    return reflect_xy(*(np.ascontiguousarray(p, dtype=np.float64) for p in (points, on_line)))


def looks_mirrored(
    query: SemanticGraph, target: SemanticGraph, T_target_query: np.ndarray,
    inlier_objects: np.ndarray, radius: float, plain_landed: np.ndarray | None = None,
    prepared: PreparedGraph | None = None,
) -> tuple[bool, int, int]:  # fmt: skip
    """(mirrored, objects the alignment lands on the target, objects the query reflected across
    its inliers' line lands): query objects within `radius` metres of a same-class target
    object, the reflection tried in the query frame (module docstring). `plain_landed`: the
    (n,) bool `landed` of the query under T_target_query at this radius when already known
    (the acceptance test's neighbour search): only the reflected query is searched then.
    prepared: the target's `PreparedGraph` (its neighbour grid is used and kept), or None."""
    if len(inlier_objects) < 2:
        return False, 0, 0
    flipped = apply(T_target_query, reflect_across_line(query.positions,
                                                        query.positions[inlier_objects]))
    chance = ChanceModel(target, radius, max(query.n_classes, target.n_classes), prepared)
    if plain_landed is None:
        moved = apply(T_target_query, query.positions)
        both = landed(np.vstack([moved, flipped]), np.tile(query.labels, 2), chance)
        plain_landed, flipped_landed = both[: len(query)], both[len(query) :]
    else:
        flipped_landed = landed(flipped, query.labels, chance)
    plain = int(np.count_nonzero(plain_landed))
    mirror = int(np.count_nonzero(flipped_landed))
    mirrored = mirror - plain >= max(MIRROR_MARGIN, MIRROR_EXCESS * len(query))
    return bool(mirrored), plain, mirror
