"""Colour tables: which colour is which class, for maps whose classes are coded as colours.

File format: one class a line, `class_id r g b [name]` (spaces or commas; `#` comments), r g b
in 0-255. Class ids need not be contiguous; colours must be distinct. A UTF-8 byte-order mark
is ignored (`sgloc.io.text`). """

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.errors import GraphFileError
from sgloc.io.text import read_text_file


def read_colour_table(path: str | Path) -> tuple[np.ndarray, list[str]]:
    """(table (k,3) uint8 where row c is class c's colour, names) from a colour-table file.
    Rows of ids missing from the file are set to an impossible colour (-1 never matches)."""
    path = Path(path)
    text = read_text_file(path, "colour table (lines `class r g b [name]`)", GraphFileError)
    ids, rgb, names = [], [], {}
    for n, line in enumerate(text.splitlines(), 1):
        parts = line.split("#", 1)[0].replace(",", " ").split()
        if not parts:
            continue
        try:
            cid, r, g, b = (int(p) for p in parts[:4])
        except ValueError:
            raise GraphFileError(
                f"{path}:{n}: expected `class_id r g b [name]` with integers, got {line.strip()!r}."
            ) from None
        if cid < 0 or not all(0 <= v <= 255 for v in (r, g, b)):
            raise GraphFileError(f"{path}:{n}: class id must be >= 0 and r g b in 0-255.")
        ids.append(cid)
        rgb.append((r, g, b))
        names[cid] = " ".join(parts[4:]) or f"class {cid}"
    if not ids:
        raise GraphFileError(f"{path}: empty colour table; give `class r g b` lines.")
    if len({tuple(c) for c in rgb}) != len(rgb) or len(set(ids)) != len(ids):
        raise GraphFileError(f"{path}: every class needs its own id and its own colour.")
    table = np.full((max(ids) + 1, 3), -1, dtype=np.int64)
    table[ids] = rgb
    return table, [names.get(i, f"class {i}") for i in range(len(table))]
