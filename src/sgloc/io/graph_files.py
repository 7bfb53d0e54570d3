"""Graph files by suffix: `.pcd`, `.json` ({"positions": [[x,y,z],...], "labels": [...]}, or a
spark-dsg scene graph), `.npz` (arrays `positions` (n,3) and `labels` (n,)), `.sparkdsg`
(a binary spark-dsg scene graph: its objects layer, `sgloc.io.scene_graph`).

Readers are strict: only regular files of bounded size are opened, labels must be integers,
numbers finite, shapes exact; anything else is a GraphFileError naming the file and the fix.
A reader for another format registers itself in READERS (suffix -> function path -> arrays).
Importing this module makes `read_graph` / `write_graph` what `SemanticGraph.load` / `.save`
call (`sgloc.maps.files.GRAPH_FILES`).
"""

from __future__ import annotations

import json
import re
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sgloc.errors import GraphFileError, SglocError
from sgloc.io.files import MAX_GRAPH_FILE_BYTES, check_regular_file, read_regular_file
from sgloc.maps.files import GRAPH_FILES
from sgloc.validation import check_graph_arrays

#: Deepest JSON nesting read ({"positions": [[x, y, z]]} is 3 deep).
MAX_JSON_DEPTH = 16
#: Longest integer literal in a JSON graph (digits); longer ones are refused, not converted.
MAX_JSON_INT_DIGITS = 20

GraphArrays = tuple[np.ndarray, np.ndarray]


def _read_pcd(path: Path) -> GraphArrays:
    from sgloc.io.pcd import read_pcd

    return read_pcd(path)


def _json_depth(text: str) -> int:
    """Greatest nesting depth of [] and {} outside strings."""
    stripped = re.sub(r'"(?:[^"\\]|\\.)*"', '""', text).encode("utf-8", "replace")
    b = np.frombuffer(stripped, dtype=np.uint8)
    step = np.isin(b, (ord("["), ord("{"))).astype(np.int64) - np.isin(b, (ord("]"), ord("}")))
    return int(np.cumsum(step).max()) if b.size else 0


def _json_number(kind: str) -> Callable[[str], float | int]:
    def parse(token: str) -> float | int:
        if kind == "int":
            if len(token.lstrip("-")) > MAX_JSON_INT_DIGITS:
                raise ValueError(
                    f"integer {token[:12]}... has more than {MAX_JSON_INT_DIGITS} digits"
                )
            return int(token)
        value = float(token)
        if not np.isfinite(value):
            raise ValueError(f"number {token} is beyond the float range")
        return value

    return parse


def _unique_keys(pairs: list[tuple[str, object]]) -> dict:
    keys = [k for k, _ in pairs]
    if len(set(keys)) != len(keys):
        twice = sorted({k for k in keys if keys.count(k) > 1})
        raise ValueError(f"key {twice[0]!r} appears twice in one object")
    return dict(pairs)


def _reject_constant(token: str) -> float:
    raise ValueError(f"{token} is not a finite number")


def _read_json(path: Path) -> GraphArrays:
    raw = read_regular_file(path, "JSON graph file")
    from sgloc.io.scene_graph import is_scene_graph_json, read_scene_graph

    if is_scene_graph_json(raw):  # a Hydra / spark-dsg scene graph: its objects layer
        return read_scene_graph(path)
    try:
        text = raw.decode("utf-8").removeprefix("\ufeff")  # a byte-order mark is no JSON
    except UnicodeDecodeError as e:
        raise GraphFileError(
            f"{path}: not UTF-8 text (byte {e.start}); is this a JSON file?"
        ) from None
    if _json_depth(text) > MAX_JSON_DEPTH:
        raise GraphFileError(
            f"{path}: JSON nested deeper than {MAX_JSON_DEPTH} levels; a graph is "
            '{"positions": [[x, y, z], ...], "labels": [...]}.'
        )
    try:
        data = json.loads(
            text,
            parse_int=_json_number("int"),
            parse_float=_json_number("float"),
            parse_constant=_reject_constant,
            object_pairs_hook=_unique_keys,
        )
    except ValueError as e:  # JSONDecodeError is a ValueError, so are our number checks
        raise GraphFileError(f"{path}: invalid JSON graph ({e}).") from None
    if not isinstance(data, dict) or "positions" not in data or "labels" not in data:
        raise GraphFileError(
            f"{path}: JSON graph needs keys 'positions' (list of [x, y, z]) and 'labels'."
        )
    positions, labels = data["positions"], data["labels"]
    if not isinstance(positions, list) or not all(
        isinstance(r, list) and len(r) == 3 and all(_is_real(v) for v in r) for r in positions
    ):
        raise GraphFileError(f"{path}: 'positions' must be a list of [x, y, z] rows of numbers.")
    if not isinstance(labels, list) or not all(_is_int(v) for v in labels):
        raise GraphFileError(
            f"{path}: 'labels' must be a list of integer class ids (not strings, booleans or "
            "fractions)."
        )
    return np.array(positions, dtype=np.float64).reshape(-1, 3), np.array(labels, dtype=np.int64)


def _is_real(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _is_int(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _read_npz(path: Path) -> GraphArrays:
    raw = read_regular_file(path, ".npz graph file")
    if raw.startswith(b"\x93NUMPY"):
        raise GraphFileError(
            f"{path}: is a single .npy array, not an .npz archive; save the graph with "
            "numpy.savez(path, positions=..., labels=...)."
        )
    if not raw.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        raise GraphFileError(f"{path}: not an .npz (zip) archive; is the file damaged?")
    _check_zip_end(raw, path)
    try:
        with zipfile.ZipFile(path) as zf:
            total = sum(info.file_size for info in zf.infolist())
        if total > MAX_GRAPH_FILE_BYTES:
            raise GraphFileError(f"{path}: archive expands to {total} bytes; too large a graph.")
        with np.load(path, allow_pickle=False) as z:
            missing = {"positions", "labels"} - set(z.files)
            if missing:
                raise GraphFileError(
                    f"{path}: .npz graph needs arrays 'positions' and 'labels' "
                    f"(missing {', '.join(sorted(missing))})."
                )
            positions, labels = z["positions"], z["labels"]
    except GraphFileError:
        raise
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, KeyError) as e:
        raise GraphFileError(
            f"{path}: damaged .npz archive ({type(e).__name__}); re-save it."
        ) from None
    except RuntimeError as e:  # zipfile: a (flipped) flag bit says the member is encrypted
        raise GraphFileError(
            f"{path}: damaged .npz archive ({type(e).__name__}); re-save it."
        ) from None
    except (ValueError, OSError) as e:
        raise GraphFileError(f"{path}: cannot read .npz arrays ({e}); re-save them.") from None
    if positions.dtype.kind not in "fiu" or positions.ndim != 2 or positions.shape[1] != 3:
        raise GraphFileError(
            f"{path}: 'positions' must be a real (n, 3) array, got {positions.dtype} "
            f"{positions.shape}."
        )
    if labels.dtype.kind not in "iu" or labels.shape != (positions.shape[0],):
        raise GraphFileError(
            f"{path}: 'labels' must be an integer ({positions.shape[0]},) array, got "
            f"{labels.dtype} {labels.shape}."
        )
    return positions.astype(np.float64), labels.astype(np.int64)


def _check_zip_end(raw: bytes, path: Path) -> None:
    """The zip's end record (plus its comment) must end the file: no trailing bytes."""
    end = raw.rfind(b"PK\x05\x06", max(0, len(raw) - 22 - 0xFFFF))
    if end < 0 or len(raw) - end < 22:
        raise GraphFileError(f"{path}: damaged .npz archive (no end record); re-save it.")
    comment = int.from_bytes(raw[end + 20 : end + 22], "little")
    if end + 22 + comment != len(raw):
        raise GraphFileError(
            f"{path}: {len(raw) - end - 22 - comment} unexpected bytes after the .npz archive; "
            "the file is damaged or was appended to; re-save it."
        )


def _read_ply(path: Path) -> GraphArrays:
    from sgloc.io.ply import read_ply

    return read_ply(path)


def _read_table(path: Path) -> GraphArrays:
    from sgloc.io.table import read_table

    return read_table(path)


def _read_scene_graph(path: Path) -> GraphArrays:
    from sgloc.io.scene_graph import read_scene_graph

    return read_scene_graph(path)


#: Graph readers by lower-case suffix (with their default options; `sgloc.io.inputs` passes
#: a class field or colour table).
READERS: dict[str, Callable[[Path], GraphArrays]] = {
    ".pcd": _read_pcd,
    ".json": _read_json,
    ".npz": _read_npz,
    ".ply": _read_ply,
    ".csv": _read_table,
    ".txt": _read_table,
    ".sparkdsg": _read_scene_graph,
}
#: Suffixes `write_graph` writes (every suffix `read_graph` reads but `.sparkdsg`: scene graphs
#: are read only).
SUFFIXES = (".pcd", ".json", ".npz", ".ply", ".csv", ".txt")


def read_graph(path: str | Path) -> GraphArrays:
    """Read (positions (n,3) float64, labels (n,) int64) from a graph file; GraphFileError (or
    InvalidGraphError for values beyond sgloc.validation's limits) if it is bad."""
    path = Path(path)
    kinds = ", ".join(READERS)
    check_regular_file(path, f"graph file ({kinds})")
    suffix = path.suffix.lower()
    reader = READERS.get(suffix)
    if reader is None:
        raise GraphFileError(f"{path}: unknown graph format {suffix!r}; use one of {kinds}.")
    try:
        positions, labels = reader(path)
    except SglocError:
        raise
    except (ValueError, OSError, UnicodeDecodeError) as e:
        raise GraphFileError(f"{path}: cannot read graph ({type(e).__name__}: {e}).") from None
    return check_graph_arrays(str(path), positions, labels)


def check_graph_suffix(path: str | Path) -> str:
    """The lower-case suffix of a graph file to write; GraphFileError naming `path` when
    write_graph has no format for it."""
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        raise GraphFileError(
            f"{path}: unknown graph format {suffix!r}; use one of {', '.join(SUFFIXES)}."
        )
    return suffix


def write_graph(
    path: str | Path, positions: np.ndarray, labels: np.ndarray, edge_radius: float | None = None
) -> Path:
    """Write a graph; the format follows the suffix (.pcd, .json, .npz, .ply, .csv, .txt);
    only .json keeps `edge_radius`."""
    path = Path(path)
    suffix = check_graph_suffix(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".pcd":
        from sgloc.io.pcd import write_pcd

        write_pcd(path, positions, labels)
    elif suffix == ".ply":
        from sgloc.io.ply import write_ply

        write_ply(path, positions, labels)
    elif suffix in (".csv", ".txt"):
        from sgloc.io.table import write_table

        write_table(path, positions, labels)
    elif suffix == ".json":
        data = {
            "positions": np.asarray(positions).tolist(),
            "labels": np.asarray(labels).astype(int).tolist(),
        }
        if edge_radius is not None:
            data["edge_radius"] = edge_radius
        path.write_text(json.dumps(data))
    else:
        np.savez_compressed(path, positions=np.asarray(positions), labels=np.asarray(labels))
    return path


GRAPH_FILES.register(read_graph, write_graph)
