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
    """File-safe names, a repeated one (ignoring case: some file systems do) suffixed with its
    position ('map-1', 'Map-2')."""
    safe = [safe_name(n) for n in names]
    low = [s.lower() for s in safe]
    return [f"{s}-{i}" if low.count(s.lower()) > 1 else s for i, s in enumerate(safe)]


def robot_names(paths: Sequence[str | Path]) -> list[str]:
    """A robot name per input file: its stem; files sharing a stem are named by their parent
    folder too ('r1/map.pcd', 'r2/map.pcd' -> 'r1-map', 'r2-map')."""
    ps = [Path(p) for p in paths]
    stems = [p.stem.lower() for p in ps]
    names = [f"{p.parent.name}-{p.stem}" if stems.count(p.stem.lower()) > 1 and p.parent.name
             else p.stem for p in ps]
    return unique_names(names)
