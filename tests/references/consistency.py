"""Numpy references of `sgloc.consistency`'s kernels: the pairwise consistency matrix tile by
tile, its consistent pairs and triangles, and the local (within a radius) supports and pruning,
dense m x m."""

from __future__ import annotations

import numpy as np

from sgloc.consistency.pairwise import consistent_blocks, unpack_rows


def consistency_bool(
    src: np.ndarray, dst: np.ndarray, tau: float, form: str = "distance"
) -> np.ndarray:
    """(m,m) bool consistency matrix (symmetric, diagonal False), filled tile by tile in numpy
    (the reference of `sgloc.consistency.pairwise.consistency_matrix`)."""
    m = len(src)
    M = np.empty((m, m), dtype=bool)
    for rows, cols, ok, _ in consistent_blocks(src, dst, tau, form):
        M[rows, cols] = ok
        M[cols, rows] = ok.T
    np.fill_diagonal(M, False)
    return M


def consistency_bits(
    src: np.ndarray, dst: np.ndarray, tau: float, form: str = "distance"
) -> tuple[np.ndarray, np.ndarray]:
    """`sgloc.consistency.pairwise.consistency_bits` from `consistency_bool`."""
    from sgloc.consistency.pairwise import pack_rows

    M = consistency_bool(src, dst, tau, form)
    return pack_rows(M), M.sum(axis=1, dtype=np.int64)


def upper_pairs(bits: np.ndarray, keep: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """np.nonzero(np.triu(M)) of the unpacked rows, both ends in `keep` (default all): the
    reference of `consistent_pairs` and `ConsistentPairs`."""
    keep = np.ones(len(bits), dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    M = unpack_rows(bits, len(bits)) & keep[None, :] & keep[:, None]
    ii, jj = np.nonzero(np.triu(M, 1))
    return ii.astype(np.int64), jj.astype(np.int64)


def common_partner_count(bits: np.ndarray, ii: np.ndarray, jj: np.ndarray) -> int:
    """`sgloc.consistency.pairwise.common_partner_count` on the unpacked rows."""
    M = unpack_rows(bits, bits.shape[1] * 64)
    return int(np.count_nonzero(M[np.asarray(ii)] & M[np.asarray(jj)]))


def _neighbours(src: np.ndarray, radius: float) -> np.ndarray:
    """(m,m) bool: query points closer than `radius` (float64 as cdist), no diagonal."""
    from scipy.spatial.distance import cdist

    near = cdist(src, src) < radius
    np.fill_diagonal(near, False)
    return near


def local_counts(
    src: np.ndarray, dst: np.ndarray, tau: float, radius: float, form: str = "distance"
) -> tuple[np.ndarray, np.ndarray]:
    """`sgloc.consistency.local.local_counts` in numpy (dense m x m)."""
    src = np.asarray(src, dtype=np.float64)
    near = _neighbours(src, radius)
    ok = consistency_bool(src, dst, tau, form) & near
    return near.sum(axis=1, dtype=np.int64), ok.sum(axis=1, dtype=np.int64)


def prune_local(
    src: np.ndarray,
    dst: np.ndarray,
    tau: float,
    eta: float,
    radius: float,
    form: str = "distance",
    self_vote: int = 0,
) -> np.ndarray:
    """`sgloc.consistency.local.prune_local` in numpy (dense m x m, one removal per step)."""
    src = np.asarray(src, dtype=np.float64)
    if len(src) == 0:
        return np.zeros(0, dtype=np.int64)
    near = _neighbours(src, radius)
    ok = consistency_bool(src, dst, tau, form) & near
    r = near.sum(axis=1).astype(np.int64)
    V = ok.sum(axis=1).astype(np.int64)
    alive = np.ones(len(src), dtype=bool)
    s = int(self_vote)
    while alive.any():
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.where(r + s > 0, (V + s) / (r + s), np.inf)
        frac[~alive] = np.nan
        i = int(np.nanargmin(frac))  # the first of equal minima: the lowest index
        if not V[i] + s < eta * (r[i] + s):
            break
        alive[i] = False
        hit = near[i] & alive
        r[hit] -= 1
        V[ok[i] & alive] -= 1
    return np.flatnonzero(alive).astype(np.int64)
