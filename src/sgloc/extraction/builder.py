"""Cross-frame association: observations (class + map-frame position) -> SemanticGraph.

The same back end serves image frames (regions back-projected) and detection frames (LiDAR
objects): an observation with the same class within `merge_distance` of an existing vertex is
that vertex, whose position becomes the running mean of its observations; otherwise it starts
a new vertex. Observations of one frame are distinct objects (they never merge with each
other), and each frame is associated at once with a KD-tree over the vertices.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np
from scipy.spatial import cKDTree

from sgloc.datasets.base import Frame
from sgloc.errors import DatasetError, SglocError
from sgloc.extraction.backprojection import region_positions, to_map
from sgloc.extraction.config import ExtractionConfig
from sgloc.extraction.segmentation import segment
from sgloc.graph import SemanticGraph

#: How many nearest vertices are searched per observation for one of its class.
_K_NEAREST = 16


class GraphBuilder:
    """Accumulates observations into vertices (running means with observation counts)."""

    def __init__(self, config: ExtractionConfig | None = None) -> None:
        self.config = config or ExtractionConfig()
        self._sums = np.zeros((0, 3))
        self._counts = np.zeros(0, dtype=np.int64)
        self._labels = np.zeros(0, dtype=np.int64)
        self.n_frames = 0
        self.n_observations = 0

    @property
    def positions(self) -> np.ndarray:
        """(n,3) current vertex positions (running means, metres, map frame)."""
        return self._sums / self._counts[:, None]

    @property
    def counts(self) -> np.ndarray:
        """(n,) number of observations merged into each vertex."""
        return self._counts.copy()

    @property
    def labels(self) -> np.ndarray:
        return self._labels.copy()

    def state(self) -> dict[str, np.ndarray]:
        """The builder's arrays (sums of positions (n,3), counts (n,), labels (n,), n_frames,
        n_observations), enough to resume it exactly with `from_state`."""
        return {"sums": self._sums.copy(), "counts": self._counts.copy(),
                "labels": self._labels.copy(), "n_frames": np.array(self.n_frames),
                "n_observations": np.array(self.n_observations)}

    @classmethod
    def from_state(cls, config: ExtractionConfig, state: dict[str, np.ndarray]) -> GraphBuilder:
        """A builder resumed from `state()`'s arrays."""
        b = cls(config)
        b._sums = np.asarray(state["sums"], np.float64).reshape(-1, 3)
        b._counts = np.asarray(state["counts"], np.int64).ravel()
        b._labels = np.asarray(state["labels"], np.int64).ravel()
        if not len(b._sums) == len(b._counts) == len(b._labels):
            raise SglocError("GraphBuilder state: sums, counts and labels differ in length.")
        b.n_frames = int(state["n_frames"])
        b.n_observations = int(state["n_observations"])
        return b

    def add_observations(self, positions: np.ndarray, labels: np.ndarray) -> np.ndarray:
        """Associate one frame's observations ((k,3) map-frame metres, (k,) class ids).

        Returns (k,) the vertex index each observation went to.
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
        target = np.full(len(pos_ok), -1, dtype=np.int64)
        n = len(self._counts)
        if n and len(pos_ok) and self.config.merge_distance > 0:
            k = min(_K_NEAREST, n)
            tree = cKDTree(self.positions)
            dist, nn = tree.query(pos_ok, k=k, distance_upper_bound=self.config.merge_distance)
            dist, nn = dist.reshape(len(pos_ok), k), nn.reshape(len(pos_ok), k)
            found = np.isfinite(dist) & (dist < self.config.merge_distance)
            nn_safe = np.where(found, nn, 0)
            same = found & (self._labels[nn_safe] == lab_ok[:, None])
            has = same.any(axis=1)
            first = np.argmax(same, axis=1)  # nearest same-class (query results are sorted)
            target[has] = nn_safe[has, first[has]]
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

    def add_frame(self, frame: Frame) -> np.ndarray:
        """Observe one frame (detections, or semantic + depth images); returns the map-frame
        observations it gave as (k,3) positions (labels are in the vertices)."""
        pos, lab = frame_observations(frame, self.config)
        self.add_observations(pos, lab)
        return pos

    def graph(self, name: str | None = None) -> SemanticGraph:
        """The vertices seen at least `min_observations` times, as a SemanticGraph."""
        keep = self._counts >= self.config.min_observations
        return SemanticGraph(
            self.positions[keep], self._labels[keep], self.config.edge_radius, name=name
        )


def frame_observations(frame: Frame, config: ExtractionConfig) -> tuple[np.ndarray, np.ndarray]:
    """One frame's observations in the map frame: ((k,3) metres, (k,) class ids)."""
    T = np.asarray(frame.T_map_sensor, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DatasetError(f"frame {frame.index}: T_map_sensor must be a finite 4x4 transform.")
    if frame.detections is not None:
        pts, lab = frame.detections
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        lab = np.asarray(lab).astype(np.int64).ravel()
        if config.max_range is not None and len(pts):
            near = np.linalg.norm(pts, axis=1) <= config.max_range
            pts, lab = pts[near], lab[near]
        return to_map(pts, T), lab
    if frame.is_image:
        H, W = np.shape(frame.semantic)
        seg = segment(
            frame.semantic,
            frame.depth,
            config.max_depth,
            config.depth_jump,
            config.min_pixels_for(H, W),
            config.ignore_classes,
        )
        pts = region_positions(seg, frame.depth, frame.K, config.position)
        return to_map(pts, T), seg.classes
    raise DatasetError(
        f"frame {frame.index} has neither detections nor semantic + depth images with K; "
        "the loader must fill one of them."
    )


def build_graph(
    frames: Iterable[Frame],
    config: ExtractionConfig | None = None,
    name: str | None = None,
    progress: Callable[[Frame], None] | None = None,
) -> SemanticGraph:
    """Build a robot's semantic graph from its frames (image or detection frames alike).

    Args:
        frames: any iterable of Frame (a Dataset, a list, a generator), poses in the map frame.
        config: ExtractionConfig (paper defaults when None).
        name: the graph's name.
        progress: called after each frame (e.g. to advance a progress bar).
    """
    builder = GraphBuilder(config)
    for frame in frames:
        builder.add_frame(frame)
        if progress is not None:
            progress(frame)
    return builder.graph(name)
