"""ExtractionConfig: every setting of graph extraction, with the paper's (Guo's) defaults."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

from sgloc.errors import SglocError
from sgloc.maps.association import AssociationSettings
from sgloc.pipeline.presets import extraction_settings
from sgloc.validation import (
    MAX_COORDINATE,
    choice,
    integer,
    real,
    same_setting,
    setting,
    validate_settings,
)

#: Image size at which Guo's `min_pixels` = 5000 holds (width, height).
REFERENCE_RESOLUTION = (1024, 576)


@dataclass
class ExtractionConfig:
    """Settings of `build_graph`.

    Segmentation (images):
        max_depth: pixels deeper than this (metres) are ignored (Guo 30 m, X-View 50 m).
        depth_jump: a neighbour pixel joins a region only if its depth differs by less than
            this (metres; Guo 1 m).
        min_pixels: regions smaller than this are dropped, at `REFERENCE_RESOLUTION`
            (Guo 5000 px at 1024x576); scaled by the image's pixel count (see `min_pixels_for`).
        position: "mean" = mean of the region's back-projected 3D points (Guo); "centre" =
            the region's 2D pixel centroid back-projected at the region's median depth (X-View).
        ignore_classes: class ids never turned into vertices (e.g. road, sky).
    Detections (LiDAR objects):
        max_range: detections farther than this from the sensor (metres) are ignored; None = all.
    Association (both; declared by `sgloc.maps.association.AssociationSettings`, as
    `ignore_classes`):
        association_radius: an observation within this distance (metres) of an existing vertex
            of the same class is that vertex (Guo 5 m); the vertex keeps the running mean.
        min_observations: vertices seen fewer times are dropped at the end (1 keeps all).
        edge_radius: graph edges join vertices closer than this (metres; Guo 20 m).
    """

    max_depth: float = setting(30.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    depth_jump: float = setting(1.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    min_pixels: int = setting(5000, check=integer(1))
    position: Literal["mean", "centre"] = setting("mean", check=choice("mean", "centre"))
    ignore_classes: tuple[int, ...] = same_setting(AssociationSettings, "ignore_classes")
    max_range: float | None = setting(
        None, check=real(0.0, MAX_COORDINATE, low_open=True, none_ok=True, unit="m")
    )
    association_radius: float = same_setting(AssociationSettings, "association_radius")
    min_observations: int = same_setting(AssociationSettings, "min_observations")
    edge_radius: float = same_setting(AssociationSettings, "edge_radius")

    def __post_init__(self) -> None:
        validate_settings(self, "ExtractionConfig")

    def min_pixels_for(self, height: int, width: int) -> int:
        """`min_pixels` scaled from 1024x576 to an image of height x width (at least 1)."""
        ref = REFERENCE_RESOLUTION[0] * REFERENCE_RESOLUTION[1]
        return max(1, int(round(self.min_pixels * (height * width) / ref)))

    def with_overrides(self, **overrides: Any) -> ExtractionConfig:
        """A copy with some settings changed (unknown names raise SglocError)."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = set(overrides) - names
        if unknown:
            raise SglocError(
                f"unknown extraction setting(s) {sorted(unknown)}; known: {sorted(names)}."
            )
        return dataclasses.replace(self, **overrides)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def extraction_preset(name: str) -> ExtractionConfig:
    """The ExtractionConfig of the preset (or dataset) `name` in `sgloc.pipeline.presets` (the
    paper's
    defaults when none is tuned), e.g. "kitti-objects" for LiDAR object detections."""
    return ExtractionConfig(**extraction_settings(name))
