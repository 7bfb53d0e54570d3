"""Numeric text files (poses, calibration) read with clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.errors import DatasetError


def require_file(path: Path, what: str) -> Path:
    """Return `path`, or raise DatasetError naming it and what it should hold."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing {what}.")
    return path


def read_numbers(path: Path, what: str, per_row: int | None = None) -> np.ndarray:
    """Read a whitespace/comma separated numeric text file as float64 rows.

    per_row: the number of values each row must have (error otherwise). Blank lines and lines
    starting with '#' are skipped.
    """
    require_file(path, what)
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        try:
            vals = [float(v) for v in s.replace(",", " ").split()]
        except ValueError:
            raise DatasetError(
                f"{path}:{lineno}: {what}: non-numeric value in {s[:60]!r}."
            ) from None
        if per_row is not None and len(vals) != per_row:
            raise DatasetError(
                f"{path}:{lineno}: {what}: expected {per_row} values a row, got {len(vals)}."
            )
        rows.append(vals)
    if not rows:
        raise DatasetError(f"{path}: {what}: the file holds no rows.")
    if per_row is None and len({len(r) for r in rows}) > 1:
        raise DatasetError(f"{path}: {what}: rows have different lengths.")
    arr = np.array(rows, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise DatasetError(f"{path}: {what}: NaN or infinite values.")
    return arr
