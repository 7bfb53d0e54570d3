"""Pair source `synthia`: SYNTHIA's forward camera (Omni_F) and backward camera (Omni_B) as two
robots, the paper's SYNTHIA experiment (Table 2 whole maps, Fig. 6 overlap sweep)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from sgloc.evaluation.scenes import (
    MovedTargetSource,
    register_pair_source,
    route_overlap,
    window_overlaps,
)
from sgloc.geometry import invert
from sgloc.graph import DEFAULT_EDGE_RADIUS, SemanticGraph
from sgloc.presets import extraction_preset

CAMERAS = ("Omni_F", "Omni_B")


@functools.lru_cache(maxsize=4)
def _camera_poses(root: str, camera: str) -> np.ndarray:
    """(N,4,4) world-from-optical poses of every frame of one camera."""
    from sgloc.datasets import make_dataset

    return make_dataset("synthia", root, camera=camera).poses


@functools.lru_cache(maxsize=64)
def _synthia_graph(
    root: str, camera: str, first: int, last: int, edge_radius: float
) -> SemanticGraph:
    """One camera's graph from frames first..last (inclusive), in its first frame's optical
    frame (the `synthia` extraction preset: objects only)."""
    from sgloc.datasets import make_dataset
    from sgloc.extraction import build_graph

    ds = make_dataset("synthia", root, camera=camera, frames=(first, last), start_frame=True)
    g = build_graph(ds, extraction_preset("synthia"), name=f"{camera}[{first}-{last}]")
    return g.with_edge_radius(edge_radius)


@register_pair_source("synthia")
@dataclass(frozen=True)
class SynthiaPairs(MovedTargetSource):
    """A SYNTHIA sequence folder (e.g. SYNTHIA-SEQS-04-SUMMER, or one written by
    `sgloc.sim.synthia_writer`): robot A (target) = Omni_F, robot B (query) = Omni_B, each map in
    its first frame's camera frame; the target is moved by a random rigid transform per trial.

    overlap=None: the whole sequences (Table 2). overlap=o: robot A maps the first `length`
    frames, robot B a window of `length` frames slid along the sequence so that the fraction of
    B's route within `radius` m of A's route is as close to o as it allows (the achieved value
    is in the pair's info as `overlap`). Ground truth: both cameras' poses are in the
    sequence's world frame, T_A_B = inv(P_A[a0]) @ P_B[b0].
    """

    data_set: ClassVar[str | None] = "synthia"
    root: str | None = None
    overlap: float | None = None
    length: int = 200
    radius: float = 10.0
    edge_radius: float = DEFAULT_EDGE_RADIUS

    def windows(self) -> tuple[tuple[int, int], tuple[int, int], float]:
        """(A frames, B frames, achieved route overlap), inclusive ranges."""
        PA, PB = (_camera_poses(self.root, c) for c in CAMERAS)
        xa, xb = PA[:, :3, 3], PB[:, :3, 3]
        if self.overlap is None:
            a, b = (0, len(PA) - 1), (0, len(PB) - 1)
            return a, b, route_overlap(xb, xa, self.radius)
        n = min(self.length, len(PA), len(PB))
        a = (0, n - 1)
        starts = np.arange(0, len(PB) - n + 1)
        ovs = window_overlaps(xb, xa[:n], starts, n, self.radius)
        s = int(starts[np.argmin(np.abs(ovs - self.overlap))])
        return a, (s, s + n - 1), float(ovs[s])

    def maps(self, seed: int) -> tuple[SemanticGraph, SemanticGraph, np.ndarray, dict[str, Any]]:
        a, b, ov = self.windows()
        PA, PB = (_camera_poses(self.root, c) for c in CAMERAS)
        target = _synthia_graph(self.root, CAMERAS[0], *a, self.edge_radius)
        query = _synthia_graph(self.root, CAMERAS[1], *b, self.edge_radius)
        info = {"overlap": round(ov, 4), "frames_a": f"{a[0]}-{a[1]}", "frames_b": f"{b[0]}-{b[1]}"}
        return query, target, invert(PA[a[0]]) @ PB[b[0]], info
