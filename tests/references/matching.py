"""Numpy reference of the matching kernel (`sgloc.matching.similarity_kernels`): the same-class
top-k candidates by block products in numpy, the path sparse descriptors take."""

from __future__ import annotations

import numpy as np
from scipy import sparse

from sgloc.matching import candidates
from sgloc.matching.candidates import MatchingConfig


def match_flagged(
    desc_q, desc_t, labels_q: np.ndarray, labels_t: np.ndarray, config: MatchingConfig,
    flag_ratio: float | None = None,
) -> tuple[np.ndarray, ...]:  # fmt: skip
    """`sgloc.matching.candidates.match_flagged` by the numpy block products: the descriptors
    handed over as sparse rows (the same values), which the kernel does not take."""
    as_rows = (sparse.csr_array(np.asarray(d, dtype=np.float64)) for d in (desc_q, desc_t))
    return candidates.match_flagged(*as_rows, labels_q, labels_t, config, flag_ratio)
