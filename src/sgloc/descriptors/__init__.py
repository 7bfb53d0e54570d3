"""Vertex descriptors by name: `histogram`, `random_walk`, `fast`, `distance_histogram`,
`triangles`."""

from __future__ import annotations

from typing import Any

from sgloc.descriptors.base import Descriptor, DescriptorMatrix
from sgloc.descriptors.distance import DistanceHistogramDescriptor, TriangleDescriptor
from sgloc.descriptors.fast import FastDescriptor
from sgloc.descriptors.histogram import HistogramDescriptor
from sgloc.descriptors.random_walk import RandomWalkDescriptor
from sgloc.registry import Registry

DESCRIPTORS: Registry[type[Descriptor]] = Registry(
    "descriptor",
    {
        "histogram": HistogramDescriptor,
        "random_walk": RandomWalkDescriptor,
        "fast": FastDescriptor,
        "distance_histogram": DistanceHistogramDescriptor,
        "triangles": TriangleDescriptor,
    },
)


def make_descriptor(name: str | Descriptor, **params: Any) -> Descriptor:
    """A descriptor by name (see DESCRIPTORS) with optional parameters."""
    if isinstance(name, Descriptor):
        return name
    return DESCRIPTORS.lookup(name)(**params)


__all__ = [
    "DESCRIPTORS",
    "Descriptor",
    "DescriptorMatrix",
    "DistanceHistogramDescriptor",
    "FastDescriptor",
    "HistogramDescriptor",
    "RandomWalkDescriptor",
    "TriangleDescriptor",
    "make_descriptor",
]
