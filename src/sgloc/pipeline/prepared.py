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
(objects x classes x bins floats), and for maps larger than
`sgloc.matching.candidates.BLOCKS_MIN_OBJECTS`
objects a second, normalised copy for the matching kernel: grouped by class for the classes
searched exhaustively, by the lists of the candidate-search index for the classes of more than
`sgloc.matching.index.INDEX_MIN_CLASS` objects (`MatchingConfig.search`; rebuilt by `add` and
on `load`). The acceptance test's neighbour grid of the map (`chance_grid`, at most 64 bytes
per object) and its class counts are built with it, so a query's chance model costs its own
neighbourhood, not the map.

All of it is held by the map's `canonical` (`sgloc.maps.prepared_graph.PreparedGraph`), which the
localizer hands to the stages; what a query builds on it for later ones (grids at other radii,
the candidate-search index of a class a localizer searches by index) is kept there too, and
goes with the map. Nothing is kept anywhere else: a localization against the graph itself
builds all of it for that call.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.descriptors import DistanceHistogramDescriptor, RandomWalkDescriptor
from sgloc.errors import SglocError
from sgloc.maps.canonical import CanonicalPair, canonical_order
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.prepared_graph import PreparedGraph
from sgloc.maps.scale import AUTO, estimate_scale
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.presets import at_estimated_scale
from sgloc.validation import check_graph_arrays

#: The file format's name and version (`PreparedMap.save`).
FORMAT = "sgloc.PreparedMap"
VERSION = 1
#: A localization needs at least this many target objects (as `sgloc.pipeline.localizer`).
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
        (`sgloc.maps.canonical`); target: the canonical graph (classes renumbered 0..L-1);
        descriptors: (n, d) the canonical graph's descriptor rows (read-only);
        blocks: the matching kernel's class blocks (`sgloc.matching.candidates.TargetBlocks`) or
        None; canonical: the `PreparedGraph` of `target` holding descriptors, blocks, neighbour
        grids and class indexes, handed to the stages of every query;
        chance_grid: the acceptance test's neighbour grid of `target` at the config's
        acceptance radius, built when the map is.
    """

    def __init__(self, graph: SemanticGraph, config: LocalizerConfig | None = None) -> None:
        if not isinstance(graph, SemanticGraph):
            raise PreparedMapError(f"prepare needs a SemanticGraph, got {type(graph).__name__}.")
        self.config = config or LocalizerConfig()
        #: The scene scale estimated from `graph` when `config` asked for scale="auto" (the
        #: map keeps it as it grows; `sgloc.maps.scale.ScaleEstimate`), else None.
        self.scale_estimate = None
        if self.config.scale == AUTO and isinstance(graph, SemanticGraph) and len(graph) >= 2:
            self.scale_estimate = estimate_scale(graph)
            self.config = at_estimated_scale(self.config, self.scale_estimate)
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
        self.canonical = PreparedGraph(self.target)
        self.chance_grid = self._chance_grid()

    def _chance_grid(self):
        """The acceptance test's neighbour grid of the map at the config's acceptance radius
        (`PreparedGraph.grid`), built now rather than by the first query, and the class
        counts."""
        radius = float(self.config.acceptance.radius or self.config.ransac.threshold)
        _ = self.canonical.class_counts  # built now, not by the first query
        return self.canonical.grid(radius)

    def _describe(self) -> np.ndarray:
        """The canonical graph's descriptors, computed whole."""
        rng = np.random.default_rng(0)  # unused: the descriptor is deterministic
        return self.descriptor(self.target, len(self.classes), rng)

    _accepted: LocalizerConfig | None = None  # the last config `pair` checked

    def _set_descriptors(self, descriptors) -> None:
        if isinstance(descriptors, np.ndarray):
            descriptors.flags.writeable = False
        self.descriptors = descriptors
        self.blocks = _matching_blocks(descriptors, self.target.labels, self.config)
        # On a new map's `canonical` (`_set_graph` makes it): nothing built on old rows stays.
        self.canonical.descriptors, self.canonical.blocks = descriptors, self.blocks

    # -- use --------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.graph)

    def __repr__(self) -> str:
        return (
            f"PreparedMap(name={self.graph.name!r}, n={len(self)}, "
            f"classes={len(self.classes)}, descriptor={self.config.descriptor!r})"
        )

    # -- growth -----------------------------------------------------------------------------
    def add(self, positions: np.ndarray, labels: np.ndarray) -> PreparedMap:
        """Add objects (positions (k,3) metres in the map's frame, labels (k,) class ids) to
        the map, in place; they get the vertex indices len(map) .. len(map) + k - 1. With the
        default descriptor only the descriptors within its radius of the new objects change
        (updated exactly: the same bits as preparing the grown map anew); other descriptors
        are recomputed whole. Returns the map."""
        pos, lab = check_graph_arrays("added objects", positions, labels)
        if len(pos) == 0:
            return self
        old = (self.graph, self.order, self.classes, self.target, self.descriptors)
        g = self.graph
        grown = SemanticGraph(
            np.concatenate([g.positions, pos]), np.concatenate([g.labels, lab]),
            g.edge_radius, g.name,
        )  # fmt: skip
        self._set_graph(grown)
        incremental = isinstance(self.descriptor, DistanceHistogramDescriptor) and isinstance(
            old[4], np.ndarray
        )
        if incremental:
            self._set_descriptors(self._grown_descriptors(*old[1:], pos, lab))
        else:
            self._set_descriptors(self._describe())
        return self

    def _grown_descriptors(
        self,
        old_order: np.ndarray,
        old_classes: np.ndarray,
        old_target: SemanticGraph,
        old_rows: np.ndarray,
        pos: np.ndarray,
        lab: np.ndarray,
    ) -> np.ndarray:
        """The grown map's canonical descriptor rows from the old ones: columns moved to the
        new class table, the new objects' contributions added to the old rows within the
        radius, the new objects' rows computed, all put in the new canonical order. Sums of
        the descriptor's weights are exact, so this equals computing them anew."""
        from sgloc.maps.neighbor_kernels import distance_histograms, near_class_counts

        desc, L = self.descriptor, len(self.classes)
        nb, radius, taper = int(desc.n_bins), float(desc.radius), float(desc.taper)
        n_old = len(old_target)
        rows = np.zeros((n_old + len(pos), L * nb))
        moved = np.searchsorted(self.classes, old_classes)  # new column block of each old one
        rows[:n_old].reshape(n_old, L, nb)[:, moved, :] = old_rows.reshape(n_old, -1, nb)
        p_old = np.ascontiguousarray(old_target.positions)
        l_old = np.searchsorted(self.classes, old_classes[old_target.labels])
        l_new = np.searchsorted(self.classes, lab)
        none = np.zeros(0)
        near = near_class_counts(p_old, pos, np.zeros(len(pos), np.int64), 1, radius, none)[0]
        hit = np.flatnonzero(near[:, 0] > 0)  # old objects within the radius of a new one
        args = (L, radius, nb, taper)
        rows[hit] += distance_histograms(p_old[hit], np.full(len(hit), -1), pos, l_new, *args)
        local = np.concatenate([p_old[hit], pos])
        local_labels = np.concatenate([l_old[hit], l_new])
        self_index = len(hit) + np.arange(len(pos))
        rows[n_old:] = distance_histograms(pos, self_index, local, local_labels, *args)
        # Row of each caller index: old objects at their old canonical place, then the new.
        where = np.empty(n_old + len(pos), dtype=np.int64)
        where[old_order] = np.arange(n_old)
        where[n_old:] = n_old + np.arange(len(pos))
        return rows[where[self.order]]

    # -- files ------------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write the prepared map to one `.npz` file (numpy arrays, and a JSON header with the
        format version and the config it was prepared for); returns the path. Descriptors are
        stored, so loading skips their computation."""
        path = Path(path)
        meta = {
            "format": FORMAT,
            "version": VERSION,
            "name": self.graph.name,
            "edge_radius": self.graph.edge_radius,
            "descriptor_settings": self.descriptor_settings(),
            "config": _plain(self.config.to_dict()),
        }
        arrays = {"positions": self.graph.positions, "labels": self.graph.labels}
        if isinstance(self.descriptor, DistanceHistogramDescriptor):
            arrays["descriptors"] = self.descriptors
        with path.open("wb") as f:
            np.savez(f, meta=np.array(json.dumps(meta)), **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path, config: LocalizerConfig | None = None) -> PreparedMap:
        """Read a map written by `save`. `config`: the localizer config it will serve; its
        descriptor must be the one the map was prepared for (PreparedMapError else). Without
        it, the saved config is used."""
        meta, arrays = _read(Path(path))
        saved = LocalizerConfig.from_dict(meta["config"])
        if config is not None:
            mine = meta["descriptor_settings"]
            theirs = descriptor_settings(config, float(meta["edge_radius"]))
            if theirs != mine:
                raise PreparedMapError(
                    f"{path}: prepared for another descriptor than the given config's "
                    f"({_differences(mine, theirs)}); load it without a config, or prepare "
                    "the map again with this config."
                )
        graph = SemanticGraph(arrays["positions"], arrays["labels"], float(meta["edge_radius"]),
                              meta["name"])  # fmt: skip
        out = cls.__new__(cls)
        out.config = config or saved
        out.descriptor = out.config.descriptor_config
        out._set_graph(graph)
        rows = arrays.get("descriptors")
        if not _stored(out.descriptor, rows, len(graph), len(out.classes)):
            rows = out._describe()  # not stored (another descriptor): computed anew
        out._set_descriptors(rows)
        return out

    def descriptor_settings(self) -> dict[str, Any]:
        """What binds a localizer to this map: the descriptor's name and parameters and the
        graph's edge radius (m)."""
        return descriptor_settings(self.config, self.graph.edge_radius)

    def _check(self, config: LocalizerConfig) -> None:
        """PreparedMapError unless `config`'s descriptor is the one this map was prepared for."""
        mine = self.descriptor_settings()
        theirs = descriptor_settings(config, self.graph.edge_radius)
        if theirs != mine:
            raise PreparedMapError(
                f"map {self.graph.name!r} was prepared for another descriptor than the "
                f"localizer's ({_differences(mine, theirs)}); prepare it with the localizer's "
                "config: sgloc.prepare(graph, config) or Localizer(config).prepare(graph)."
            )

    def pair(self, query: SemanticGraph, config: LocalizerConfig) -> CanonicalPair | None:
        """The canonical (query, map) pair carrying the map's `canonical` prepared graph
        (descriptors, matching blocks, grids), for a localizer with `config`; None when the
        query holds a class the map does not (the class table then differs: localize against
        `graph` instead)."""
        if config is not self._accepted:  # a localizer passes the same config every call
            self._check(config)
            self._accepted = config
        query_classes = np.unique(query.labels)
        if not np.all(np.isin(query_classes, self.classes)):
            return None
        pair = CanonicalPair.with_canonical_target(
            query, self.classes, self.order, self.target, config
        )
        pair.prepared_target = self.canonical
        return pair


def descriptor_settings(config: LocalizerConfig, edge_radius: float) -> dict[str, Any]:
    """The descriptor's name and parameters under `config`, and the edge radius (metres; the
    adjacency-based descriptors depend on it), as plain JSON values."""
    d = config.descriptor_config
    params = json.loads(json.dumps(dataclasses.asdict(d), default=float))
    return {"descriptor": d.name, "params": params, "edge_radius": float(edge_radius)}


def _differences(prepared: dict[str, Any], other: dict[str, Any]) -> str:
    """'radius: prepared 40.0, here 30.0; ...' for the settings that differ."""
    flat = [(k, prepared[k], other[k]) for k in ("descriptor", "edge_radius")]
    keys = sorted(set(prepared["params"]) | set(other["params"]))
    flat += [(k, prepared["params"].get(k), other["params"].get(k)) for k in keys]
    return "; ".join(f"{k}: prepared {a!r}, here {b!r}" for k, a, b in flat if a != b)


def _stored(descriptor, rows: np.ndarray | None, n: int, n_classes: int) -> bool:
    """Whether `rows` from a file are the default descriptor's rows of this map (shape and
    type; the file's header named the same descriptor settings)."""
    if not isinstance(descriptor, DistanceHistogramDescriptor) or rows is None:
        return False
    return rows.dtype == np.float64 and rows.shape == (n, n_classes * int(descriptor.n_bins))


def _plain(value: Any) -> Any:
    """`value` with numpy scalars and tuples made JSON values."""
    return json.loads(json.dumps(value, default=lambda v: v.item() if hasattr(v, "item") else v))


def _read(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(header, arrays) of a prepared-map file; PreparedMapError when it is not one."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(str(arrays.pop("meta")))
    except (OSError, ValueError, KeyError) as e:
        raise PreparedMapError(
            f"{path}: not a prepared map file ({e}); write one with PreparedMap.save."
        ) from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise PreparedMapError(f"{path}: not a prepared map file; write one with PreparedMap.save.")
    if meta.get("version") != VERSION:
        raise PreparedMapError(
            f"{path}: prepared map format version {meta.get('version')}, this sgloc reads "
            f"version {VERSION}; prepare the map again from its graph."
        )
    for key in ("positions", "labels"):
        if key not in arrays:
            raise PreparedMapError(f"{path}: prepared map file without {key!r}.")
    for key, kind in (("name", str), ("edge_radius", float), ("descriptor_settings", dict),
                      ("config", dict)):  # fmt: skip
        if not isinstance(meta.get(key), kind):
            raise PreparedMapError(
                f"{path}: prepared map header without a valid {key!r}; save the map again."
            )
    return meta, arrays


def _matching_blocks(descriptors, labels: np.ndarray, config: LocalizerConfig):
    """The matching kernel's class blocks of the map (`sgloc.matching.candidates.TargetBlocks`),
    with the
    candidate-search index of its large classes unless the config's matching search is
    "exact", or None when matching runs without them (sparse descriptors, or a map small
    enough to build them per call)."""
    from sgloc.matching.candidates import target_blocks

    return target_blocks(descriptors, labels, config.matching.search)


def prepare(target: SemanticGraph, config: LocalizerConfig | None = None) -> PreparedMap:
    """`target` prepared for repeated localization under `config` (default settings): its
    canonical form, descriptors and matching blocks computed once (sgloc.pipeline.prepared)."""
    return PreparedMap(target, config)


__all__ = ["PreparedMap", "PreparedMapError", "descriptor_settings", "prepare"]
