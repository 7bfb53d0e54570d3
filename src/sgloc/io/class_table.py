"""Class tables: which class id a class name stands for, for graph tables whose class column
holds names (`car`, `pole`).

File format: one class a line, `class_id name` (spaces or commas; `#` comments); a colour
table's lines `class_id r g b name` are read too, so one file may serve both. Names are
matched without regard to case; a class may have several names (one line each).
"""

from __future__ import annotations

from pathlib import Path

from sgloc.errors import GraphFileError, SglocError
from sgloc.io.text import read_text_file


def read_class_table(path: str | Path) -> dict[str, int]:
    """{lower-case name: class id} from a class-table (or colour-table) file."""
    path = Path(path)
    try:
        text = read_text_file(path, "class table (lines `class_id name`)")
    except SglocError as e:  # a DatasetError: here a graph input
        raise GraphFileError(str(e)) from None
    table: dict[str, int] = {}
    for n, line in enumerate(text.splitlines(), 1):
        parts = line.split("#", 1)[0].replace(",", " ").split()
        if not parts:
            continue
        rgb = len(parts) >= 5 and all(p.isdigit() for p in parts[1:4])
        name = " ".join(parts[4:] if rgb else parts[1:]).lower()
        if not parts[0].isdigit() or not name:
            raise GraphFileError(
                f"{path}:{n}: expected `class_id name` (or `class_id r g b name`), got "
                f"{line.strip()!r}."
            )
        if table.get(name, int(parts[0])) != int(parts[0]):
            raise GraphFileError(f"{path}:{n}: the name {name!r} is given two class ids.")
        table[name] = int(parts[0])
    if not table:
        raise GraphFileError(f"{path}: empty class table; give `class_id name` lines.")
    return table


def class_ids(names: list[str], table: dict[str, int] | None, path: Path) -> list[int]:
    """The class ids of `names` (a table's class column) through `table`; GraphFileError
    naming the first unknown name (or the missing table)."""
    if table is None:
        raise GraphFileError(
            f"{path}: the class column holds names ({names[0]!r}); give a class table "
            "(--class-table FILE with lines `class_id name`), or write class ids."
        )
    unknown = next((n for n in names if n.lower() not in table), None)
    if unknown is not None:
        raise GraphFileError(
            f"{path}: class {unknown!r} is not in the class table; add a line `class_id "
            f"{unknown}` to it (known: {', '.join(sorted(table))})."
        )
    return [table[n.lower()] for n in names]
