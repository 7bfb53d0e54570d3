"""CSV / TXT graph tables: one object a row, x y z and a class.

Columns are found by name when the first row is a header (`x,y,z,label`; class column named
by `label_field`, else the first of label/class/class_id/semantic/category), else by position:
x y z in columns 0-2 and the class in column 3 (or `label_field` as a 0-based index).
Separators: commas, semicolons, tabs or spaces; `#` starts a comment; a leading UTF-8
byte-order mark (spreadsheet "CSV UTF-8") is ignored. The class column holds integer class ids,
or class names turned into ids by a class table (`sgloc.io.class_table`). A table with a header
but no object rows is refused, as an empty file is: a map needs objects.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from sgloc.errors import GraphFileError
from sgloc.io.class_table import class_ids
from sgloc.io.files import MAX_GRAPH_FILE_BYTES, read_regular_file
from sgloc.io.ply import LABEL_FIELDS
from sgloc.io.text import decode_text

_SPLIT = re.compile(r"[,;\s]+")


def read_table(
    path: str | Path, label_field: str | None = None, classes: dict[str, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Read object positions (n,3) and class ids (n,) from a CSV or whitespace table; `classes`
    ({name: id}, `sgloc.io.class_table.read_class_table`) reads a class column of names."""
    path = Path(path)
    what = "graph table (rows `x y z label`)"
    text = decode_text(
        read_regular_file(path, what, MAX_GRAPH_FILE_BYTES, GraphFileError), path, what,
        GraphFileError,
    )
    rows = [
        _SPLIT.split(ln.split("#", 1)[0].strip())
        for ln in text.splitlines()
        if ln.split("#", 1)[0].strip()
    ]
    if not rows:
        raise GraphFileError(f"{path}: empty table; expected rows `x y z label`.")
    header = None if _is_number(rows[0][0]) else [h.strip().lower() for h in rows[0]]
    if header is not None and "stamp" in header:
        raise GraphFileError(_keyframe_table_refusal(path))
    body = rows[1:] if header else rows
    if not body:
        raise GraphFileError(
            f"{path}: a header but no object rows; a map needs at least one row `x,y,z,label` "
            "under the header."
        )
    cx, cy, cz, cl = _columns(path, header, label_field, len(body[0]) if body else 0)
    try:
        names = [r[cl] for r in body]
        if names and not all(_is_number(n) for n in names):
            names = [str(c) for c in class_ids(names, classes, path)]
        vals = np.array(
            [[r[cx], r[cy], r[cz], n] for r, n in zip(body, names, strict=True)], dtype=np.float64
        )
    except (IndexError, ValueError) as e:
        raise GraphFileError(
            f"{path}: every row needs numbers in the x y z columns and a class column value ({e})."
        ) from e
    lab = vals[:, 3]
    if np.any(~np.isfinite(lab)) or np.any(lab != np.round(lab)):
        raise GraphFileError(f"{path}: the class column must hold integer class ids.")
    return vals[:, :3].reshape(-1, 3), lab.astype(np.int64)


def _keyframe_table_refusal(path: Path) -> str:
    """Why a table with a `stamp` column is not a map: it is a recorded run's keyframe table
    (`objects.csv` of the plain layout, docs/replay.md), each row in its keyframe's sensor
    frame; the message names the command that reads it."""
    robot = path.parent
    run = robot.parent if (robot / "odometry.tum").is_file() else None
    command = f"`sgloc replay {run}`" if run is not None else (
        "`sgloc replay RUN` (RUN: the folder holding the robot folders)"
    )
    return (
        f"{path}: a `stamp` column: this is a recorded run's keyframe table (each row an "
        "object seen from one keyframe, in that keyframe's sensor frame), not a map; replay "
        f"the run with {command} (docs/replay.md)."
    )


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _columns(
    path: Path, header: list[str] | None, label_field: str | None, width: int
) -> tuple[int, int, int, int]:
    """Indices of x, y, z and the class column."""
    if label_field is not None and label_field.strip().lstrip("-").isdigit():
        label_index: int | None = int(label_field)
    else:
        label_index = None
    if header is None:
        if label_field is not None and label_index is None:
            raise GraphFileError(
                f"{path}: no header row, so --label-field must be a column index (0-based)."
            )
        return 0, 1, 2, 3 if label_index is None else label_index
    missing = [c for c in "xyz" if c not in header]
    if missing:
        raise GraphFileError(f"{path}: header lacks column(s) {' '.join(missing)}: {header}.")
    if label_index is None:
        name = label_field.lower() if label_field else next(
            (f for f in LABEL_FIELDS if f in header), None
        )
        if name is None or name not in header:
            raise GraphFileError(
                f"{path}: no class column {name or ''!r} in the header {header}; "
                "name it with --label-field."
            )
        label_index = header.index(name)
    return header.index("x"), header.index("y"), header.index("z"), label_index


def write_table(path: str | Path, positions: np.ndarray, labels: np.ndarray) -> Path:
    """Write objects as a table with a header `x y z label`: commas for .csv, spaces else."""
    path = Path(path)
    sep = "," if path.suffix.lower() == ".csv" else " "
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = np.column_stack([np.asarray(positions, dtype=np.float64), labels])
    np.savetxt(path, rows, fmt=["%.6f"] * 3 + ["%d"], delimiter=sep,
               header=sep.join(("x", "y", "z", "label")), comments="")
    return path
