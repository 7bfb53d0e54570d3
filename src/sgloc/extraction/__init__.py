"""Graph extraction: frames (semantic + depth images, or object detections) -> SemanticGraph."""

from sgloc.extraction.backprojection import backproject_pixels, region_positions, to_map
from sgloc.extraction.builder import GraphBuilder, build_graph, frame_observations
from sgloc.extraction.config import REFERENCE_RESOLUTION, ExtractionConfig, extraction_preset
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
    "region_positions",
    "segment",
    "to_map",
]
