"""File names for robots: distinct for distinct robots, on any file system."""

from __future__ import annotations

from collections.abc import Sequence

from sgloc.io.names import safe_name


def robot_file_stems(names: Sequence[str]) -> dict[str, str]:
    """{robot: file stem}: `sgloc.io.names.safe_name` of each name (unsafe characters such as
    `/` and spaces become `-`), and stems that would collide, also case-insensitively (and with
    a suffix given earlier), get `-2`, `-3`, ... in the order given, so no two robots ever
    write the same file."""
    out: dict[str, str] = {}
    used: set[str] = set()
    for name in names:
        base = safe_name(name)
        stem, k = base, 1
        while stem.lower() in used:
            k += 1
            stem = f"{base}-{k}"
        used.add(stem.lower())
        out[name] = stem
    return out
