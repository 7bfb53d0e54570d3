"""A sparse one-class object detector's view of a run: what a camera robot's detector gives
where a LiDAR gave many objects of several classes.

`sparse_detections` keeps the sightings of one class within a range, each with a probability
that leaves about `per_keyframe` of them per keyframe on average, and moves each along its
line of sight by a depth error that grows with range (a stereo or monocular depth: sigma =
`range_noise` x range). Stamps, poses and names are kept."""

from __future__ import annotations

import dataclasses

import numpy as np

from sgloc.errors import SglocError
from sgloc.io.keyframes import RobotLog


def sparse_detections(log: RobotLog, label: int, rng: np.random.Generator,
                      per_keyframe: float = 3.0, max_range: float = 40.0,
                      range_noise: float = 0.015) -> RobotLog:
    """`log` seen by a sparse one-class detector: sightings of class `label` within
    `max_range` metres of the sensor, kept with a probability that leaves `per_keyframe` per
    keyframe on average (all of them when there are fewer), each moved along its line of sight
    by a Gaussian error of `range_noise` x its range (metres)."""
    if per_keyframe <= 0 or max_range <= 0 or range_noise < 0:
        raise SglocError("sparse detections: per_keyframe and max_range must be > 0 and "
                         "range_noise >= 0.")
    p = np.asarray(log.positions, np.float64).reshape(-1, 3)
    r = np.linalg.norm(p, axis=1)
    near = (np.asarray(log.labels) == label) & (r < max_range) & (r > 0)
    keep_p = min(1.0, per_keyframe * len(log) / max(int(near.sum()), 1))
    keep = near & (rng.random(len(p)) < keep_p)
    ray = p[keep] / r[keep, None]
    moved = p[keep] + ray * (range_noise * r[keep] * rng.standard_normal(int(keep.sum())))[:, None]
    return dataclasses.replace(log, keyframe=np.asarray(log.keyframe)[keep], positions=moved,
                               labels=np.asarray(log.labels)[keep])
