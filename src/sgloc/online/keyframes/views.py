"""Where the robots saw an object from: the viewpoint offset of object centres, for the keyframe
back-end's link refits and co-location factors (`OnlineConfig.view_correction`).

A sighting's position is the centre of what the sensor saw of an object, its near side: it lies
closer to the sensor than the object's centre, by an offset that depends on the detector and the
objects (about 0.2 m on KITTI's objects). An object's position in a robot's map is the mean of
its sightings, so it is pulled towards where the robot saw it from. Two robots that saw the same
objects from the same places (a revisit in the same direction) share that pull; two that saw them
from opposite sides (one arriving where the other set off, or passing the other way) do not, and
aligning their maps shifts one robot against the other by about twice the offset along the way
they looked.

The offset is measured on the maps themselves: within an object, its sightings from different
directions scatter by the offset along their rays, so regressing each sighting's position (less
its object's mean) on its unit ray (less the object's mean ray) over every object gives
-offset (`view_offset`). The regression takes the horizontal component across the robot's
direction of travel: along it, drifting odometry (a scale error) moves an object's sightings
from ahead against those from behind as the offset would, across it only a heading error
does, by much less over the stretch an object is seen from. An object's position corrected
for it is its mean plus the offset times its mean ray (`view_corrected`): seen from all
around, the mean ray is about zero and the object stays; seen from one side, it moves away
from the sensor by about the offset."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sgloc.online.robot_map import RobotMap


def sighting_rays(m: RobotMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(object (s,) index into the association's objects, position (s,3) and unit ray (s,3)
    from the sensor to the sighting, both in the robot's odometry frame as its keyframes are
    placed now (`RobotMap.views`)) of every sighting of `m`."""
    w, ray = m.views()
    return m.sightings()[2], w, ray


def _per_object(o: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(n,3) mean of `values` (s,3) per object index `o` (s,) (zero for objects unseen)."""
    count = np.maximum(np.bincount(o, minlength=n), 1).astype(np.float64)
    return np.stack([np.bincount(o, weights=values[:, c], minlength=n) for c in range(3)],
                    axis=1) / count[:, None]


def mean_rays(m: RobotMap) -> np.ndarray:
    """(n,3) per object of `m`'s association (confirmed or not), the mean of the unit rays
    of its sightings in the odometry frame (length 1 for an object seen from one direction
    only, about 0 for one seen from all around)."""
    def compute() -> np.ndarray:
        o, _, ray = sighting_rays(m)
        return _per_object(o, ray, len(m.builder.counts))

    return m.derived("mean_rays", compute)


def _across(m: RobotMap, k: np.ndarray) -> np.ndarray:
    """(s,3) per keyframe index k, the horizontal unit vector across the robot's direction of
    travel there (from its neighbouring keyframes; the odometry frame's z up); zero where the
    robot stood still."""
    a = m.anchors()[:, :3, 3]
    i = np.arange(len(a))
    t = a[np.minimum(i + 1, len(a) - 1)] - a[np.maximum(i - 1, 0)]
    across = np.stack([-t[:, 1], t[:, 0], np.zeros(len(t))], axis=1)
    norm = np.linalg.norm(across, axis=1, keepdims=True)
    return (across / np.maximum(norm, 1e-12) * (norm > 1e-9))[k]


def view_offset(maps: Sequence[RobotMap]) -> float:
    """Metres (>= 0): how much closer to the sensor a sighting lies than its object's centre,
    pooled over the confirmed objects of `maps`; 0.0 without sightings from different
    directions or when the data say the sightings lie beyond the centre. Regressed across the
    direction of travel only: along it, an odometry scale error displaces the sightings of an
    object seen ahead against those seen behind just as the offset does (see the module
    doc)."""
    num = den = 0.0
    for m in maps:
        a, b = m.derived("view_terms", lambda m=m: _view_terms(m))
        num += a
        den += b
    return max(0.0, -num / den) if den > 0.0 else 0.0


def _view_terms(m: RobotMap) -> tuple[float, float]:
    """`m`'s sums of `view_offset`'s regression: (sum dw du, sum du du) over the sightings of
    its confirmed objects."""
    o, w, ray = sighting_rays(m)
    n = len(m.builder.counts)
    keep = (m.builder.counts >= m.min_observations)[o]
    across = _across(m, m.sightings()[0])
    dw = np.sum((w - _per_object(o, w, n)[o]) * across, axis=1)[keep]
    du = np.sum((ray - _per_object(o, ray, n)[o]) * across, axis=1)[keep]
    return float(np.sum(dw * du)), float(np.sum(du * du))


def view_corrected(m: RobotMap, offset: float) -> np.ndarray:
    """(n,3) the positions of every object of `m`'s association (odometry frame, metres),
    each moved away from where it was seen from by `offset` times its mean ray."""
    return m.builder.positions + float(offset) * mean_rays(m)
