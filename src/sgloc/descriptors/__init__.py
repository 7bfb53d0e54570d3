"""Vertex descriptors by name: `histogram`, `random_walk`, `fast`."""

from __future__ import annotations

from typing import Any

from sgloc.descriptors.base import Descriptor, DescriptorMatrix
from sgloc.descriptors.fast import FastDescriptor
from sgloc.descriptors.histogram import HistogramDescriptor
from sgloc.descriptors.random_walk import RandomWalkDescriptor
from sgloc.registry import lookup

DESCRIPTORS: dict[str, type[Descriptor]] = {
    "histogram": HistogramDescriptor,
    "random_walk": RandomWalkDescriptor,
    "fast": FastDescriptor,
}


def make_descriptor(name: str | Descriptor, **params: Any) -> Descriptor:
    """A descriptor by name (`histogram`, `random_walk`, `fast`) with optional parameters."""
    if isinstance(name, Descriptor):
        return name
    return lookup(DESCRIPTORS, name, "descriptor")(**params)


__all__ = [
    "DESCRIPTORS",
    "Descriptor",
    "DescriptorMatrix",
    "FastDescriptor",
    "HistogramDescriptor",
    "RandomWalkDescriptor",
    "make_descriptor",
]
