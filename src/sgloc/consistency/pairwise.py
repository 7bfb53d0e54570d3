"""Pairwise consistency of two match sets: the graph behind rejection and acceptance.

Two matches i, j (src_i <-> dst_i, src_j <-> dst_j) are consistent when the rigid motion that
maps one graph onto the other could preserve their relation:
- form "distance" (Alg. 1): |D(q_i,q_j) - D(t_i,t_j)| < tau;
- form "neighbor" (Eq. 2-3): (D(q_i,q_j) < tau) == (D(t_i,t_j) < tau).
Every decision equals the dense float64 computation (`scipy.spatial.distance.cdist`).

`consistency_bits` / `consistency_matrix` run the compiled one-pass kernel
(`sgloc.consistency.pairwise_kernels`): bit-packed rows, m^2 / 8 bytes. `consistent_blocks` is the
plain numpy computation, tile by tile (float32 Gram products with an exact float64 recheck near
tau): it yields the distance differences (the spectral rejector's affinities). The dense numpy
references the kernels are checked against live with the tests (`tests/references/`).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from sgloc.errors import TooManyMatchesError, UnknownNameError
from sgloc.kernels import one_blas_thread

#: Most matches the all-pairs consistency pass takes: its packed rows hold m^2 / 8 bytes
#: (2.8 GB here), beside the two graphs. The default settings never reach it: above
#: ALL_PAIRS_LIMIT candidates they check pairs within a radius (`sgloc.consistency.local`).
MAX_MATCHES = 150_000

#: Candidate counts up to which the default settings check all pairs (the neighbor rejector's
#: scope "auto", the acceptance test's hypothesis count); above, only pairs within a radius
#: (`sgloc.consistency.local`) or a random sample of pairs: 12.5 MB of packed rows at this size.
ALL_PAIRS_LIMIT = 10_000

#: Side of the square tiles computed at once: 512 x 512 float32 = 1 MB per temporary (L2-sized).
TILE = 512

#: Bound, relative to R^2 (R the largest norm of a centred point set), on the float32 rounding
#: error of a squared distance from the 5-term Gram product: the inputs' rounding and a 5-term
#: dot product each cost at most a few units of 2^-24 times sum |a_k b_k| <= 4 R^2, i.e. about
#: 14 eps R^2 in all; twice that here for margin.
_GRAM_REL_ERROR = 32 * np.finfo(np.float32).eps

FORMS = ("distance", "neighbor")


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


def check_form(form: str) -> None:
    """Raise UnknownNameError unless `form` is a consistency form."""
    if form not in FORMS:
        raise UnknownNameError(f"unknown consistency form {form!r}; use 'distance' or 'neighbor'.")


def consistency_bits(
    src: np.ndarray, dst: np.ndarray, tau: float, form: str = "distance"
) -> tuple[np.ndarray, np.ndarray]:
    """(bits, degree): bit-packed consistency rows (m, ceil(m/64)) uint64 (bit j % 64 of word
    j // 64 of row i: matches i != j consistent) and each match's count of consistent partners
    (m,) int64. src, dst: (m,3) metres. Compiled, one pass over the pairs."""
    check_form(form)
    check_match_count(len(src))
    if len(src) == 0:
        return np.zeros((0, 0), dtype=np.uint64), np.zeros(0, dtype=np.int64)
    from sgloc.consistency.pairwise_kernels import consistency_bits as kernel

    src = np.ascontiguousarray(src, dtype=np.float64)
    dst = np.ascontiguousarray(dst, dtype=np.float64)
    return kernel(src, dst, float(tau), form == "neighbor")


def check_match_count(m: int) -> None:
    """TooManyMatchesError when m matches exceed MAX_MATCHES (the packed rows' memory)."""
    if m > MAX_MATCHES:
        raise TooManyMatchesError(
            f"{m:,} matches are too many for the pairwise consistency check (it would need "
            f"{m * m / 8e9:.1f} GB; at most {MAX_MATCHES:,}): keep fewer candidates (lower "
            "top_k or max_candidates, or raise min_similarity), pass fewer correspondences, "
            "or use the neighbor rejector's local scope (scope='local')."
        )


def pack_rows(M: np.ndarray) -> np.ndarray:
    """Bool (n,m) rows as uint64 words (n, ceil(m/64)), the layout of `consistency_bits`."""
    n, m = M.shape
    packed = np.packbits(M, axis=1, bitorder="little")
    out = np.zeros((n, 8 * ((m + 63) // 64)), dtype=np.uint8)
    out[:, : packed.shape[1]] = packed
    return out.view("<u8").astype(np.uint64, copy=False)


def unpack_rows(bits: np.ndarray, m: int) -> np.ndarray:
    """Bool (n,m) from uint64 rows (n, ceil(m/64)) (the inverse of `pack_rows`)."""
    as_bytes = np.ascontiguousarray(bits).astype("<u8", copy=False).view(np.uint8)
    return np.unpackbits(as_bytes, axis=1, count=m, bitorder="little").view(bool)


def consistency_matrix(
    src: np.ndarray, dst: np.ndarray, tau: float, form: str = "distance"
) -> np.ndarray:
    """(m,m) bool pairwise consistency of matches (symmetric, diagonal False); see the module
    docstring for the forms. Compiled; m^2 bytes."""
    bits, _ = consistency_bits(src, dst, tau, form)
    return unpack_rows(bits, len(src))


def consistent_pairs(bits: np.ndarray, degree: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ii, jj) int64: every consistent pair with ii < jj, row-major (np.nonzero(np.triu(M)))
    from packed rows and degrees (`consistency_bits`). Compiled."""
    if len(bits) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    from sgloc.consistency.triangle_kernels import upper_edges

    return upper_edges(bits, np.asarray(degree, dtype=np.int64))


def common_partner_count(bits: np.ndarray, ii: np.ndarray, jj: np.ndarray) -> int:
    """Sum over the pairs (ii[k], jj[k]) of the number of matches consistent with both; over all
    consistent pairs i < j it is 3 x the number of triangles of the consistency graph."""
    if len(bits) == 0:
        return 0
    from sgloc.consistency.triangle_kernels import common_counts

    return int(common_counts(bits, np.asarray(ii, dtype=np.int64), np.asarray(jj, dtype=np.int64)))


class ConsistentPairs:
    """The consistent pairs i < j of packed rows (`consistency_bits`), in row-major order (that
    of np.nonzero(np.triu(M))), without listing them: m words of bookkeeping instead of 16
    bytes per pair (a large candidate set has tens of millions of pairs). Compiled.

    size: the number of pairs; `at(k)`: (ii, jj) of the pairs at positions k; `within(keep)`:
    the pairs whose both matches are kept (same order); `all()`: every pair."""

    def __init__(self, bits: np.ndarray, keep: np.ndarray | None = None) -> None:
        m = bits.shape[0]
        self.bits = bits
        self.keep = np.ones(m, dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
        if m == 0:  # no matches, no pairs
            self.size = 0
            return
        from sgloc.consistency.triangle_kernels import kept_starts

        # The kept columns as one packed row, and the row-major position of each row's first
        # pair.
        self._keep_words, self.row_start = kept_starts(bits, self.keep)
        self.size = int(self.row_start[-1])

    def at(self, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ii, jj) int64 of the pairs at positions k (any order, repeats allowed; 0 <= k <
        size)."""
        k = np.asarray(k, dtype=np.int64).ravel()
        if k.size and (k.min() < 0 or k.max() >= self.size):
            raise IndexError(f"pair positions must lie in [0, {self.size})")
        if self.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        from sgloc.consistency.triangle_kernels import edges_at

        order = np.argsort(k, kind="stable")
        ii, jj = edges_at(self.bits, self._keep_words, self.row_start, k[order])
        out_i, out_j = np.empty_like(ii), np.empty_like(jj)
        out_i[order], out_j[order] = ii, jj
        return out_i, out_j

    def within(self, keep: np.ndarray) -> ConsistentPairs:
        """The pairs whose both matches are in the bool mask `keep` (m,)."""
        return ConsistentPairs(self.bits, self.keep & np.asarray(keep, dtype=bool))

    def all(self) -> tuple[np.ndarray, np.ndarray]:
        """Every pair: `consistent_pairs` (16 bytes per pair)."""
        return self.at(np.arange(self.size))

