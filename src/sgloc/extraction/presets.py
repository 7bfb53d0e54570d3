"""Tuned settings per dataset: the extraction config each loader's data needs and the
localizer settings that go with it. `sgloc build-graph` uses `extraction_preset(name)`.

KITTI objects (GOSMatch LiDAR detections): consecutive scans are ~1 m apart and centroids are
precise to well under a metre, but poles and trunks stand a few metres apart, so Guo's 5 m
merge radius fuses distinct objects; 3 m keeps them apart while still merging one object's
repeated detections, and objects seen only once (mostly noise clusters) are dropped. The
centroids being precise, a 2 m RANSAC inlier threshold and tau = 2 m suit them better than the
image-based 5 m defaults. Measured in benchmarks/docs: see docs/extraction.md.
"""

from __future__ import annotations

from sgloc.config import LocalizerConfig
from sgloc.extraction.config import ExtractionConfig


def kitti_objects_extraction_config() -> ExtractionConfig:
    """Extraction settings for `kitti_objects` (LiDAR object detections)."""
    return ExtractionConfig(merge_distance=3.0, min_observations=2)


def kitti_objects_localizer_config() -> LocalizerConfig:
    """Localizer settings for graphs built with `kitti_objects_extraction_config`."""
    return LocalizerConfig().with_overrides(ransac_threshold=2.0, tau=2.0)


_EXTRACTION_PRESETS = {"kitti_objects": kitti_objects_extraction_config}


def extraction_preset(dataset: str) -> ExtractionConfig:
    """The extraction settings for a dataset name (the paper's defaults when none is tuned)."""
    key = dataset.strip().lower().replace("-", "_")
    return _EXTRACTION_PRESETS.get(key, ExtractionConfig)()
