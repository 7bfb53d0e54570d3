"""One robot's growing object map in its odometry frame: sightings associated and averaged."""

from __future__ import annotations

import numpy as np

from sgloc.errors import SglocError
from sgloc.geometry import apply
from sgloc.graph import SemanticGraph
from sgloc.validation import check_graph_arrays


class RobotMap:
    """Objects of one robot (odometry frame, metres) built from keyframe sightings.

    A sighting joins the nearest object of its class within `radius` metres (nearest-neighbour
    gate on the current means); the object's position is the mean of its sightings. Sightings
    that join nothing start new objects. An object is confirmed from `min_observations`
    sightings; only confirmed objects are in `graph()`.
    """

    def __init__(self, name: str, radius: float, min_observations: int, edge_radius: float):
        self.name = name
        self.radius = float(radius)
        self.min_observations = int(min_observations)
        self.edge_radius = float(edge_radius)
        self.sums = np.zeros((0, 3))
        self.counts = np.zeros(0, np.int64)
        self.labels = np.zeros(0, np.int64)
        self.keyframes = 0
        self._graph: SemanticGraph | None = None

    @property
    def means(self) -> np.ndarray:
        """(m,3) every object's mean position (confirmed or not)."""
        return self.sums / np.maximum(self.counts, 1)[:, None]

    @property
    def n_confirmed(self) -> int:
        return int(np.count_nonzero(self.counts >= self.min_observations))

    def add(self, T_odom_sensor: np.ndarray, positions: np.ndarray, labels: np.ndarray) -> int:
        """Add one keyframe's sightings (sensor frame); returns how many objects became
        confirmed by it."""
        T = np.asarray(T_odom_sensor, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise SglocError(
                f"robot {self.name!r}: T_odom_sensor must be a finite 4x4 matrix, got shape "
                f"{T.shape}; pass the keyframe's pose in the robot's odometry frame."
            )
        pos, lab = check_graph_arrays(f"robot {self.name!r} keyframe", positions, labels)
        self.keyframes += 1
        if not len(pos):
            return 0
        before = self.counts >= self.min_observations
        pos = apply(T, pos)
        target = self._associate(pos, lab)
        new = target < 0
        k = int(new.sum())
        target[new] = len(self.counts) + np.arange(k)
        self.sums = np.concatenate([self.sums, np.zeros((k, 3))])
        self.counts = np.concatenate([self.counts, np.zeros(k, np.int64)])
        self.labels = np.concatenate([self.labels, lab[new]])
        np.add.at(self.sums, target, pos)
        np.add.at(self.counts, target, 1)
        after = self.counts >= self.min_observations
        gained = int(after.sum() - before.sum())
        if gained or (after[: len(before)] & before).any():
            self._graph = None  # a confirmed object moved or a new one came
        return gained

    def _associate(self, pos: np.ndarray, lab: np.ndarray) -> np.ndarray:
        """Index of the existing object each sighting joins (-1: none)."""
        out = np.full(len(pos), -1, np.int64)
        if not len(self.counts) or self.radius <= 0:
            return out
        from scipy.spatial import cKDTree  # deferred: scipy.spatial loads in ~0.2 s

        means = self.means
        # Classes far apart along a 4th axis: one tree answers "nearest of the same class".
        offset = 4.0 * (np.abs(means).max() + np.abs(pos).max() + self.radius) + 1.0
        tree = cKDTree(np.column_stack([means, self.labels * offset]))
        d, idx = tree.query(np.column_stack([pos, lab * offset]),
                            distance_upper_bound=self.radius)
        hit = np.isfinite(d)
        out[hit] = idx[hit]
        return out

    def graph(self) -> SemanticGraph:
        """The confirmed objects as a SemanticGraph (cached until they change)."""
        if self._graph is None:
            keep = self.counts >= self.min_observations
            self._graph = SemanticGraph(
                self.means[keep], self.labels[keep], self.edge_radius, name=self.name
            )
        return self._graph

    def state(self) -> dict[str, np.ndarray]:
        """Arrays that restore this map (`from_state`)."""
        return {"sums": self.sums, "counts": self.counts, "labels": self.labels,
                "keyframes": np.array(self.keyframes)}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        self.sums = np.asarray(state["sums"], np.float64).reshape(-1, 3)
        self.counts = np.asarray(state["counts"], np.int64)
        self.labels = np.asarray(state["labels"], np.int64)
        self.keyframes = int(state["keyframes"])
        self._graph = None
