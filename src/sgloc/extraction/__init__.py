"""Graph extraction: frames (semantic + depth images, or object detections) -> SemanticGraph."""

from sgloc.extraction.backprojection import backproject_pixels, region_positions, to_map
from sgloc.extraction.builder import GraphBuilder, build_graph, frame_observations
from sgloc.extraction.config import REFERENCE_RESOLUTION, ExtractionConfig
from sgloc.extraction.presets import (
    extraction_preset,
    kitti_objects_extraction_config,
    kitti_objects_localizer_config,
)
from sgloc.extraction.segmentation import Segmentation, segment

__all__ = [
    "REFERENCE_RESOLUTION",
    "ExtractionConfig",
    "GraphBuilder",
    "Segmentation",
    "backproject_pixels",
    "build_graph",
    "extraction_preset",
    "frame_observations",
    "kitti_objects_extraction_config",
    "kitti_objects_localizer_config",
    "region_positions",
    "segment",
    "to_map",
]
