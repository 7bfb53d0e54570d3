"""What every vertex descriptor is: a callable graph -> (n, d) matrix, one row per vertex."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from sgloc.maps.graph import SemanticGraph
from sgloc.validation import validate_settings

DescriptorMatrix = np.ndarray | sparse.csr_array


@dataclass
class Descriptor:
    """Base class. Subclasses are dataclasses of their parameters and implement `__call__`.

    `__call__(graph, n_classes, rng)` returns an (n, d) matrix (dense or CSR) whose rows are the
    vertices' descriptors; an all-zero row means "no descriptor" and is never matched.
    `n_classes` must be the same for the two graphs that will be compared.
    """

    name = "base"

    def __post_init__(self) -> None:
        validate_settings(self)  # type, range, finiteness of every field (sgloc.validation)

    def __call__(
        self, graph: SemanticGraph, n_classes: int, rng: np.random.Generator
    ) -> DescriptorMatrix:
        raise NotImplementedError


def one_hot(labels: np.ndarray, n_classes: int) -> sparse.csr_array:
    """(n, n_classes) sparse one-hot matrix of class ids."""
    n = labels.shape[0]
    return sparse.csr_array((np.ones(n), (np.arange(n), labels)), shape=(n, n_classes))
