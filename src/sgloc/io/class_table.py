"""Class tables: which class id a class name stands for. The one reader, used by every command
(`localize` / `fleet --class-table`, a replay layout's `classes.txt`, `replay --class-table`).

File format: one class a line, `class_id name` (spaces or commas; `#` comments); a colour
table's lines `class_id r g b name` are read too, so one file may serve both. A class may have
several names (one line each). Names are matched without regard to case (`Car`, `car` and `CAR`
are one name); a name given two different ids is refused.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from sgloc.errors import DatasetError, GraphFileError
from sgloc.io.text import read_text_file


class ClassTableError(GraphFileError, DatasetError):
    """A class table, or a class name it does not hold (a graph file's or a replay input's)."""


def read_class_table(path: str | Path) -> dict[str, int]:
    """{lower-case name: class id} from a class-table (or colour-table) file; ClassTableError
    naming the file and line otherwise."""
    path = Path(path)
    text = read_text_file(path, "class table (lines `class_id name`)", ClassTableError)
    table: dict[str, int] = {}
    for n, line in enumerate(text.splitlines(), 1):
        parts = line.split("#", 1)[0].replace(",", " ").split()
        if not parts:
            continue
        rgb = len(parts) >= 5 and all(p.isdigit() for p in parts[1:4])
        name = " ".join(parts[4:] if rgb else parts[1:]).lower()
        if not parts[0].isdigit() or not name:
            raise ClassTableError(
                f"{path}:{n}: expected `class_id name` (id an integer >= 0; or `class_id r g b "
                f"name`), got {line.strip()!r}."
            )
        if table.get(name, int(parts[0])) != int(parts[0]):
            raise ClassTableError(
                f"{path}:{n}: the name {name!r} is given two class ids (names are compared "
                "without regard to case); give each name one id."
            )
        table[name] = int(parts[0])
    if not table:
        raise ClassTableError(f"{path}: empty class table; give `class_id name` lines.")
    return table


def class_names_by_id(table: dict[str, int]) -> list[str]:
    """Class k's first name in `table` at index k ("class k" for ids without a name)."""
    by_id: dict[int, str] = {}
    for name, cid in table.items():
        by_id.setdefault(cid, name)
    return [by_id.get(i, f"class {i}") for i in range(max(by_id) + 1)]


def write_class_table(path: str | Path, names: Sequence[str]) -> Path:
    """Write `class_id name` lines, class k = names[k]."""
    path = Path(path)
    path.write_text("".join(f"{k} {name}\n" for k, name in enumerate(names)))
    return path


_NO_TABLE = (
    "give integer class ids, or a class table of `class_id name` lines (--class-table FILE; "
    "a replay layout may instead hold it as classes.txt)"
)


def resolve_class(token: str, table: dict[str, int] | None, where: str) -> int:
    """A class value -> class id: an integer >= 0 as is, else a name of `table` (any case);
    ClassTableError naming `where` and the fix otherwise."""
    t = token.strip()
    if t.isdigit():
        return int(t)
    if table is not None and t.lower() in table:
        return table[t.lower()]
    if table is None:
        raise ClassTableError(
            f"{where}: class {t!r} is neither an integer id >= 0 nor a known name; {_NO_TABLE}."
        )
    raise ClassTableError(
        f"{where}: class {t!r} is neither an integer id >= 0 nor in the class table; add a line "
        f"`class_id {t}` to it (known: {', '.join(sorted(table))})."
    )


def class_ids(names: list[str], table: dict[str, int] | None, path: Path) -> list[int]:
    """The class ids of `names` (a graph table's class column of names) through `table`;
    ClassTableError naming the first unknown name (or the missing table)."""
    if table is None:
        raise ClassTableError(
            f"{path}: the class column holds names ({names[0]!r}); {_NO_TABLE}."
        )
    unknown = next((n for n in names if n.lower() not in table and not n.isdigit()), None)
    if unknown is not None:
        raise ClassTableError(
            f"{path}: class {unknown!r} is not in the class table; add a line `class_id "
            f"{unknown}` to it (known: {', '.join(sorted(table))})."
        )
    return [resolve_class(n, table, str(path)) for n in names]
