"""Neighbor-constraint outlier rejection: the paper's Algorithm 1."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial.distance import cdist

from sgloc.rejection.base import Rejector


def consistency_matrix(
    src: np.ndarray, dst: np.ndarray, tau: float, form: str = "distance"
) -> np.ndarray:
    """(m,m) bool pairwise consistency of matches, diagonal False.

    form="distance" (Alg. 1): M_ij = |D(q_i,q_j) - D(t_i,t_j)| < tau.
    form="neighbor" (Eq. 2-3): M_ij = Nei(q_i,q_j) == Nei(t_i,t_j), Nei = distance < tau.
    """
    dq, dt = cdist(src, src), cdist(dst, dst)
    if form == "distance":
        M = np.abs(dq - dt) < tau
    elif form == "neighbor":
        M = (dq < tau) == (dt < tau)
    else:
        raise ValueError(f"unknown consistency form {form!r}; use 'distance' or 'neighbor'")
    np.fill_diagonal(M, False)
    return M


def prune_by_support(M: np.ndarray, eta: float) -> np.ndarray:
    """Alg. 1 step 2 on a consistency matrix M (m,m) with a False diagonal.

    While the remaining match with the least support V_i (number of other remaining matches it
    agrees with) has V_i < eta * (r - 1), r the number of matches still remaining, remove it and
    update V -= M[i] (O(m) per removal). Returns the sorted indices of the survivors.

    The bound shrinks with r: against the original m every match ends up removed (PAPER.md).
    M_ii does not count: a match does not vouch for itself, so V_i ranges over 0..r-1.
    """
    m = M.shape[0]
    if m == 0:
        return np.zeros(0, dtype=np.int64)
    V = M.sum(axis=1, dtype=np.int64).astype(np.float64)
    alive = np.ones(m, dtype=bool)
    r = m
    while r > 1:
        i = int(np.argmin(V))
        if V[i] >= eta * (r - 1):
            break
        V -= M[i]
        V[i] = np.inf
        alive[i] = False
        r -= 1
    return np.flatnonzero(alive)


@dataclass
class NeighborRejector(Rejector):
    """Reject matches whose geometric relations disagree between the two graphs (Alg. 1).

    tau: metres. For form="distance", the largest accepted difference of a pair's distances
        in the two graphs; for form="neighbor", the neighbour radius of Nei().
    eta: a match survives while it agrees with at least eta of the other remaining matches.
    form: "distance" (Alg. 1's pseudo-code, the default) or "neighbor" (Eq. 2-3).
    """

    tau: float = 5.0
    eta: float = 0.5
    form: Literal["distance", "neighbor"] = "distance"
    name = "neighbor"

    def __call__(self, src, dst, scores=None):
        if len(src) == 0:
            return np.zeros(0, dtype=np.int64)
        return prune_by_support(consistency_matrix(src, dst, self.tau, self.form), self.eta)
