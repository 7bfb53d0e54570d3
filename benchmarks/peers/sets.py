"""Correspondence sets the peer benchmark runs every method on.

Each set is one list of candidate matches src[i] (query frame) <-> dst[i] (target frame) with the
ground truth T_gt (dst <- src) and, per match, whether it is correct:
- airsim-guo: the histogram-descriptor matches of Guo's cloud1 (query) against cloud2 (target),
  the target moved by a random rigid transform per seed (ground truth identity before it); a
  match is correct when its two vertices lie within T_p = 10 m under the ground truth (paper).
- kitti00: the two-robot split of KITTI 00 (A = scans 0-800, B = 3900-4540, each in its start
  frame, graphs by the kitti_objects preset), B's matches against A, A moved per seed; correct
  within 3 m (the raw KITTI poses are off by 1-2 m at revisits).
- synthetic: `sgloc.sim.correspondences` (m, outlier ratio, random or structured outliers);
  correct = generated as an inlier (noise 0.5 m).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from sgloc.datasets.downloads import data_path
from sgloc.descriptors import make_descriptor
from sgloc.geometry import apply, random_rigid_transform
from sgloc.maps.graph import SemanticGraph
from sgloc.matching.candidates import MatchingConfig, match_descriptors
from sgloc.sim.correspondences import make_correspondences


@dataclass
class BenchSet:
    """One correspondence set and how to judge a method on it.

    family / kind / outlier_ratio: for grouping rows. tau: the consistency tolerance given to
    the rejectors (metres); threshold: RANSAC / inlier distance (metres); success_m, success_deg:
    a run succeeds when its transform is within both.
    """

    family: str
    kind: str
    seed: int
    src: np.ndarray
    dst: np.ndarray
    T_gt: np.ndarray
    correct: np.ndarray
    tau: float
    threshold: float
    success_m: float
    success_deg: float

    @property
    def m(self) -> int:
        return len(self.src)

    @property
    def outlier_ratio(self) -> float:
        return float(1 - self.correct.mean()) if self.m else 1.0

    @property
    def group(self) -> str:
        if self.family == "synthetic":
            return f"synthetic m={self.m} {self.kind}"
        return self.family


def _candidates(q: SemanticGraph, t: SemanticGraph, matching: MatchingConfig) -> np.ndarray:
    rng = np.random.default_rng(0)
    desc = make_descriptor("histogram")
    n_classes = max(q.n_classes, t.n_classes)
    cand, _ = match_descriptors(
        desc(q, n_classes, rng), desc(t, n_classes, rng), q.labels, t.labels, matching
    )
    return cand


def _moved_sets(
    family: str,
    q: SemanticGraph,
    t: SemanticGraph,
    T_t_q: np.ndarray,
    cand: np.ndarray,
    seeds: int,
    tau: float,
    threshold: float,
    correct_radius: float,
    success: tuple[float, float],
) -> Iterator[BenchSet]:
    src = q.positions[cand[:, 0]]
    dst0 = t.positions[cand[:, 1]]
    correct = np.linalg.norm(apply(T_t_q, src) - dst0, axis=1) < correct_radius
    for seed in range(seeds):
        T = random_rigid_transform(np.random.default_rng(1000 + seed))
        yield BenchSet(
            family, "real", seed, src, apply(T, dst0), T @ T_t_q, correct, tau, threshold,
            *success,
        )  # fmt: skip


def airsim_sets(seeds: int) -> Iterator[BenchSet]:
    d = data_path("airsim_guo")
    q, t = SemanticGraph.load(d / "cloud1.pcd"), SemanticGraph.load(d / "cloud2.pcd")
    cand = _candidates(q, t, MatchingConfig())
    # Success as the paper: translation error under 20 m (rotation is not bounded there).
    yield from _moved_sets(
        "airsim-guo", q, t, np.eye(4), cand, seeds, 5.0, 5.0, 10.0, (20.0, 180.0)
    )


def kitti_sets(seeds: int) -> Iterator[BenchSet]:
    """KITTI 00 two-robot maps (needs sgloc.datasets' kitti_objects and sgloc.extraction)."""
    from sgloc.datasets import make_dataset
    from sgloc.extraction import (
        build_graph,
        extraction_preset,
    )
    from sgloc.pipeline.presets import localizer_preset

    root = data_path("kitti00")
    a = make_dataset("kitti_objects", root, scans="0-800", start_frame=True)
    b = make_dataset("kitti_objects", root, scans="3900-4540", start_frame=True)
    a_w = make_dataset("kitti_objects", root, scans="0-800")
    b_w = make_dataset("kitti_objects", root, scans="3900-4540")
    T_a_b = np.linalg.inv(a_w.poses[0]) @ b_w.poses[0]
    cfg = extraction_preset("kitti-objects")
    ga, gb = build_graph(a, cfg), build_graph(b, cfg)
    lcfg = localizer_preset("kitti-objects")
    cand = _candidates(gb, ga, lcfg.matching)
    tau = float(lcfg.rejection_params.get("tau", 2.0))
    yield from _moved_sets(
        "kitti00", gb, ga, T_a_b, cand, seeds, tau, lcfg.ransac.threshold, 3.0, (3.0, 3.0)
    )


def synthetic_sets(
    sizes: dict[int, tuple[list[float], int]], kinds: tuple[str, ...] = ("random", "structured")
) -> Iterator[BenchSet]:
    """sizes: m -> (outlier ratios, seeds per ratio and kind)."""
    for m, (ratios, seeds) in sizes.items():
        for ratio in ratios:
            for kind in kinds:
                for seed in range(seeds):
                    rng = np.random.default_rng([m, int(ratio * 1000), seed, kind == "random"])
                    cs = make_correspondences(m, ratio, rng, kind)
                    yield BenchSet(
                        "synthetic", kind, seed, cs.src, cs.dst, cs.T_dst_src, cs.inlier,
                        5.0, 5.0, 2.0, 2.0,
                    )  # fmt: skip
