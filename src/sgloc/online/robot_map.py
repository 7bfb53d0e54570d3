"""One robot's growing object map in its odometry frame: sightings associated and averaged by
the same association as offline map building (`sgloc.association`)."""

from __future__ import annotations

import numpy as np

from sgloc.association import AssociationSettings, ObjectAssociation
from sgloc.errors import SglocError
from sgloc.geometry import apply
from sgloc.graph import SemanticGraph
from sgloc.validation import check_graph_arrays


class RobotMap:
    """Objects of one robot (odometry frame, metres) built from keyframe sightings.

    A sighting joins the nearest object of its class within `radius` metres (its position
    becomes the running mean of its sightings); sightings of one keyframe never merge with each
    other; sightings that join nothing start new objects. An object is confirmed from
    `min_observations` sightings; only confirmed objects are in `graph()`.
    """

    def __init__(self, name: str, radius: float, min_observations: int, edge_radius: float):
        self.name = name
        self.min_observations = int(min_observations)
        self.builder = ObjectAssociation(AssociationSettings(
            merge_distance=float(radius), min_observations=int(min_observations),
            edge_radius=float(edge_radius),
        ))  # fmt: skip
        self._graph: SemanticGraph | None = None
        self._confirmed = 0
        self.stamps: list[float] = []
        self.poses: list[np.ndarray] = []

    @property
    def n_confirmed(self) -> int:
        """Objects seen at least `min_observations` times."""
        return self._confirmed

    @property
    def keyframes(self) -> int:
        return self.builder.n_frames

    def add(
        self, stamp: float, T_odom_sensor: np.ndarray, positions: np.ndarray, labels: np.ndarray
    ) -> None:
        """Add one keyframe's sightings (positions (n,3) in the sensor frame, metres; labels
        (n,) class ids; T_odom_sensor (4,4) the keyframe's pose in the odometry frame; stamp
        in seconds)."""
        T = np.asarray(T_odom_sensor, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise SglocError(
                f"robot {self.name!r}: T_odom_sensor must be a finite 4x4 matrix, got shape "
                f"{T.shape}; pass the keyframe's pose in the robot's odometry frame."
            )
        pos, lab = check_graph_arrays(f"robot {self.name!r} keyframe", positions, labels)
        went = self.builder.add_observations(apply(T, pos), lab)
        self.stamps.append(float(stamp))
        self.poses.append(T.copy())
        counts = self.builder.counts
        # The confirmed map changed when a sighting went to an object that is now confirmed.
        if len(went) and (counts[went] >= self.min_observations).any():
            self._graph = None
        self._confirmed = int(np.count_nonzero(counts >= self.min_observations))

    def graph(self) -> SemanticGraph:
        """The confirmed objects as a SemanticGraph (cached until they change)."""
        if self._graph is None:
            self._graph = self.builder.graph(self.name)
        return self._graph

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """(stamps (k,), T_odom_sensor (k,4,4)) of the keyframes so far."""
        return np.array(self.stamps, np.float64), np.array(self.poses).reshape(-1, 4, 4)

    def state(self) -> dict[str, np.ndarray]:
        """Arrays that restore this map (`set_state`)."""
        stamps, poses = self.trajectory()
        return {**self.builder.state(), "stamps": stamps, "poses": poses}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        self.builder = ObjectAssociation.from_state(self.builder.config, state)
        self.stamps = [float(t) for t in state["stamps"]]
        self.poses = [np.array(T) for T in np.asarray(state["poses"]).reshape(-1, 4, 4)]
        self._confirmed = int(np.count_nonzero(self.builder.counts >= self.min_observations))
        self._graph = None
