"""Lookup by name in the registries of stages (descriptors, rejectors, datasets)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TypeVar

from sgloc.errors import UnknownNameError

T = TypeVar("T")


def lookup(table: Mapping[str, T], name: str, kind: str) -> T:
    """The entry `name` of `table` (case-insensitive, '-' read as '_'); an UnknownNameError
    naming the `kind` and the choices otherwise."""
    key = str(name).strip().lower().replace("-", "_")
    if key not in table:
        raise UnknownNameError(f"unknown {kind} {name!r}; choose one of {', '.join(table)}.")
    return table[key]
