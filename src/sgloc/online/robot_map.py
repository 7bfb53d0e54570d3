"""One robot's growing object map in its odometry frame: sightings associated and averaged by
the same association as offline map building (`sgloc.maps.association`). Every sighting is kept
with the keyframe that saw it and its position in that keyframe's sensor frame, so that the map
follows a corrected trajectory (`RobotMap.reanchor`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from sgloc.errors import SglocError
from sgloc.geometry import apply
from sgloc.maps.association import AssociationSettings, ObjectAssociation
from sgloc.maps.graph import SemanticGraph
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.prepared import MIN_VERTICES, PreparedMap, prepare
from sgloc.validation import check_graph_arrays


class RobotMap:
    """Objects of one robot (odometry frame, metres) built from keyframe sightings.

    A sighting joins the nearest object of its class within `radius` metres (its position
    becomes the running mean of its sightings); sightings of one keyframe never merge with each
    other; sightings that join nothing start new objects. An object is confirmed from
    `min_observations` sightings; only confirmed objects are in `graph()`. `sightings()`
    gives, per sighting, its keyframe, its position in that keyframe's sensor frame and its
    object; `reanchor` re-places the objects under corrected keyframe poses.
    """

    def __init__(self, name: str, radius: float, min_observations: int, edge_radius: float):
        self.name = name
        self.min_observations = int(min_observations)
        self.builder = ObjectAssociation(AssociationSettings(
            association_radius=float(radius), min_observations=int(min_observations),
            edge_radius=float(edge_radius),
        ))  # fmt: skip
        self._graph: SemanticGraph | None = None
        self._prepared: PreparedMap | None = None  # of _graph
        self._confirmed = 0
        self.stamps: list[float] = []
        self.poses: list[np.ndarray] = []
        self._anchor: list[np.ndarray] = []  # the keyframe poses the objects are placed with
        self._travel: list[float] = []  # metres travelled to each keyframe
        self._chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._sightings: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._views: tuple[np.ndarray, np.ndarray] | None = None  # of _sightings, `views`
        self._derived: dict[str, Any] = {}  # `derived`, of _views
        self.version = 0  # counts the changes of the objects' or keyframes' placement

    @property
    def n_confirmed(self) -> int:
        """Objects seen at least `min_observations` times."""
        return self._confirmed

    @property
    def keyframes(self) -> int:
        return self.builder.n_frames

    def add(
        self, stamp: float, T_odom_sensor: np.ndarray, positions: np.ndarray, labels: np.ndarray
    ) -> None:
        """Add one keyframe's sightings (positions (n,3) in the sensor frame, metres; labels
        (n,) class ids; T_odom_sensor (4,4) the keyframe's pose in the odometry frame; stamp
        in seconds)."""
        T = np.asarray(T_odom_sensor, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise SglocError(
                f"robot {self.name!r}: T_odom_sensor must be a finite 4x4 matrix, got shape "
                f"{T.shape}; pass the keyframe's pose in the robot's odometry frame."
            )
        pos, lab = check_graph_arrays(f"robot {self.name!r} keyframe", positions, labels)
        went = self.builder.add_observations(apply(T, pos), lab)
        ok = went >= 0
        self._chunks.append((np.full(int(ok.sum()), len(self.poses), np.int64), pos[ok],
                             went[ok]))
        self._sightings = self._views = None
        self._derived = {}
        self.version += 1
        step = float(np.linalg.norm(T[:3, 3] - self.poses[-1][:3, 3])) if self.poses else 0.0
        self._travel.append(self._travel[-1] + step if self._travel else 0.0)
        self.stamps.append(float(stamp))
        self.poses.append(T.copy())
        self._anchor.append(T.copy())
        counts = self.builder.counts
        # The confirmed map changed when a sighting went to an object that is now confirmed.
        if len(went) and (counts[went] >= self.min_observations).any():
            self._graph = None
        self._confirmed = int(np.count_nonzero(counts >= self.min_observations))

    def graph(self) -> SemanticGraph:
        """The confirmed objects as a SemanticGraph (cached until they change)."""
        if self._graph is None:
            self._graph = self.builder.graph(self.name)
            self._prepared = None
        return self._graph

    def prepared(self, config: LocalizerConfig, uses: int = 2) -> SemanticGraph | PreparedMap:
        """`graph()` prepared for localizations against it with `config`
        (`sgloc.PreparedMap`), kept until the confirmed objects change or another config asks.
        The graph itself while it is too small to prepare, or when no preparation is kept and
        fewer than `uses` localizations are to use it (preparing costs about one of them)."""
        graph = self.graph()
        kept = self._prepared is not None and self._prepared.config is config
        if kept or (uses >= 2 and len(graph) >= MIN_VERTICES):
            if not kept:
                self._prepared = prepare(graph, config)
            return self._prepared
        return graph

    def sightings(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(keyframe (s,) index, position (s,3) metres in that keyframe's sensor frame, object
        (s,) index into the association's objects) of every sighting kept, in arrival order."""
        if self._sightings is None:
            if self._chunks:
                k, p, o = (np.concatenate(x) for x in zip(*self._chunks, strict=True))
            else:
                k, p, o = np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64)
            self._chunks = [(k, p, o)]
            self._sightings = (k, p, o)
        return self._sightings

    def views(self) -> tuple[np.ndarray, np.ndarray]:
        """(position (s,3), unit ray from the sensor (s,3)) of every sighting (`sightings`
        order) in the odometry frame, its keyframe placed as it is now (`anchors`); kept until
        a keyframe is added or moved."""
        if self._views is None:
            k, p, _ = self.sightings()
            A = self.anchors()
            t = w = A[:, :3, 3][k]
            for j in range(3):  # R p column by column: far lighter than gathering (s,3,3)
                w = w + np.ascontiguousarray(A[:, :3, j])[k] * p[:, j:j + 1]
            norm = np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-12)
            self._views = (w, (w - t) / norm)
        return self._views

    def derived(self, key: str, compute: Callable[[], Any]) -> Any:
        """`compute()` (a value derived from `views`, e.g. `sgloc.online.keyframes.views`'s),
        kept under `key` until a keyframe is added or moved."""
        if key not in self._derived:
            self._derived[key] = compute()
        return self._derived[key]

    def anchors(self) -> np.ndarray:
        """(k,4,4) the keyframe poses (odometry frame) the objects are placed with now: the
        odometry's, or the last `reanchor`'s."""
        return np.array(self._anchor).reshape(-1, 4, 4)

    def reanchor(self, T_odom_keyframes: np.ndarray, tolerance: float = 1e-12) -> int:
        """Re-place every object at the mean of its sightings seen from the corrected keyframe
        poses T_odom_keyframes (k,4,4) (odometry frame, one per keyframe so far). Only the
        sightings of keyframes whose pose moved by more than `tolerance` (any matrix entry) are
        re-projected: their objects' sums change by the difference. Returns how many
        keyframes moved."""
        T = np.asarray(T_odom_keyframes, np.float64)
        if T.shape != (len(self.poses), 4, 4) or not np.isfinite(T).all():
            raise SglocError(
                f"robot {self.name!r}: reanchor needs ({len(self.poses)},4,4) finite keyframe "
                f"poses, got {T.shape}."
            )
        old = self.anchors()
        moved = np.abs(T - old).reshape(len(T), -1).max(axis=1, initial=0.0) > tolerance
        if not moved.any():
            return 0
        k, p, o = self.sightings()
        sel = moved[k]
        ks, ps = k[sel], p[sel]
        delta = (np.einsum("sij,sj->si", T[ks, :3, :3], ps) + T[ks, :3, 3]
                 - np.einsum("sij,sj->si", old[ks, :3, :3], ps) - old[ks, :3, 3])
        self.builder.shift(o[sel], delta)
        for i in np.flatnonzero(moved):
            self._anchor[i] = T[i].copy()
        self._graph = self._views = None
        self._derived = {}
        self.version += 1
        return int(moved.sum())

    def travelled(self) -> np.ndarray:
        """(k,) metres travelled (odometry) from the first keyframe to each keyframe."""
        return np.array(self._travel, np.float64)

    @property
    def distance(self) -> float:
        """Metres travelled (odometry) from the first keyframe to the latest (0.0 before)."""
        return self._travel[-1] if self._travel else 0.0

    def seen_since(self, first: int) -> np.ndarray:
        """(n,) bool over the association's objects: sighted by keyframe `first` or a later
        one."""
        return self.seen_between(first, len(self.poses))

    def seen_between(self, first: int, stop: int) -> np.ndarray:
        """(n,) bool over the association's objects: sighted by a keyframe k with first <= k <
        stop."""
        k, _, o = self.sightings()
        seen = np.zeros(len(self.builder.counts), bool)
        seen[o[(k >= first) & (k < stop)]] = True
        return seen

    def subgraph(self, objects: np.ndarray) -> SemanticGraph:
        """The confirmed objects among `objects` ((n,) bool over the association's objects) as a
        SemanticGraph (odometry frame)."""
        keep = np.asarray(objects, bool) & (self.builder.counts >= self.min_observations)
        return SemanticGraph(self.builder.positions[keep], self.builder.labels[keep],
                             self.builder.config.edge_radius, name=self.name)

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """(stamps (k,), T_odom_sensor (k,4,4)) of the keyframes so far."""
        return np.array(self.stamps, np.float64), np.array(self.poses).reshape(-1, 4, 4)

    def state(self) -> dict[str, np.ndarray]:
        """Arrays that restore this map (`set_state`)."""
        stamps, poses = self.trajectory()
        k, p, o = self.sightings()
        return {**self.builder.state(), "stamps": stamps, "poses": poses,
                "anchors": self.anchors(), "sighting_keyframe": k, "sighting_position": p,
                "sighting_object": o}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        self.builder = ObjectAssociation.from_state(self.builder.config, state)
        self.stamps = [float(t) for t in state["stamps"]]
        self.poses = [np.array(T) for T in np.asarray(state["poses"]).reshape(-1, 4, 4)]
        self._travel = [0.0] * bool(len(self.poses))
        for a, b in zip(self.poses[:-1], self.poses[1:], strict=True):  # as `add` sums them
            self._travel.append(self._travel[-1] + float(np.linalg.norm(b[:3, 3] - a[:3, 3])))
        anchors = np.asarray(state.get("anchors", state["poses"])).reshape(-1, 4, 4)
        self._anchor = [np.array(T) for T in anchors]
        if "sighting_keyframe" in state:  # sessions saved before sightings were kept have none
            self._chunks = [(np.asarray(state["sighting_keyframe"], np.int64).ravel(),
                             np.asarray(state["sighting_position"], np.float64).reshape(-1, 3),
                             np.asarray(state["sighting_object"], np.int64).ravel())]
        else:
            self._chunks = []
        self._sightings = self._views = None
        self._derived = {}
        self._confirmed = int(np.count_nonzero(self.builder.counts >= self.min_observations))
        self._graph = None
