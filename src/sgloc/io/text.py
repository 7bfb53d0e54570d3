"""Numeric text files (poses, calibration) read with clear errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sgloc.errors import DatasetError
from sgloc.io.files import MAX_TEXT_FILE_BYTES, check_regular_file, read_regular_file


def require_file(path: Path, what: str) -> Path:
    """Return `path` if it is a regular file, or raise DatasetError naming it and what it should
    hold (a folder, pipe or device is refused before it is opened)."""
    if not Path(path).exists():
        raise DatasetError(f"{path}: missing {what}.")
    return check_regular_file(path, what, DatasetError)


def read_numbers(path: Path, what: str, per_row: int | None = None) -> np.ndarray:
    """Read a whitespace/comma separated numeric text file as float64 rows.

    per_row: the number of values each row must have (error otherwise). Blank lines and lines
    starting with '#' are skipped.
    """
    text = read_text_file(path, what)
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        try:
            vals = [float(v) for v in s.replace(",", " ").split()]
            if not all(math.isfinite(v) for v in vals):
                raise ValueError
        except ValueError:
            raise DatasetError(
                f"{path}:{lineno}: {what}: non-numeric or non-finite value in {s[:60]!r}."
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


def read_text_file(path: Path, what: str) -> str:
    """The UTF-8 text of a regular file of bounded size; DatasetError naming it otherwise."""
    raw = read_regular_file(require_file(path, what), what, MAX_TEXT_FILE_BYTES, DatasetError)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise DatasetError(f"{path}: {what}: not a UTF-8 text file.") from None
