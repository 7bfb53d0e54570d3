"""Cross-frame association of object sightings (class + map-frame position) into objects.

An observation with the same class within `association_radius` of an existing object is that
object, whose position becomes the running mean of its observations; otherwise it starts a new
object. Observations of one frame are distinct objects (they never merge with each other), and
each frame is associated at once with a KD-tree over the objects. Offline map building
(`sgloc.extraction.GraphBuilder`) and the online session's robot maps
(`sgloc.online.robot_map`) both use it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from sgloc.errors import SglocError
from sgloc.maps.graph import DEFAULT_EDGE_RADIUS, SemanticGraph
from sgloc.validation import (
    MAX_COORDINATE,
    class_ids,
    integer,
    real,
    setting,
    validate_settings,
)

#: How many nearest objects are searched per observation for one of its class.
K_NEAREST = 16


@dataclass(frozen=True)
class AssociationSettings:
    """association_radius: metres, an observation this close to an object of its class is that
    object (0: never merge); min_observations: objects seen fewer times are left out of
    `graph()`; edge_radius: metres, the graph's edges; ignore_classes: class ids never
    turned into objects. These four settings are declared here only:
    `sgloc.extraction.ExtractionConfig` takes them by name (`sgloc.validation.same_setting`)."""

    association_radius: float = setting(5.0, check=real(0.0, MAX_COORDINATE, unit="m"))
    min_observations: int = setting(1, check=integer(1))
    edge_radius: float = setting(
        DEFAULT_EDGE_RADIUS, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m")
    )
    ignore_classes: tuple[int, ...] = setting((), check=class_ids)

    def __post_init__(self) -> None:
        validate_settings(self, "AssociationSettings")


class ObjectAssociation:
    """Accumulates observations into objects (running means with observation counts).

    `config`: any object with AssociationSettings' fields (default AssociationSettings()).
    """

    def __init__(self, config: Any = None) -> None:
        self.config = config if config is not None else AssociationSettings()
        self._sums = np.zeros((0, 3))
        self._counts = np.zeros(0, dtype=np.int64)
        self._labels = np.zeros(0, dtype=np.int64)
        self.n_frames = 0
        self.n_observations = 0

    @property
    def positions(self) -> np.ndarray:
        """(n,3) current object positions (running means, metres, map frame)."""
        return self._sums / self._counts[:, None]

    @property
    def counts(self) -> np.ndarray:
        """(n,) number of observations merged into each object."""
        return self._counts.copy()

    @property
    def labels(self) -> np.ndarray:
        return self._labels.copy()

    def state(self) -> dict[str, np.ndarray]:
        """The arrays (sums of positions (n,3), counts (n,), labels (n,), n_frames,
        n_observations), enough to resume exactly with `from_state`."""
        return {"sums": self._sums.copy(), "counts": self._counts.copy(),
                "labels": self._labels.copy(), "n_frames": np.array(self.n_frames),
                "n_observations": np.array(self.n_observations)}  # fmt: skip

    @classmethod
    def from_state(cls, config: Any, state: dict[str, np.ndarray]) -> Any:
        """An association resumed from `state()`'s arrays."""
        b = cls(config)
        b._sums = np.asarray(state["sums"], np.float64).reshape(-1, 3)
        b._counts = np.asarray(state["counts"], np.int64).ravel()
        b._labels = np.asarray(state["labels"], np.int64).ravel()
        if not len(b._sums) == len(b._counts) == len(b._labels):
            raise SglocError("GraphBuilder state: sums, counts and labels differ in length.")
        b.n_frames = int(state["n_frames"])
        b.n_observations = int(state["n_observations"])
        return b

    def shift(self, objects: np.ndarray, delta: np.ndarray) -> None:
        """Move observations already merged: add delta (k,3) metres to the position sums of
        `objects` (k,) (repeats add up), e.g. when the poses they were seen from are corrected;
        counts and labels are unchanged."""
        np.add.at(self._sums, np.asarray(objects, np.int64), np.asarray(delta, np.float64))

    def add_observations(self, positions: np.ndarray, labels: np.ndarray) -> np.ndarray:
        """Associate one frame's observations ((k,3) map-frame metres, (k,) class ids).

        Returns (k,) the object index each observation went to (-1: not finite, a negative
        class or an ignored class).
        """
        pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        lab = np.asarray(labels).astype(np.int64).ravel()
        if lab.shape[0] != pos.shape[0]:
            raise SglocError(
                f"{pos.shape[0]} observation positions but {lab.shape[0]} labels; give one "
                "label per position."
            )
        finite = np.all(np.isfinite(pos), axis=1) & (lab >= 0)
        if self.config.ignore_classes:
            finite &= ~np.isin(lab, np.asarray(self.config.ignore_classes))
        assigned = np.full(len(pos), -1, dtype=np.int64)
        pos_ok, lab_ok = pos[finite], lab[finite]
        target = self._nearest_same_class(pos_ok, lab_ok)
        n = len(self._counts)
        new = target < 0
        n_new = int(new.sum())
        target[new] = n + np.arange(n_new)
        self._sums = np.concatenate([self._sums, np.zeros((n_new, 3))])
        self._counts = np.concatenate([self._counts, np.zeros(n_new, dtype=np.int64)])
        self._labels = np.concatenate([self._labels, lab_ok[new]])
        np.add.at(self._sums, target, pos_ok)
        np.add.at(self._counts, target, 1)
        assigned[finite] = target
        self.n_frames += 1
        self.n_observations += len(pos_ok)
        return assigned

    def _nearest_same_class(self, pos: np.ndarray, lab: np.ndarray) -> np.ndarray:
        """(k,) the nearest existing object of each observation's class closer than
        association_radius, -1 where there is none."""
        target = np.full(len(pos), -1, dtype=np.int64)
        n, radius = len(self._counts), self.config.association_radius
        if n and len(pos) and radius > 0:
            k = min(K_NEAREST, n)
            tree = cKDTree(self.positions)
            dist, nn = tree.query(pos, k=k, distance_upper_bound=radius)
            dist, nn = dist.reshape(len(pos), k), nn.reshape(len(pos), k)
            found = np.isfinite(dist) & (dist < radius)
            nn_safe = np.where(found, nn, 0)
            same = found & (self._labels[nn_safe] == lab[:, None])
            has = same.any(axis=1)
            first = np.argmax(same, axis=1)  # nearest same-class (query results are sorted)
            target[has] = nn_safe[has, first[has]]
        return target

    def graph(self, name: str | None = None) -> SemanticGraph:
        """The objects seen at least `min_observations` times, as a SemanticGraph."""
        keep = self._counts >= self.config.min_observations
        return SemanticGraph(
            self.positions[keep], self._labels[keep], self.config.edge_radius, name=name
        )
