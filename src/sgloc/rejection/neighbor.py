"""Neighbor-constraint outlier rejection: the paper's Algorithm 1."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from sgloc.consistency.local import prune_local
from sgloc.consistency.pairwise import (
    ALL_PAIRS_LIMIT,
    consistency_bits,
    consistency_matrix,
    pack_rows,
)
from sgloc.rejection.base import Rejector
from sgloc.validation import MAX_COORDINATE, choice, real, setting

__all__ = [
    "NeighborRejector",
    "consistency_matrix",
    "prune_bits",
    "prune_by_support",
]


#: Alg. 1's removal bounds (see NeighborRejector).
BOUNDS = ("remaining", "literal")

#: Which pairs of candidates are checked (see NeighborRejector).
SCOPES = ("auto", "all", "local")


def prune_by_support(M: np.ndarray, eta: float, bound: str = "remaining") -> np.ndarray:
    """Alg. 1 step 2 on a consistency matrix M (m,m) bool with a False diagonal: the sorted
    indices of the survivors (compiled, `sgloc.rejection.prune_kernels`).

    bound="remaining": while the remaining match with the least support V_i (number of other
    remaining matches it agrees with; M_ii does not count) has V_i < eta * (r - 1), r the
    number of matches still remaining, remove it (ties: the lowest index). The bound shrinks
    with r: against the original m every match would end up removed. bound="literal" is
    described in NeighborRejector."""
    M = np.asarray(M)
    if M.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    M = M if M.dtype == np.bool_ else M != 0
    return prune_bits(pack_rows(M), M.sum(axis=1, dtype=np.int64), eta, bound)


def prune_bits(
    bits: np.ndarray, degree: np.ndarray, eta: float, bound: str = "remaining"
) -> np.ndarray:
    """`prune_by_support` on bit-packed rows and their counts (`consistency_bits` output)."""
    if bound not in BOUNDS:
        raise ValueError(f"unknown bound {bound!r}; use one of {BOUNDS}")
    m = len(degree)
    if bound == "remaining" or m == 0:
        return _prune_remaining(bits, degree, eta)
    # The literal bound: remove while 1 + V_i < eta * r (V_i without M_ii). The rule of
    # "remaining", V_i < eta * (r - 1), run with one extra match consistent with every match, is
    # exactly that: the extra one adds 1 to every support and to r, and, having the largest
    # possible support, is never removed before a real match (eta <= 1; ties go to the lower
    # index).
    n_words = (m + 1 + 63) // 64
    wide = np.zeros((m + 1, n_words), dtype=np.uint64)
    wide[:m, : bits.shape[1]] = bits
    wide[:m, m // 64] |= np.uint64(1) << np.uint64(m % 64)
    wide[m] = pack_rows(np.arange(m + 1)[None, :] < m)[0]
    support = np.append(np.asarray(degree, dtype=np.int64) + 1, m)
    kept = _prune_remaining(wide, support, eta)
    return kept[kept < m]


def _prune_remaining(bits: np.ndarray, degree: np.ndarray, eta: float) -> np.ndarray:
    """The "remaining" rule on packed rows (compiled)."""
    if len(bits) == 0:
        return np.zeros(0, dtype=np.int64)
    from sgloc.rejection.prune_kernels import prune_bits as kernel

    return kernel(bits, degree, float(eta))


@dataclass
class NeighborRejector(Rejector):
    """Reject matches whose geometric relations disagree between the two graphs (Alg. 1).

    tau: metres. For form="distance", the largest accepted difference of a pair's distances
        in the two graphs; for form="neighbor", the neighbour radius of Nei().
    eta: a match survives while it agrees with at least eta of the other remaining matches.
    form: "distance" (Alg. 1's pseudo-code, the default) or "neighbor" (Eq. 2-3).
    bound: when the least supported remaining match (ties: the lowest index) is removed, with
        r matches remaining and V_i the number of other remaining matches it agrees with:
        - "remaining" (the default): V_i < eta * (r - 1); a match does not vouch for itself.
        - "literal": 1 + V_i < eta * r, Alg. 1 as its pseudo-code reads: M_ii = 1 (a match's
          distances agree with themselves, |D - D| = 0 < tau), V = row sums of M, loop while
          V_i < 0.5 * rows of M_0, and M_0 loses a row per removal, so its rows are r.
        With eta = 0.5 the two differ only when r is even and the least support is
        V_i = r/2 - 1: "remaining" removes that match, "literal" stops there.
    scope: which pairs of candidates are checked.
        - "all": every pair (Alg. 1 as published; m^2 work, m^2 / 8 bytes; at most
          `sgloc.consistency.pairwise.MAX_MATCHES` candidates).
        - "local": only candidates whose query objects lie closer than `local_radius`
          (`sgloc.consistency.local`): r_i and V_i count the remaining candidates within the
          radius of i and those consistent with i; the least supported fraction V_i / r_i is
          removed first, while V_i < eta * r_i ("literal": 1 + V_i < eta * (1 + r_i)). Work
          grows with the candidates times those within the radius, memory with the
          candidates. A radius covering the whole query map gives the result of "all".
        - "auto" (the default): "all" up to `sgloc.consistency.pairwise.ALL_PAIRS_LIMIT` (10,000)
          candidates, "local" above (small problems keep the published form exactly).
    local_radius: metres, the neighbourhood of the "local" scope in the query map (the
        default descriptor's radius).
    """

    tau: float = setting(5.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    eta: float = setting(0.5, check=real(0.0, 1.0))
    form: Literal["distance", "neighbor"] = setting(
        "distance", check=choice("distance", "neighbor", what="the consistency form")
    )
    bound: Literal["remaining", "literal"] = setting(
        "remaining", check=choice("remaining", "literal", what="Alg. 1's removal bound")
    )
    scope: Literal["auto", "all", "local"] = setting(
        "auto", check=choice("auto", "all", "local", what="which pairs of candidates are checked")
    )
    local_radius: float = setting(40.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    name = "neighbor"

    def __call__(self, src, dst, scores=None):
        if len(src) == 0:
            return np.zeros(0, dtype=np.int64)
        if self.uses_local(len(src)):
            self_vote = 1 if self.bound == "literal" else 0
            return prune_local(
                src, dst, self.tau, self.eta, self.local_radius, self.form, self_vote
            )
        bits, degree = consistency_bits(src, dst, self.tau, self.form)
        return prune_bits(bits, degree, self.eta, self.bound)

    def uses_local(self, m: int) -> bool:
        """Whether `m` candidates are pruned within the local radius (scope, see above)."""
        return self.scope == "local" or (self.scope == "auto" and m > ALL_PAIRS_LIMIT)
