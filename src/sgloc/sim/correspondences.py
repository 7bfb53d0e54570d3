"""Synthetic correspondence sets with known inliers, for rejector tests and benchmarks.

A set holds m candidate matches src[i] (query frame) <-> dst[i] (target frame). Inliers obey the
ground-truth motion T_dst_src up to Gaussian noise. Outliers come two ways:
- random: dst is an unrelated point of the target's area (what wrong descriptor matches give);
- structured: groups of outliers that follow a second rigid motion of their own (each group is
  a shifted, turned copy of the true motion), so they agree with each other in every pairwise
  distance, as repeated city objects (rows of poles, trees, parked cars) produce.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from sgloc.errors import SglocError
from sgloc.geometry import apply, make_transform, random_rigid_transform


@dataclass
class CorrespondenceSet:
    """m candidate matches with ground truth.

    src, dst: (m,3) metres, query and target frames; match i is src[i] <-> dst[i].
    inlier: (m,) bool, True for the matches that obey T_dst_src.
    group: (m,) int, 0 for inliers, -1 for random outliers, k >= 1 for structured group k.
    T_dst_src: (4,4) ground truth; noise: inlier noise std (metres).
    """

    src: np.ndarray
    dst: np.ndarray
    inlier: np.ndarray
    group: np.ndarray
    T_dst_src: np.ndarray
    noise: float
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.src)

    @property
    def outlier_ratio(self) -> float:
        return float(1.0 - self.inlier.mean()) if len(self) else 0.0


def make_correspondences(
    m: int,
    outlier_ratio: float,
    rng: np.random.Generator,
    outliers: Literal["random", "structured"] = "random",
    noise: float = 0.5,
    extent: float = 200.0,
    height: float = 5.0,
    group_ratio: float = 0.5,
    n_groups: int = 3,
    min_shift: float = 25.0,
    T_dst_src: np.ndarray | None = None,
) -> CorrespondenceSet:
    """A shuffled set of m matches with round(m * outlier_ratio) outliers.

    Query points are uniform in an extent x extent x height box (metres; a flat city).
    outliers="structured": `n_groups` groups of round(group_ratio * n_inliers) outliers each
    (fewer if there are not enough outliers) follow the motion T_dst_src @ S_k, S_k a random
    turn about z and a shift of at least `min_shift` metres; the remaining outliers are random.
    group_ratio < 1 keeps the true motion the largest consistent set (otherwise no method
    can tell it from a decoy).
    """
    if m < 0 or not 0.0 <= outlier_ratio <= 1.0:
        raise SglocError(f"need m >= 0 and 0 <= outlier_ratio <= 1, got {m} and {outlier_ratio}.")
    if outliers not in ("random", "structured"):
        raise SglocError(f"outliers must be 'random' or 'structured', got {outliers!r}.")
    T = random_rigid_transform(rng) if T_dst_src is None else np.asarray(T_dst_src, float)
    n_out = int(round(m * outlier_ratio))
    n_in = m - n_out
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([extent, extent, height])
    src = rng.uniform(lo, hi, (m, 3))
    dst = np.empty((m, 3))
    group = np.full(m, -1, dtype=np.int64)
    group[:n_in] = 0
    dst[:n_in] = apply(T, src[:n_in]) + rng.normal(0.0, noise, (n_in, 3))
    start = n_in
    if outliers == "structured":
        size = max(int(round(group_ratio * n_in)), 3)
        start = _structured_groups(src, dst, group, T, rng, start, size, n_groups, noise, min_shift)
    # Random outliers: an unrelated point of the target's area.
    dst[start:] = apply(T, rng.uniform(lo, hi, (m - start, 3)))
    order = rng.permutation(m)
    return CorrespondenceSet(
        src=src[order],
        dst=dst[order],
        inlier=(group == 0)[order],
        group=group[order],
        T_dst_src=T,
        noise=noise,
        meta={"m": m, "outlier_ratio": outlier_ratio, "outliers": outliers, "extent": extent},
    )


def _structured_groups(
    src: np.ndarray,
    dst: np.ndarray,
    group: np.ndarray,
    T: np.ndarray,
    rng: np.random.Generator,
    start: int,
    size: int,
    n_groups: int,
    noise: float,
    min_shift: float,
) -> int:
    """Fill dst and group (in place) from row `start` with up to `n_groups` groups of `size`
    outliers, group k following T @ S_k (S_k a random turn about z and a shift of
    min_shift..2 min_shift metres) plus noise; return the first row left for random outliers."""
    m = len(src)
    for k in range(1, n_groups + 1):
        end = min(start + size, m)
        if end - start < 3:
            break
        angle = rng.uniform(-np.pi, np.pi)
        direction = rng.normal(size=2)
        shift = direction / np.linalg.norm(direction) * rng.uniform(min_shift, 2 * min_shift)
        S = make_transform(Rotation.from_euler("z", angle).as_matrix(), np.array([*shift, 0.0]))
        dst[start:end] = apply(T @ S, src[start:end]) + rng.normal(0, noise, (end - start, 3))
        group[start:end] = k
        start = end
    return start
