"""Spectral outlier rejection (Leordeanu and Hebert, ICCV 2005), on pairwise distance consistency.

The matches form a graph whose edge weights say how well two matches agree on their pair's
distance: A_ij = exp(-(D(q_i,q_j) - D(t_i,t_j))^2 / (2 sigma^2)) when the difference is below
tau, else 0 (A_ii = 1). The correct matches form a strongly connected cluster, which the leading
eigenvector of A picks out (large entries). Matches are then accepted greedily by decreasing
entry, skipping any that disagrees (difference >= tau) with too many already accepted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.consistency.pairwise import consistency_bits
from sgloc.rejection.base import Rejector
from sgloc.validation import MAX_COORDINATE, real, setting


@dataclass
class SpectralRejector(Rejector):
    """Leading-eigenvector (spectral matching) rejection of inconsistent matches.

    tau: metres; pairs whose distances differ by tau or more get no affinity and count as
        disagreeing in the greedy selection.
    sigma: metres, width of the Gaussian affinity on the distance difference.
    min_ratio: stop the greedy selection when the eigenvector entry drops below this fraction
        of the largest one.
    min_agreement: a match is accepted when it agrees with at least this fraction of the matches
        accepted before it (1.0: with all of them, the classic mutual consistency).
    """

    tau: float = setting(5.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    sigma: float = setting(2.5, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    min_ratio: float = setting(0.1, check=real(0.0, 1.0))
    min_agreement: float = setting(0.9, check=real(0.0, 1.0))
    name = "spectral"

    def __call__(self, src, dst, scores=None):
        """Compiled (`sgloc.rejection.spectral_kernels`): float64 affinities as CSR rows from the
        packed consistency rows, power iteration, greedy selection on the packed rows."""
        if len(src) == 0:
            return np.zeros(0, dtype=np.int64)
        from sgloc.rejection import spectral_kernels as kernels

        src = np.ascontiguousarray(src, dtype=np.float64)
        dst = np.ascontiguousarray(dst, dtype=np.float64)
        bits, degree = consistency_bits(src, dst, self.tau, "distance")
        csr = kernels.affinity_csr(src, dst, bits, degree, float(self.sigma))
        x = kernels.leading_eigenvector(*csr, 200, 1e-6)
        order = np.argsort(-x, kind="stable")
        return kernels.greedy_select(x, order, bits, self.min_ratio, self.min_agreement)
