"""Pairwise consistency of two match sets: the graph behind rejection and acceptance.

Two matches i, j (src_i <-> dst_i, src_j <-> dst_j) are consistent when the rigid motion that
maps one graph onto the other could preserve their relation:
- form "distance" (Alg. 1): |D(q_i,q_j) - D(t_i,t_j)| < tau;
- form "neighbor" (Eq. 2-3): (D(q_i,q_j) < tau) == (D(t_i,t_j) < tau).
Every decision equals the dense float64 computation (`scipy.spatial.distance.cdist`).

`consistency_bits` / `consistency_matrix` run the compiled one-pass kernel
(`sgloc.consistency.pairwise_kernels`): bit-packed rows, m^2 / 8 bytes. The numpy references the
kernels are checked against (float32 Gram tiles with an exact float64 recheck near tau) live
with the tests (`tests/references/`).
"""

from __future__ import annotations

import numpy as np

from sgloc.errors import TooManyMatchesError, UnknownNameError

#: Most matches the all-pairs consistency pass takes: its packed rows hold m^2 / 8 bytes
#: (2.8 GB here), beside the two graphs. The default settings never reach it: above
#: ALL_PAIRS_LIMIT candidates they check pairs within a radius (`sgloc.consistency.local`).
MAX_MATCHES = 150_000

#: Candidate counts up to which the default settings check all pairs (the neighbor rejector's
#: scope "auto", the acceptance test's hypothesis count); above, only pairs within a radius
#: (`sgloc.consistency.local`) or a random sample of pairs: 12.5 MB of packed rows at this size.
ALL_PAIRS_LIMIT = 10_000

FORMS = ("distance", "neighbor")


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
            "or use the neighbor rejector's local scope (--set scope=local; Python: scope='local')."
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

