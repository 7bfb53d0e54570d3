"""A prepared map: a target graph's canonical form, descriptors and matching blocks, built once
and reused by every query localized against it (a robot relocalizing its scans against a kept
map, a fleet localizing new keyframes against a growing one).

    prepared = sgloc.prepare(city_map)           # or Localizer(config).prepare(city_map)
    res = sgloc.localize(scan, prepared)         # wherever a target graph is accepted
    prepared.add(new_positions, new_labels)      # objects mapped since: only their
                                                 # neighbourhood's descriptors change
    prepared.save("city.sgmap.npz"); sgloc.PreparedMap.load("city.sgmap.npz")

A localization against a prepared map gives the same result, bit for bit, as against the graph
it holds (`prepared.graph`). Preparing costs memory linear in the map: the descriptors
(objects x classes x bins floats), and for maps larger than `sgloc.kernels.SMALL_PROBLEM`
objects a second, normalised copy grouped by class for the matching kernel.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from sgloc.canonical import CanonicalPair, canonical_order
from sgloc.config import LocalizerConfig
from sgloc.descriptors import DistanceHistogramDescriptor, RandomWalkDescriptor
from sgloc.errors import SglocError
from sgloc.graph import SemanticGraph

#: The file format's name and version (`PreparedMap.save`).
FORMAT = "sgloc.PreparedMap"
VERSION = 1
#: A localization needs at least this many target objects (as `sgloc.localizer`).
MIN_VERTICES = 3


class PreparedMapError(SglocError):
    """A prepared map that does not fit the request: another descriptor configuration than the
    localizer's, a file that is not a prepared map, or a map too small to localize against."""


class PreparedMap:
    """A target map prepared for repeated localization (module docstring). Build it with
    `sgloc.prepare(graph, config)` or `Localizer.prepare(graph)`.

    graph: the map as a SemanticGraph, in the caller's vertex order (results index it).
    config: the LocalizerConfig it was prepared for; only its descriptor binds: a localizer
        with another descriptor or descriptor parameters refuses the map.
    classes: (L,) the map's class ids, sorted; order: (n,) its canonical vertex order
        (`sgloc.canonical`); target: the canonical graph (classes renumbered 0..L-1);
        descriptors: (n, d) the canonical graph's descriptor rows (read-only).
    """

    def __init__(self, graph: SemanticGraph, config: LocalizerConfig | None = None) -> None:
        if not isinstance(graph, SemanticGraph):
            raise PreparedMapError(f"prepare needs a SemanticGraph, got {type(graph).__name__}.")
        self.config = config or LocalizerConfig()
        self.descriptor = self.config.descriptor_config
        if isinstance(self.descriptor, RandomWalkDescriptor):
            raise PreparedMapError(
                "descriptor 'random_walk' draws from the call's random generator, so its "
                "target descriptors cannot be kept; prepare with another descriptor."
            )
        self._set_graph(graph)
        self._set_descriptors(self._describe())

    # -- construction -----------------------------------------------------------------------
    def _set_graph(self, graph: SemanticGraph) -> None:
        if len(graph) < MIN_VERTICES:
            raise PreparedMapError(
                f"map {graph.name!r} has {len(graph)} objects; localization needs at least "
                f"{MIN_VERTICES} (map a larger area)."
            )
        self.graph = graph
        self.classes = np.unique(graph.labels)
        self.order = canonical_order(graph)
        self.order.flags.writeable = False
        labels = np.searchsorted(self.classes, graph.labels[self.order])
        self.target = SemanticGraph(
            graph.positions[self.order], labels, graph.edge_radius, graph.name
        )

    def _describe(self) -> np.ndarray:
        """The canonical graph's descriptors, computed whole."""
        rng = np.random.default_rng(0)  # unused: the descriptor is deterministic
        return self.descriptor(self.target, len(self.classes), rng)

    def _set_descriptors(self, descriptors) -> None:
        if isinstance(descriptors, np.ndarray):
            descriptors.flags.writeable = False
        self.descriptors = descriptors
        self.blocks = _matching_blocks(descriptors, self.target.labels)

    # -- use --------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.graph)

    def __repr__(self) -> str:
        return (
            f"PreparedMap(name={self.graph.name!r}, n={len(self)}, "
            f"classes={len(self.classes)}, descriptor={self.config.descriptor!r})"
        )

    def descriptor_settings(self) -> dict[str, Any]:
        """What binds a localizer to this map: the descriptor's name and parameters and the
        graph's edge radius (m)."""
        return descriptor_settings(self.config, self.graph.edge_radius)

    def pair(self, query: SemanticGraph, config: LocalizerConfig) -> CanonicalPair | None:
        """The canonical (query, map) pair carrying the prepared descriptors and matching
        blocks, for a localizer with `config`; None when the query holds a class the map does
        not (the class table then differs: localize against `graph` instead)."""
        mine = self.descriptor_settings()
        theirs = descriptor_settings(config, self.graph.edge_radius)
        if theirs != mine:
            raise PreparedMapError(
                f"map {self.graph.name!r} was prepared for descriptor {mine}, the localizer "
                f"uses {theirs}; prepare the map with the localizer's config "
                "(sgloc.prepare(graph, config))."
            )
        query_classes = np.unique(query.labels)
        if not np.all(np.isin(query_classes, self.classes)):
            return None
        pair = CanonicalPair.with_canonical_target(
            query, self.classes, self.order, self.target, config
        )
        pair.target_descriptors = self.descriptors
        pair.target_blocks = self.blocks
        return pair


def descriptor_settings(config: LocalizerConfig, edge_radius: float) -> dict[str, Any]:
    """The descriptor's name and parameters under `config`, and the edge radius (metres; the
    adjacency-based descriptors depend on it), as plain JSON values."""
    d = config.descriptor_config
    params = json.loads(json.dumps(d.get_params(), default=float))
    return {"descriptor": d.name, "params": params, "edge_radius": float(edge_radius)}


def _matching_blocks(descriptors, labels: np.ndarray):
    """The matching kernel's class blocks of the map (`sgloc.matching.TargetBlocks`), or None
    when matching runs without them (sparse descriptors, or a map small enough for the numpy
    path)."""
    from sgloc.matching import target_blocks

    return target_blocks(descriptors, labels)


def prepare(target: SemanticGraph, config: LocalizerConfig | None = None) -> PreparedMap:
    """`target` prepared for repeated localization under `config` (default settings): its
    canonical form, descriptors and matching blocks computed once (sgloc.prepared)."""
    return PreparedMap(target, config)


__all__ = ["PreparedMap", "PreparedMapError", "descriptor_settings", "prepare"]
_ = DistanceHistogramDescriptor  # the descriptor `add` updates row by row
