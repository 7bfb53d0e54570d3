"""Frames -> SemanticGraph: the same back end (`sgloc.maps.association`: an observation with the
same class within `association_radius` of an existing vertex is that vertex, the running mean of
its observations) serves image frames (regions back-projected) and detection frames (LiDAR
objects)."""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from sgloc.datasets.base import Frame
from sgloc.errors import DatasetError
from sgloc.extraction.backprojection import region_positions, to_map
from sgloc.extraction.config import ExtractionConfig
from sgloc.extraction.segmentation import segment
from sgloc.maps.association import ObjectAssociation
from sgloc.maps.graph import SemanticGraph


class GraphBuilder(ObjectAssociation):
    """Accumulates frames' observations into vertices (`sgloc.maps.association`), with the
    settings of an ExtractionConfig."""

    def __init__(self, config: ExtractionConfig | None = None) -> None:
        super().__init__(config or ExtractionConfig())

    def add_frame(self, frame: Frame) -> np.ndarray:
        """Observe one frame (detections, or semantic + depth images); returns the map-frame
        observations it gave as (k,3) positions (labels are in the vertices)."""
        pos, lab = frame_observations(frame, self.config)
        self.add_observations(pos, lab)
        return pos


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
