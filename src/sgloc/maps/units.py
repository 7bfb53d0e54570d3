"""A hint when maps look like they are not in metres (millimetres, centimetres): objects of a
semantic map lie metres apart, so a median spacing of hundreds of "metres" is a unit error."""

from __future__ import annotations

import numpy as np

from sgloc.maps.graph import SemanticGraph

#: Median distance (m) from an object to its nearest neighbour above which a map is suspected
#: to be in other units (object maps of streets and rooms: a few metres).
SUSPECT_SPACING_M = 100.0


def median_spacing(graph: SemanticGraph) -> float:
    """Median distance (m) from each object to its nearest other object (inf below 2)."""
    if len(graph) < 2:
        return float("inf")
    from scipy.spatial import cKDTree  # deferred: asked only of maps not localized

    d, _ = cKDTree(graph.positions).query(graph.positions, k=2)
    return float(np.median(d[:, 1]))


def units_hint(query: SemanticGraph, target: SemanticGraph) -> str:
    """Empty, or a sentence for a "not localized" reason when a map's objects lie implausibly far
    apart for metres."""
    spacing = {role: median_spacing(g) for role, g in (("query", query), ("target", target))}
    far = {r: s for r, s in spacing.items() if np.isfinite(s) and s > SUSPECT_SPACING_M}
    if not far:
        return ""
    which = " and ".join(f"{s:.0f} m ({r})" for r, s in far.items())
    return (
        f"; objects lie a median {which} from their nearest neighbour: sgloc expects metres; "
        "if a map is in millimetres or centimetres, divide its positions by 1000 or 100"
    )
