"""Named settings, in one place: the localizer settings and the extraction settings tuned for
each kind of data. `sgloc localize|fleet|experiment --preset NAME` and the dataset loaders,
experiments and the demo all read them from here (`localizer_preset(name)` gives the
LocalizerConfig, `sgloc.extraction.extraction_preset(name)` the ExtractionConfig).

Localizer presets (flat `LocalizerConfig.with_overrides` settings):
- `default`: sgloc's own defaults (nothing changed).
- `paper`: the paper's pipeline and nothing of sgloc's additions: the histogram descriptor,
  the best match per query object (exact search, >= 0.5), Alg. 1 as its pseudo-code reads
  (`bound="literal"`, tau 5 m, eta 0.5), Guo et al.'s RANSAC (samples of 4 matches drawn with
  replacement, a fixed 1000 draws, most inliers wins, >= 5 inliers and >= 1 % of the matches,
  T_error 5 m, the model refit once on its inliers), the plain weighted SVD of Eq. 4 (no robust
  refit, no ICP), any rigid motion (dof 6, no gravity gate) and no acceptance test beyond
  Guo's inlier rule.
- `guo`: `paper` without the rejection (Guo et al.'s pipeline, the paper's baseline).
- `airsim-guo`: Guo et al.'s Airsim object maps; sgloc's defaults.
- `city`: graphs extracted from the rendered synthetic city. A building's vertex depends on the
  viewpoint (the centroid of the visible part of a facade moves as a robot drives past, and two
  robots see opposite ends), so every other class weighs 10x a building in the final fit.
- `city-objects`: a street grid's object maps that agree to decimetres (the synthetic city's
  object sightings, surveyed maps): `city` plus the agreement check (`min_agreement` 0.75):
  an alignment at another copy of a repeating street grid lands only the furniture the grid
  repeats, two maps of one place land most of the objects it puts side by side. Chosen on
  pair attempts of the 12x12-block city, seeds 0-1 (true alignments land >= 0.92 of those
  objects, lattice offsets <= 0.63; docs/repetition.md); not for maps extracted from images,
  whose true alignments land 0.7-0.9 (docs/acceptance.md).
- `kitti-objects`: GOSMatch LiDAR object centroids; precise to well under a metre, so a 2 m
  RANSAC threshold and tau = 2 m suit them better than the image-based 5 m defaults.
- `street`, `forest`, `room`: the scene scales of `sgloc.maps.scale` (docs/scenes.md): `street` is
  the defaults; `forest` (unit 1.25 m: one-class trunk maps, trunks a few metres apart, good
  to 0.2-0.5 m) and `room` (unit 0.5 m: furniture under a metre apart, good to ~5 cm) set
  every absolute length of the pipeline to its street value times unit / 5 m; `room` also
  refits the query at the places where the target repeats itself (identical offices). `forest` also
  keeps 5 candidates per object with 20 m descriptors and lets every candidate count as the
  acceptance test's evidence: with one class, neighbourhoods look alike and the right match is
  seldom the most similar one (chosen on the synthetic forests' tuning seeds, docs/scenes.md).

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

from sgloc.maps.scale import SCENES
from sgloc.registry import Registry

if TYPE_CHECKING:
    from sgloc.maps.scale import ScaleEstimate
    from sgloc.pipeline.config import LocalizerConfig

#: Guo et al.'s pipeline (the paper's baseline), every sgloc addition switched off.
_GUO: dict[str, Any] = {
    "descriptor": "histogram",
    "min_similarity": 0.5,
    "top_k": 1,
    "mutual": False,
    "strategy": "top_k",
    "max_ratio": None,
    "search": "exact",
    "rejection": "none",
    "ransac_threshold": 5.0,
    "sampler": "guo",
    "scoring": "first",
    "iterations": 1000,
    "ransac_confidence": None,
    "min_inliers": 5,
    "min_inlier_ratio": 0.01,
    "refit_rounds": 0,
    "dof": 6,
    "max_tilt": None,
    "class_weights": None,
    "robust_refit": False,
    "icp": False,
    "acceptance": {"enabled": False, "distinct_ratio": None},
}

LOCALIZER_PRESETS: Registry[dict[str, Any]] = Registry("preset", {
    "default": {},
    "paper": {**_GUO, "rejection": "neighbor", "tau": 5.0, "eta": 0.5, "form": "distance",
              "bound": "literal", "scope": "all"},  # fmt: skip
    "guo": _GUO,
    "airsim-guo": {},
    "city": {"class_weights": {0: 0.1}},
    "city-objects": {"class_weights": {0: 0.1}, "min_agreement": 0.75},
    "kitti-objects": {"ransac_threshold": 2.0, "tau": 2.0},
    "street": {},
    # One class: more candidates per trunk (the right one is rarely the most similar), wider
    # descriptors (16 units: ~60 trunks at 0.05 per m^2), and every candidate is evidence
    # (the ratio test finds no match distinct when all objects are alike).
    "forest": {"scale": SCENES["forest"], "top_k": 5, "descriptor_radius": 20.0,
               "distinct_ratio": None},  # fmt: skip
    # Floors repeat their rooms (identical offices): the acceptance test refits the query at
    # up to 8 other places where the floor maps onto itself, up to 40 m away (a few offices),
    # and calls an alignment ambiguous when one of them lands about as many of the query's
    # objects (`acceptance.places`). Chosen on the tuning floors only (repeated-room negatives
    # refused 22 -> 40 of 40; room and floor pairs unchanged).
    "room": {"scale": SCENES["room"], "other_places": 8, "repetition_search": 40.0},
})

EXTRACTION_PRESETS: Registry[dict[str, Any]] = Registry("extraction preset", {
    "default": {},
    "paper": {},
    "guo": {},
    "kitti-objects": {"association_radius": 3.0, "min_observations": 2},
    "synthia": {"ignore_classes": (1, 3, 4, 12)},
})


def at_estimated_scale(config: LocalizerConfig, estimate: ScaleEstimate) -> LocalizerConfig:
    """`config` (scale="auto") at the scale estimated from the target map: the lengths of
    `estimate.unit` and the other settings of the preset of `estimate.scene` (forest: more
    candidates per trunk; room: the check of other places), except the settings `config` gives
    itself (those that differ from the defaults). A config of a numeric scale stays as it is."""
    return config.resolved(estimate.unit, localizer_settings(estimate.scene))


def localizer_settings(name: str) -> dict[str, Any]:
    """A copy of the flat localizer settings of preset `name` (e.g. {"tau": 2.0})."""
    return copy.deepcopy(LOCALIZER_PRESETS.lookup(name))


def localizer_preset(name: str) -> LocalizerConfig:
    """The LocalizerConfig of preset `name` (the paper's defaults plus the preset's settings)."""
    from sgloc.pipeline.config import LocalizerConfig

    return LocalizerConfig().with_overrides(**localizer_settings(name))


def extraction_settings(name: str) -> dict[str, Any]:
    """A copy of the extraction settings of preset `name`; {} (Guo's defaults) when none."""
    return copy.deepcopy(EXTRACTION_PRESETS.find(name) or {})
