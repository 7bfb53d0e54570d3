"""The scale of a scene: one length, the scene's *unit* (metres), from which every absolute
length of the pipeline derives. A street map (objects metres apart, positions good to about a
metre) has the unit STREET_UNIT = 5 m and the code's defaults are its lengths; a forest or a
room has a smaller unit, and each length is its street default times unit / 5 m:

| length (flat setting)             | street default | as a multiple of the unit |
|-----------------------------------|----------------|---------------------------|
| RANSAC inlier distance (ransac_threshold) | 5 m     | 1                         |
| Alg. 1 tolerance (tau), local radius      | 5 m, 40 m | 1, 8                    |
| descriptor radius (descriptor_radius)     | 40 m (triangles 30 m) | 8 (6)       |
| acceptance: min_spread                    | 5 m     | 1                         |
| acceptance: distinct_translation, small_exclusion | 10 m | 2                   |
| acceptance: verify_radius, verify_density_radius  | 1.5 m, 15 m | 0.3, 3       |
| acceptance: repetition_search (all of `AcceptanceConfig.LENGTHS`) | 100 m | 20 |
| ICP pairing radius (icp_max_distance)     | 5 m     | 1                         |
| graph edge radius (`edge_radius`)         | 20 m    | 4                         |
| sighting association radius (online)      | 1.5 m   | 0.3                       |

`LocalizerConfig.with_overrides(scale=...)` (and `localize(..., scale=...)`, the `forest` and
`room` presets, `--set scale=...`) applies the table; a length also given explicitly wins.
Named scenes: SCENES. `scene_hint` adds a sentence to a refusal when the maps' objects stand
much closer together than the scale assumes.

`scale="auto"` (AUTO) asks for the scale of the target map itself (`estimate_scale`): the named
scene whose typical nearest-neighbour spacing (TYPICAL_SPACING) is nearest the map's median
one, on a log scale (boundaries 3.2 m street/forest, 1.4 m forest/room), stepped down to a
smaller scene while the map spans fewer than EXTENT_UNITS of its unit (a descriptor's reach).
The unit is a named one, not the spacing times a constant: the unit also stands for how well
positions are known (a metre on streets, centimetres indoors), which one map's spacing does not
tell; the named units are measured (docs/scenes.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from sgloc.errors import SglocError
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.units import median_spacing
from sgloc.registry import Registry
from sgloc.validation import MAX_COORDINATE, InvalidSettingError

#: The unit length (m) of a street map: the lengths of the code's defaults are the street's.
STREET_UNIT = 5.0

#: Unit lengths (m) of the named kinds of scene (the presets of the same names use them).
#: street: KITTI, city and Airsim object maps (objects a median 3.5-6 m apart, positions good
#: to ~1 m); forest: trunk maps (0.02-0.1 stems per m^2, trunk centres good to 0.2-0.5 m);
#: room: indoor furniture (a median ~0.8 m apart, centres good to ~5 cm).
SCENES: Registry[float] = Registry("scene", {"street": STREET_UNIT, "forest": 1.25, "room": 0.5})

#: Median distance (m) from an object to its nearest neighbour in maps of each named scene
#: (measured on KITTI, city and Airsim maps, the synthetic forests and rooms of `sgloc.sim`).
TYPICAL_SPACING = {"street": 4.5, "forest": 2.3, "room": 0.85}

#: Multiples of the unit of the lengths outside LocalizerConfig.
EDGE_RADIUS_UNITS = 4.0
ASSOCIATION_RADIUS_UNITS = 0.3

#: Below this median nearest-neighbour spacing as a multiple of the unit, a refusal says that
#: the maps look like a smaller scene than the settings assume (street maps: ~0.7-1.2 units).
CLOSE_SPACING_UNITS = 0.4


#: The value of `scale` that asks for the scale estimated from the target map.
AUTO = "auto"

#: A map spans at least this many units of its scene (the descriptor radius is 8 units): a map
#: smaller than that is taken for the next smaller scene.
EXTENT_UNITS = 8.0


@dataclass(frozen=True)
class ScaleEstimate:
    """The scene scale of a map (`estimate_scale`): unit (m), the named scene it is, and what
    it was estimated from: the median distance (m) from an object to its nearest neighbour and
    the extent (m, the longer side of the objects' xy bounding box)."""

    unit: float
    scene: str
    spacing: float
    extent: float

    def to_dict(self) -> dict[str, Any]:
        """Plain values for a result document (metres)."""
        return {"unit_m": self.unit, "estimated": True, "scene": self.scene,
                "spacing_m": round(self.spacing, 3), "extent_m": round(self.extent, 1)}  # fmt: skip


def estimate_scale(graph: SemanticGraph) -> ScaleEstimate:
    """The scene scale of the map `graph` (positions in metres; module docstring): the named
    scene of SCENES nearest its median object spacing, stepped down while the map spans fewer
    than EXTENT_UNITS of the scene's unit."""
    spacing = median_spacing(graph)
    xy = np.asarray(graph.positions, dtype=np.float64)[:, :2]
    extent = float(np.ptp(xy, axis=0).max()) if len(xy) else 0.0
    if not math.isfinite(spacing) or spacing <= 0:
        raise SglocError(
            f"scale='auto': map {graph.name!r} has no two distinct object positions to "
            "estimate its scene scale from; give the scale (--preset street|forest|room or "
            "--set scale=<metres>; Python: preset='room', scale=<metres>)."
        )
    scene = min(TYPICAL_SPACING, key=lambda k: abs(math.log(spacing / TYPICAL_SPACING[k])))
    smaller = sorted((k for k in SCENES if SCENES[k] < SCENES[scene]), key=SCENES.__getitem__)
    while smaller and extent < EXTENT_UNITS * SCENES[scene]:
        scene = smaller.pop()
    return ScaleEstimate(float(SCENES[scene]), scene, spacing, extent)


def check_scale(name: str, value: Any) -> float | str:
    """A scene scale setting: a number of metres > 0, or AUTO."""
    if value == AUTO:
        return AUTO
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(value) and 0 < value <= MAX_COORDINATE):  # fmt: skip
        raise InvalidSettingError(
            f"setting {name}={value!r}: give the scene's unit length in metres (a number > 0;"
            f" street maps 5, forests 1.25, rooms 0.5) or {AUTO!r} to estimate it from the "
            "target map (docs/scenes.md)."
        )
    return float(value)


def factor(unit: float) -> float:
    """The multiple of the street defaults that a scene of unit length `unit` (m) uses."""
    return float(unit) / STREET_UNIT


def edge_radius(unit: float) -> float:
    """Graph edge radius (m) of a scene of unit length `unit` (street: 20 m)."""
    return EDGE_RADIUS_UNITS * float(unit)


def association_radius(unit: float) -> float:
    """Radius (m) within which sightings are one object, for a scene of unit `unit`."""
    return ASSOCIATION_RADIUS_UNITS * float(unit)


def scene_hint(query: SemanticGraph, target: SemanticGraph, unit: float) -> str:
    """Empty, or a sentence for a refusal when the maps' objects stand much closer together
    than a scene of unit length `unit` (m) assumes (rooms or forests with street settings).
    A map whose objects stand at one point (zero spacing) has no scale to compare."""
    spacing = min([s for s in (median_spacing(query), median_spacing(target)) if s > 0] or [0])
    if not 0 < spacing < CLOSE_SPACING_UNITS * unit:
        return ""
    closest = min(TYPICAL_SPACING, key=lambda k: abs(math.log(spacing / TYPICAL_SPACING[k])))
    suggestion = closest if SCENES[closest] < unit else "room"
    return (
        f"; objects stand a median {spacing:.2f} m from their nearest neighbour, closer than "
        f"the settings' scene scale ({unit:g} m) assumes: its lengths (inlier distance, "
        f"min_spread, radii) are too long for this map; try --preset {suggestion} (scene "
        f"scale {SCENES[suggestion]:g} m), --set scale=auto (the scale of the target map) or "
        f"--set scale=<metres> (Python: preset={suggestion!r}, scale='auto'; docs/scenes.md)"
    )
