"""Text files (poses, calibration, tables, class tables) read with clear errors.

Every text file is UTF-8; a leading byte-order mark (what spreadsheet programs write for "CSV
UTF-8") is dropped. """

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sgloc.errors import DatasetError, SglocError
from sgloc.io.files import MAX_TEXT_FILE_BYTES, check_regular_file, read_regular_file

BOM = "\ufeff"


def require_file(path: Path, what: str, error: type[SglocError] = DatasetError) -> Path:
    """Return `path` if it is a regular file, or raise `error` naming it and what it should
    hold (a folder, pipe or device is refused before it is opened)."""
    if not Path(path).exists():
        raise error(f"{path}: missing {what}.")
    return check_regular_file(path, what, error)


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


def read_text_file(path: Path, what: str, error: type[SglocError] = DatasetError) -> str:
    """The UTF-8 text of a regular file of bounded size, without a leading byte-order mark;
    `error` naming it otherwise."""
    raw = read_regular_file(require_file(path, what, error), what, MAX_TEXT_FILE_BYTES, error)
    return decode_text(raw, path, what, error)


def decode_text(
    raw: bytes, path: str | Path, what: str, error: type[SglocError] = DatasetError
) -> str:
    """`raw` as UTF-8 text without a leading byte-order mark; `error` naming `path` if it is not
    UTF-8."""
    try:
        return raw.decode("utf-8").removeprefix(BOM)
    except UnicodeDecodeError as e:
        raise error(f"{path}: {what}: not a UTF-8 text file (byte {e.start}).") from None
