"""Named settings, in one place: the localizer settings and the extraction settings tuned for
each kind of data. `sgloc localize|fleet|experiment --preset NAME` and the dataset loaders,
experiments and the demo all read them from here.

Localizer presets (flat `LocalizerConfig.with_overrides` settings):
- `paper`: the paper's defaults (5 m RANSAC threshold, tau 5 m, Histogram + neighbor constraints).
- `airsim-guo`: Guo et al.'s Airsim object maps; the paper's defaults.
- `city`: graphs extracted from the rendered synthetic city. A building's vertex depends on the
  viewpoint (the centroid of the visible part of a facade moves as a robot drives past, and two
  robots see opposite ends), so every other class weighs 10x a building in the final fit.
- `kitti-objects`: GOSMatch LiDAR object centroids; precise to well under a metre, so a 2 m
  RANSAC threshold and tau = 2 m suit them better than the image-based 5 m defaults.

Extraction presets (`ExtractionConfig` fields):
- `kitti-objects`: consecutive scans are ~1 m apart and poles and trunks stand a few metres
  apart, so Guo's 5 m merge radius fuses distinct objects; 3 m keeps them apart while still
  merging one object's repeated detections; objects seen only once (mostly noise) are dropped.
- `synthia`: the paper's defaults without SYNTHIA's classes that are not objects (sky, road,
  sidewalk, lane marking: `sgloc.datasets.synthia.SYNTHIA_STUFF_CLASSES`).
Measured in docs/extraction.md and docs/reproduction.md.
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING, Any

from sgloc.errors import UnknownNameError

if TYPE_CHECKING:
    from sgloc.config import LocalizerConfig
    from sgloc.extraction.config import ExtractionConfig

LOCALIZER_PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "airsim-guo": {},
    "city": {"class_weights": {0: 0.1}},
    "kitti-objects": {"ransac_threshold": 2.0, "tau": 2.0},
}

EXTRACTION_PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "kitti-objects": {"merge_distance": 3.0, "min_observations": 2},
    "synthia": {"ignore_classes": (1, 3, 4, 12)},
}


def _key(name: str) -> str:
    return name.strip().lower().replace("_", "-")


def localizer_settings(name: str) -> dict[str, Any]:
    """A copy of the flat localizer settings of preset `name` (e.g. {"tau": 2.0})."""
    key = _key(name)
    if key not in LOCALIZER_PRESETS:
        raise UnknownNameError(
            f"unknown preset {name!r}; choose one of {', '.join(LOCALIZER_PRESETS)}."
        )
    return copy.deepcopy(LOCALIZER_PRESETS[key])


def localizer_preset(name: str) -> LocalizerConfig:
    """The LocalizerConfig of preset `name` (the paper's defaults plus the preset's settings)."""
    from sgloc.config import LocalizerConfig

    return LocalizerConfig().with_overrides(**localizer_settings(name))


def extraction_settings(name: str) -> dict[str, Any]:
    """A copy of the extraction settings of preset `name`; {} (Guo's defaults) when none."""
    return copy.deepcopy(EXTRACTION_PRESETS.get(_key(name), {}))


def extraction_preset(name: str) -> ExtractionConfig:
    """The ExtractionConfig for a dataset name (the paper's defaults when none is tuned)."""
    from sgloc.extraction.config import ExtractionConfig

    return ExtractionConfig(**extraction_settings(name))
