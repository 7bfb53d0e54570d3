"""Tuned extraction and localizer settings per dataset, read from the one registry
`sgloc.presets` (which explains each value). `sgloc build-graph` uses `extraction_preset(name)`."""

from __future__ import annotations

from sgloc.config import LocalizerConfig
from sgloc.extraction.config import ExtractionConfig
from sgloc.presets import extraction_preset, localizer_preset

__all__ = [
    "extraction_preset",
    "kitti_objects_extraction_config",
    "kitti_objects_localizer_config",
]


def kitti_objects_extraction_config() -> ExtractionConfig:
    """Extraction settings for `kitti_objects` (LiDAR object detections)."""
    return extraction_preset("kitti-objects")


def kitti_objects_localizer_config() -> LocalizerConfig:
    """Localizer settings for graphs built with `kitti_objects_extraction_config`."""
    return localizer_preset("kitti-objects")
