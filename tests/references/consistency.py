"""Numpy references of `sgloc.consistency.pairwise`'s kernels: the pairwise consistency matrix
tile by tile (float32 Gram products, the pairs near tau decided again in float64: equal to the dense
float64 computation), its consistent pairs and triangles, and the local (within a radius)
supports and pruning, dense m x m."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from sgloc.consistency.pairwise import check_form, unpack_rows
from sgloc.kernels import one_blas_thread

#: Side of the square tiles computed at once: 512 x 512 float32 = 1 MB per temporary (L2-sized).
TILE = 512

#: Bound, relative to R^2 (R the largest norm of a centred point set), on the float32 rounding
#: error of a squared distance from the 5-term Gram product: the inputs' rounding and a 5-term
#: dot product each cost at most a few units of 2^-24 times sum |a_k b_k| <= 4 R^2, i.e. about
#: 14 eps R^2 in all; twice that here for margin.
_GRAM_REL_ERROR = 32 * np.finfo(np.float32).eps


def _augmented(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(A, B, R) with A_i . B_j = |p_i - p_j|^2 (float32, centred) and R the largest norm."""
    p = points - points.mean(axis=0)
    n = np.einsum("ij,ij->i", p, p)
    ones = np.ones(len(p))
    A = np.column_stack([p, n, ones]).astype(np.float32)
    B = np.column_stack([-2.0 * p, ones, n]).astype(np.float32)
    return A, B, float(np.sqrt(n.max())) if len(n) else 0.0


def _exact_distances(columns: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Float64 |p_i - p_j| for index arrays i, j, summed in cdist's order; `columns` (3,m)."""
    x, y, z = columns
    dx, dy, dz = x[i] - x[j], y[i] - y[j], z[i] - z[j]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


def consistent_blocks(
    src: np.ndarray, dst: np.ndarray, tau: float, form: str = "distance"
) -> Iterator[tuple[slice, slice, np.ndarray, np.ndarray | None]]:
    """Yield (rows, cols, ok, diff) over square tiles of the upper triangle (cols.start >=
    rows.start), so that every unordered pair i != j is covered once (pairs within a diagonal
    tile appear twice, as (i,j) and (j,i), with equal values).

    ok (len(rows), len(cols)) bool: the pair is consistent, exact up to float64 rounding (equal
    to the dense float64 computation); diagonal entries i == j come as computed, callers clear
    them.
    diff (same shape) float32: |D(src_i,src_j) - D(dst_i,dst_j)| in metres, approximate (within
    ~2e-3 of the point sets' extent), for soft affinities; None for form "neighbor".
    form "distance": ok = diff < tau (Alg. 1); "neighbor": ok = (D_src < tau) == (D_dst < tau).
    """
    check_form(form)
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    m = len(src)
    if m == 0:
        return
    cols_s, cols_t = np.ascontiguousarray(src.T), np.ascontiguousarray(dst.T)
    As, Bs, Rs = _augmented(src)
    At, Bt, Rt = _augmented(dst)
    # |sqrt(a) - sqrt(b)| <= sqrt(|a - b|): each distance is off by at most sqrt(err).
    err_s = float(np.sqrt(_GRAM_REL_ERROR)) * Rs + 1e-6
    err_t = float(np.sqrt(_GRAM_REL_ERROR)) * Rt + 1e-6
    for i0 in range(0, m, TILE):
        rows = slice(i0, min(m, i0 + TILE))
        for j0 in range(i0, m, TILE):
            cols = slice(j0, min(m, j0 + TILE))
            dq = _tile_distances(As, Bs, rows, cols)
            dt = _tile_distances(At, Bt, rows, cols)
            ok, diff, amb = _classify_tile(dq, dt, form, tau, err_s, err_t)
            _recheck_ambiguous(ok, diff, amb, rows, cols, cols_s, cols_t, tau)
            yield rows, cols, ok, diff


def _tile_distances(A: np.ndarray, B: np.ndarray, rows: slice, cols: slice) -> np.ndarray:
    """Float32 (len(rows), len(cols)) distances of one tile from the augmented Gram factors."""
    with one_blas_thread():  # (512 x 5 products: a second thread only waits)
        d = A[rows] @ B[cols].T
    np.maximum(d, 0.0, out=d)  # rounding can make a tiny square negative
    np.sqrt(d, out=d)
    return d


def _classify_tile(
    dq: np.ndarray, dt: np.ndarray, form: str, tau: float, err_s: float, err_t: float
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """(ok, diff, amb) of one tile from its float32 distances (overwritten): the float32
    decision, |dq - dt| for form "distance" (None otherwise), and the pairs too close to tau
    (within the error bounds err_s, err_t, metres) to be sure of."""
    tau32 = np.float32(tau)
    if form == "distance":
        diff = np.subtract(dq, dt, out=dq)
        np.abs(diff, out=diff)
        np.subtract(diff, tau32, out=dt)  # dt now holds diff - tau
        ok = dt < 0
        np.abs(dt, out=dt)
        amb = dt < np.float32(err_s + err_t)  # not certainly on one side of tau
        return ok, diff, amb
    ok = (dq < tau32) == (dt < tau32)
    np.subtract(dq, tau32, out=dq)
    np.abs(dq, out=dq)
    amb = dq < np.float32(err_s)
    np.subtract(dt, tau32, out=dt)
    np.abs(dt, out=dt)
    amb |= dt < np.float32(err_t)
    return ok, None, amb


def _recheck_ambiguous(
    ok: np.ndarray,
    diff: np.ndarray | None,
    amb: np.ndarray,
    rows: slice,
    cols: slice,
    cols_s: np.ndarray,
    cols_t: np.ndarray,
    tau: float,
) -> None:
    """Recompute the tile's ambiguous pairs in float64, in place in ok (and diff)."""
    flat = np.flatnonzero(amb)
    if not len(flat):
        return
    bi, bj = np.divmod(flat, cols.stop - cols.start)
    gi, gj = bi + rows.start, bj + cols.start
    eq = _exact_distances(cols_s, gi, gj)
    et = _exact_distances(cols_t, gi, gj)
    if diff is not None:
        ok.ravel()[flat] = np.abs(eq - et) < tau
        diff.ravel()[flat] = np.abs(eq - et)
    else:
        ok.ravel()[flat] = (eq < tau) == (et < tau)


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
