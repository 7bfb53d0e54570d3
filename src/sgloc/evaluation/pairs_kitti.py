"""KITTI 00's LiDAR objects: the sequence (poses, refined revisits), the one map builder
(`kitti_graph`, the `kitti-objects` extraction preset), the ground truth between two scan
ranges, and the pair source `kitti00`."""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from sgloc.errors import DatasetError
from sgloc.evaluation.scenes import (
    MovedTargetSource,
    register_pair_source,
    route_overlap,
    scene_data_root,
    window_overlaps,
)
from sgloc.extraction import extraction_preset
from sgloc.geometry import invert
from sgloc.maps.graph import DEFAULT_EDGE_RADIUS, SemanticGraph
from sgloc.pipeline.presets import localizer_settings as preset_settings

KITTI_LC_FILES = ("kitti_lc_test_0_10.txt", "kitti_lc_test_10_20.txt", "kitti_lc_test_20_30.txt")


def kitti_root() -> str:
    """The absolute KITTI 00 folder (the `kitti00` data set under SGLOC_DATA)."""
    return scene_data_root(None, "kitti00")


@functools.lru_cache(maxsize=2)
def kitti_sequence(root: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T_seq_lidar (N,4,4) per scan, revisit pairs (k,2) i<j, their M (k,4,4) with
    p_j = M p_i) of KITTI 00 under `root`, read once per process."""
    from sgloc.datasets.kitti_objects import TR_KITTI_00
    from sgloc.io.poses import read_kitti_poses

    P = read_kitti_poses(Path(root) / "poses_00.txt")
    Tr = np.eye(4)
    Tr[:3] = TR_KITTI_00
    found = [f for f in (Path(root) / name for name in KITTI_LC_FILES) if f.is_file()]
    if not found:
        raise DatasetError(f"{root}: no kitti_lc_test_*.txt revisit files.")
    a = np.concatenate([np.loadtxt(f, skiprows=1, ndmin=2) for f in found])
    ij, M = a[:, [1, 3]].astype(np.int64), a[:, 4:20].reshape(-1, 4, 4)
    swap = ij[:, 0] > ij[:, 1]
    ij[swap] = ij[swap][:, ::-1]
    M[swap] = np.linalg.inv(M[swap])
    return P @ Tr, ij, M


@functools.lru_cache(maxsize=512)
def kitti_graph(
    root: str, first: int, last: int, edge_radius: float = DEFAULT_EDGE_RADIUS
) -> SemanticGraph:
    """One robot's graph from scans first..last (inclusive), in its first scan's LiDAR frame,
    extracted with the `kitti-objects` preset (one scan: every object is seen once, so without
    the preset's minimum observation count)."""
    from sgloc.datasets import make_dataset
    from sgloc.extraction import build_graph

    cfg = extraction_preset("kitti-objects")
    name = f"kitti00[{first}-{last}]"
    if first == last:
        cfg, name = dataclasses.replace(cfg, min_observations=1), f"kitti00[{first}]"
    ds = make_dataset("kitti_objects", root, scans=(first, last), start_frame=True)
    return build_graph(ds, cfg, name=name).with_edge_radius(edge_radius)


def kitti_ground_truth(
    root: str, a: tuple[int, int], b: tuple[int, int], k: int = -1, swap: bool = False
) -> np.ndarray:
    """T_A_B from scans b's first-scan frame (query) to scans a's (target): the raw poses when
    k < 0, else the poses chained through refined revisit k (p_j = M p_i; a holds i and b holds
    j, or the other way round with swap) -- more accurate near the revisit."""
    L, ij, M = kitti_sequence(root)
    if k < 0:
        return invert(L[a[0]]) @ L[b[0]]
    i, j = ij[k]
    if swap:
        return invert(L[a[0]]) @ L[j] @ M[k] @ invert(L[i]) @ L[b[0]]
    return invert(L[a[0]]) @ L[i] @ invert(M[k]) @ invert(L[j]) @ L[b[0]]


@register_pair_source("kitti00")
@dataclass(frozen=True)
class Kitti00Pairs(MovedTargetSource):
    """KITTI 00 LiDAR objects (GOSMatch) as two robots, each mapping a scan range in its own
    first-scan frame; the target is also moved by a random rigid transform per trial.

    overlap=None: the fixed split of the data README (robot A = target = scans `split[0:2]`,
    robot B = query = scans `split[2:4]`).
    overlap=o: trial seed s uses revisit place s % n_places (distinct revisits (i, j) of the
    sequence from kitti_lc_test_*.txt, j - i >= min_gap scans; graphs are built once per place
    and process); robot A maps `length` scans centred on i, robot B a window of
    `length` scans near j, slid so that the fraction of B's route within `radius` m of A's
    route is as close to o as the trajectory allows (the achieved value is in the row as
    pair_overlap).
    Ground truth T_A_B: in overlap mode the poses chained through the revisit's refined
    transform M (kitti_lc_test_*.txt; more accurate than the raw poses near the revisit, and
    the windows are centred on it); for the fixed split the raw poses (M is only locally
    accurate and the split's maps reach hundreds of metres beyond it).
    """

    data_set: ClassVar[str | None] = "kitti00"
    #: Recommended localizer settings (the extraction preset's: precise LiDAR centroids).
    localizer_settings: ClassVar[dict[str, Any]] = preset_settings("kitti-objects")

    root: str | None = None
    overlap: float | None = None
    length: int = 300
    radius: float = 10.0
    min_gap: int = 600
    n_places: int = 10
    min_max_overlap: float = 0.5
    split: tuple[int, int, int, int] = (0, 800, 3900, 4540)
    edge_radius: float = DEFAULT_EDGE_RADIUS

    def sliding_windows(self, k: int) -> tuple[tuple[int, int], np.ndarray, np.ndarray]:
        """For revisit k: robot A's scans, the candidate first scans of robot B's window, and
        each window's route overlap with A (cumulative sums over the route, all at once)."""
        L_seq, ij, _ = kitti_sequence(self.root)
        xy = L_seq[:, [0, 2], 3]  # the camera sequence frame: ground plane is x-z
        n, (i, j) = len(L_seq), ij[k]
        a0 = int(np.clip(i - self.length // 2, 0, n - self.length))
        a = (a0, a0 + self.length - 1)
        lo = max(a[1] + 1, j - 2 * self.length)
        starts = np.arange(lo, max(lo, min(n - self.length, j + self.length)) + 1)
        ovs = window_overlaps(xy, xy[a[0] : a[1] + 1], starts, self.length, self.radius)
        return a, starts, ovs

    @functools.lru_cache(maxsize=8)  # noqa: B019 (a few small frozen sources per process)
    def places(self) -> np.ndarray:
        """Indices of up to `n_places` distinct revisits (j - i >= min_gap) spread over the
        sequence, each on a shared stretch of road long enough that robot B's window can be
        slid from overlap <= 0.1 to >= `min_max_overlap` with robot A's."""
        _, ij, _ = kitti_sequence(self.root)
        ok = np.flatnonzero(ij[:, 1] - ij[:, 0] >= self.min_gap)
        ok = ok[np.lexsort((ij[ok, 1], ij[ok, 0]))]
        chosen: list[int] = []
        for k in ok:
            if any(abs(ij[k, 0] - ij[c, 0]) < self.length // 2 for c in chosen):
                continue
            _, _, ovs = self.sliding_windows(int(k))
            if ovs.size and ovs.max() >= self.min_max_overlap and ovs.min() <= 0.1:
                chosen.append(int(k))
        if not chosen:
            raise DatasetError(f"{self.root}: no revisit with a long enough shared stretch.")
        picks = np.linspace(0, len(chosen) - 1, min(self.n_places, len(chosen)))
        return np.array(chosen)[np.round(picks).astype(int)]

    def windows(self, seed: int) -> tuple[tuple[int, int], tuple[int, int], int, float]:
        """(A scans, B scans, revisit index, achieved overlap) for a trial seed."""
        L_seq, ij, _ = kitti_sequence(self.root)
        if self.overlap is None:
            # Raw poses: the split's maps extend hundreds of scans from any revisit, where a
            # revisit's locally refined M is off by ~1 deg (measured: 64 of B's objects land
            # within 1 m of a same-class A object with the raw poses, 7 with M).
            xy = L_seq[:, [0, 2], 3]
            a, b = (self.split[0], self.split[1]), (self.split[2], self.split[3])
            ov = route_overlap(xy[b[0] : b[1] + 1], xy[a[0] : a[1] + 1], self.radius)
            return a, b, -1, ov
        places = self.places()
        k = int(places[int(seed) % len(places)])
        a, starts, ovs = self.sliding_windows(k)
        best = int(np.argmin(np.abs(ovs - self.overlap)))
        s = int(starts[best])
        return a, (s, s + self.length - 1), k, float(ovs[best])

    def maps(self, seed: int) -> tuple[SemanticGraph, SemanticGraph, np.ndarray, dict[str, Any]]:
        a, b, k, ov = self.windows(seed)
        target = kitti_graph(self.root, a[0], a[1], self.edge_radius)
        query = kitti_graph(self.root, b[0], b[1], self.edge_radius)
        info = {"overlap": round(ov, 4), "scans_a": f"{a[0]}-{a[1]}", "scans_b": f"{b[0]}-{b[1]}"}
        return query, target, kitti_ground_truth(self.root, a, b, k), info
