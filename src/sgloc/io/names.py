"""Robot names for output files: unique, safe as file names."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path


def safe_name(name: str) -> str:
    """`name` with path separators, whitespace and other unsafe characters replaced by '-'."""
    s = re.sub(r"[^A-Za-z0-9._+-]+", "-", str(name)).strip("-.")
    return s or "robot"


def unique_names(names: Sequence[str]) -> list[str]:
    """`safe_name` of each name, and names that would collide (ignoring case: some file systems
    do, and with a suffix given earlier) suffixed `-2`, `-3`, ... in the order given: the one
    name scheme of output files ('map', 'Map-2')."""
    out: list[str] = []
    used: set[str] = set()
    for name in names:
        base = safe_name(name)
        stem, k = base, 1
        while stem.lower() in used:
            k += 1
            stem = f"{base}-{k}"
        used.add(stem.lower())
        out.append(stem)
    return out


def robot_file_stems(names: Sequence[str]) -> dict[str, str]:
    """{robot: file stem} of distinct robot names (`unique_names`)."""
    return dict(zip(names, unique_names(names), strict=True))


def robot_names(paths: Sequence[str | Path]) -> list[str]:
    """A robot name per input file: its stem; files sharing a stem are named by their parent
    folder too ('r1/map.pcd', 'r2/map.pcd' -> 'r1-map', 'r2-map')."""
    ps = [Path(p) for p in paths]
    stems = [p.stem.lower() for p in ps]
    names = [f"{p.parent.name}-{p.stem}" if stems.count(p.stem.lower()) > 1 and p.parent.name
             else p.stem for p in ps]
    return unique_names(names)
