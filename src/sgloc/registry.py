"""Lookup by name in the registries of stages (descriptors, rejectors, datasets)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TypeVar

from sgloc.errors import UnknownNameError

T = TypeVar("T")


def normalise(name: str) -> str:
    """A registry key's spelling-free form: case-insensitive, '-' read as '_'."""
    return str(name).strip().lower().replace("-", "_")


def lookup(table: Mapping[str, T], name: str, kind: str) -> T:
    """The entry `name` of `table` (case-insensitive, '-' and '_' alike); an UnknownNameError
    naming the `kind` and the choices otherwise."""
    key = normalise(name)
    if key in table:
        return table[key]
    for entry, value in table.items():
        if normalise(entry) == key:
            return value
    raise UnknownNameError(f"unknown {kind} {name!r}; choose one of {', '.join(table)}.")


def registered_name(table: Mapping[str, object], name: str, kind: str) -> str:
    """The key of `table` that `name` spells (as `lookup` reads it)."""
    lookup(table, name, kind)
    key = normalise(name)
    return next(entry for entry in table if normalise(entry) == key)
