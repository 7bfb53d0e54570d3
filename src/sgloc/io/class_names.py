"""Class tables that give class names their ids: `classes.txt` of a replay layout.

File format: one class a line, `class_id name` (spaces or commas; `#` comments); a colour-table
line `class_id r g b name` (see sgloc.io.colour_table) is read the same way, colours ignored.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from sgloc.errors import DatasetError
from sgloc.io.text import read_text_file


def read_class_table(path: str | Path) -> dict[str, int]:
    """{name: class id} from a class table; DatasetError naming file and line otherwise."""
    path = Path(path)
    table: dict[str, int] = {}
    for n, line in enumerate(read_text_file(path, "class table").splitlines(), 1):
        parts = line.split("#", 1)[0].replace(",", " ").split()
        if not parts:
            continue
        if len(parts) >= 5 and all(p.isdigit() for p in parts[1:4]):
            parts = [parts[0], *parts[4:]]  # a colour-table line: drop r g b
        if len(parts) < 2 or not parts[0].isdigit():
            raise DatasetError(
                f"{path}:{n}: expected `class_id name` (id an integer >= 0), got {line.strip()!r}."
            )
        name = " ".join(parts[1:])
        if name in table and table[name] != int(parts[0]):
            raise DatasetError(f"{path}:{n}: class name {name!r} given twice; names must differ.")
        table[name] = int(parts[0])
    if not table:
        raise DatasetError(f"{path}: empty class table; give `class_id name` lines.")
    return table


def write_class_table(path: str | Path, names: Sequence[str]) -> Path:
    """Write `class_id name` lines, class k = names[k]."""
    path = Path(path)
    path.write_text("".join(f"{k} {name}\n" for k, name in enumerate(names)))
    return path


def resolve_class(token: str, table: dict[str, int] | None, where: str) -> int:
    """A class column value -> class id: an integer >= 0 as is, else a name of `table`."""
    t = token.strip()
    if t.isdigit():
        return int(t)
    if table is not None and t in table:
        return table[t]
    if table is None:
        fix = "give integer ids, or add a classes.txt (`class_id name` lines) or --classes"
    else:
        fix = f"known names: {', '.join(sorted(table))}; add it to the class table"
    raise DatasetError(
        f"{where}: class {t!r} is neither an integer id >= 0 nor a known name; {fix}."
    )
