"""Fast descriptor (Stumm et al. 2016 as Guo implements it, without Guo's label/bin bug)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.descriptors.base import Descriptor, one_hot
from sgloc.maps.graph import SemanticGraph


@dataclass
class FastDescriptor(Descriptor):
    """Histogram of the direct neighbours' class labels (L bins, raw counts)."""

    name = "fast"

    def __call__(self, graph: SemanticGraph, n_classes: int, rng: np.random.Generator):
        return (graph.adjacency @ one_hot(graph.labels, n_classes)).toarray()
