"""Outlier rejectors by name: `neighbor` (the paper), `none` (baseline), `spectral`, `clique`."""

from __future__ import annotations

from typing import Any

from sgloc.registry import Registry
from sgloc.rejection.base import NoRejection, Rejector
from sgloc.rejection.clique import CliqueRejector
from sgloc.rejection.neighbor import NeighborRejector, consistency_matrix, prune_by_support
from sgloc.rejection.spectral import SpectralRejector

REJECTORS: Registry[type[Rejector]] = Registry(
    "rejection",
    {
        "none": NoRejection,
        "neighbor": NeighborRejector,
        "spectral": SpectralRejector,
        "clique": CliqueRejector,
    },
)


def make_rejector(name: str | Rejector, **params: Any) -> Rejector:
    """A rejector by name with optional parameters."""
    if isinstance(name, Rejector):
        return name
    return REJECTORS.lookup(name)(**params)


__all__ = [
    "REJECTORS",
    "CliqueRejector",
    "NeighborRejector",
    "NoRejection",
    "Rejector",
    "SpectralRejector",
    "consistency_matrix",
    "make_rejector",
    "prune_by_support",
]
