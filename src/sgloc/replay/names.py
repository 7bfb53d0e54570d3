"""File names for robots: distinct for distinct robots, on any file system."""

from __future__ import annotations

import re
from collections.abc import Sequence

_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def robot_file_stems(names: Sequence[str]) -> dict[str, str]:
    """{robot: file stem}: unsafe characters (`/`, spaces, ...) become `_`, a leading dot gets a
    `robot_` prefix, and stems that would collide (also case-insensitively) get `-2`, `-3`, ...
    in the order given, so no two robots ever write the same file."""
    out: dict[str, str] = {}
    used: set[str] = set()
    for name in names:
        base = _UNSAFE.sub("_", name).strip("_") or "robot"
        if base.startswith("."):
            base = f"robot_{base}"
        stem, k = base, 1
        while stem.lower() in used:
            k += 1
            stem = f"{base}-{k}"
        used.add(stem.lower())
        out[name] = stem
    return out
