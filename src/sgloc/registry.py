"""`Registry`: the one way sgloc keeps things by name (descriptors, rejectors, frame loaders,
pair sources, presets, downloadable data sets).

Names are read case-insensitively with '-' and '_' alike (`kitti-objects` is `kitti_objects`);
an unknown name raises UnknownNameError naming the kind, the choices and the closest name.

    DESCRIPTORS = Registry[type[Descriptor]]("descriptor")

    @DESCRIPTORS.register("histogram")
    class HistogramDescriptor(Descriptor): ...

    DESCRIPTORS.lookup("Histogram")  # -> HistogramDescriptor
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterator, Mapping, MutableMapping
from typing import Generic, TypeVar

from sgloc.errors import UnknownNameError

T = TypeVar("T")


def normalise(name: str) -> str:
    """A registry key's spelling-free form: case-insensitive, '-' read as '_'."""
    return str(name).strip().lower().replace("-", "_")


class Registry(MutableMapping[str, T], Generic[T]):
    """Entries by name, in the order registered. A mapping (iterating gives the registered
    names); `lookup` reads a name however it is spelt; `aliases` are extra names of entries."""

    def __init__(
        self,
        kind: str,
        entries: Mapping[str, T] | None = None,
        aliases: Mapping[str, str] | None = None,
    ) -> None:
        self.kind = kind
        self._entries: dict[str, T] = dict(entries or {})
        self.aliases: dict[str, str] = dict(aliases or {})

    def register(self, name: str) -> Callable[[T], T]:
        """A decorator registering its argument under `name` (and returning it unchanged)."""

        def add(entry: T) -> T:
            self._entries[name] = entry
            return entry

        return add

    def key(self, name: str) -> str:
        """The registered name that `name` spells (aliases resolved); UnknownNameError with the
        choices and the closest name otherwise."""
        wanted = normalise(name)
        for alias, target in self.aliases.items():
            if normalise(alias) == wanted:
                wanted = normalise(target)
        for entry in self._entries:
            if normalise(entry) == wanted:
                return entry
        raise UnknownNameError(self.unknown_message(name))

    def lookup(self, name: str) -> T:
        """The entry `name` spells (see `key`)."""
        return self._entries[self.key(name)]

    def find(self, name: str) -> T | None:
        """The entry `name` spells, or None."""
        try:
            return self.lookup(name)
        except UnknownNameError:
            return None

    def names(self) -> list[str]:
        """The registered names and the aliases."""
        return [*self._entries, *self.aliases]

    def unknown_message(self, name: str, other: str = "") -> str:
        """The text of the error for the unknown `name` (choices and the closest name; `other`:
        what else may be given, e.g. "a folder")."""
        names = self.names()
        close = difflib.get_close_matches(normalise(name), [normalise(n) for n in names], n=1)
        hint = ""
        if close:
            hint = " (did you mean " + next(n for n in names if normalise(n) == close[0]) + "?)"
        other = f" or give {other}" if other else ""
        return f"unknown {self.kind} {name!r}{hint}; choose one of {', '.join(names)}{other}."

    def __getitem__(self, name: str) -> T:
        return self._entries[name]

    def __setitem__(self, name: str, value: T) -> None:
        self._entries[name] = value

    def __delitem__(self, name: str) -> None:
        del self._entries[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, {list(self._entries)})"
