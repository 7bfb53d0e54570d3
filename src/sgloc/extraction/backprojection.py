"""Back-projection of image regions to 3D vertex positions (sensor frame, then map frame)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from sgloc.errors import SglocError
from sgloc.extraction.segmentation import Segmentation
from sgloc.geometry import apply


def backproject_pixels(u: np.ndarray, v: np.ndarray, d: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(n,3) optical-frame points (x right, y down, z forward; metres) of pixels (u, v) at
    planar depth d: ((u - cx) / fx * d, (v - cy) / fy * d, d)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return np.stack([(u - cx) / fx * d, (v - cy) / fy * d, d], axis=-1)


def region_positions(
    seg: Segmentation, depth: np.ndarray, K: np.ndarray, position: str = "mean"
) -> np.ndarray:
    """(r,3) one point per region in the camera's optical frame (metres).

    position="mean": mean of the region's back-projected 3D points (Guo).
    position="centre": the region's 2D pixel centroid back-projected at its median depth.
    """
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise SglocError(f"intrinsics K must be a 3x3 pinhole matrix with fx, fy > 0, got {K}.")
    r = len(seg)
    if r == 0:
        return np.zeros((0, 3))
    rm = seg.region_map
    H, W = rm.shape
    v, u = np.nonzero(rm >= 0)
    ids = rm[v, u]
    d = np.asarray(depth, dtype=np.float64)[v, u]
    n = np.bincount(ids, minlength=r).astype(np.float64)
    if position == "mean":
        # mean of ((u-cx)/fx d, (v-cy)/fy d, d) from three weighted sums, no (n,3) array
        sd = np.bincount(ids, d, minlength=r)
        sud = np.bincount(ids, u * d, minlength=r)
        svd = np.bincount(ids, v * d, minlength=r)
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        return np.stack([(sud - cx * sd) / fx, (svd - cy * sd) / fy, sd], axis=1) / n[:, None]
    if position == "centre":
        uc = np.bincount(ids, u, minlength=r) / n
        vc = np.bincount(ids, v, minlength=r) / n
        dm = ndimage.median(d, labels=ids + 1, index=np.arange(1, r + 1))
        return backproject_pixels(uc, vc, np.asarray(dm, dtype=np.float64), K)
    raise SglocError(f"unknown position rule {position!r}; use 'mean' or 'centre'.")


def to_map(points_sensor: np.ndarray, T_map_sensor: np.ndarray) -> np.ndarray:
    """(n,3) sensor-frame points -> map frame with the 4x4 pose T_map_sensor."""
    return apply(np.asarray(T_map_sensor, dtype=np.float64), np.asarray(points_sensor))
