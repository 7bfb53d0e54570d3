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
    """File-safe names, a repeated one suffixed with its position ('map-1', 'map-2')."""
    safe = [safe_name(n) for n in names]
    out = []
    for i, s in enumerate(safe):
        out.append(f"{s}-{i}" if safe.count(s) > 1 else s)
    return out


def robot_names(paths: Sequence[str | Path]) -> list[str]:
    """A robot name per input file: its stem; files sharing a stem are named by their parent
    folder too ('r1/map.pcd', 'r2/map.pcd' -> 'r1-map', 'r2-map')."""
    ps = [Path(p) for p in paths]
    stems = [p.stem for p in ps]
    names = [f"{p.parent.name}-{p.stem}" if stems.count(p.stem) > 1 and p.parent.name else p.stem
             for p in ps]
    return unique_names(names)
