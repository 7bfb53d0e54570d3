"""Graph files by suffix: `.pcd`, `.json` ({"positions": [[x,y,z],...], "labels": [...]}),
`.npz` (arrays `positions`, `labels`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sgloc.errors import GraphFileError

SUFFIXES = (".pcd", ".json", ".npz")


def read_graph(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read (positions (n,3), labels (n,)) from a graph file; raise GraphFileError if bad."""
    path = Path(path)
    if not path.exists():
        raise GraphFileError(f"{path}: no such file; give the path of a .pcd, .json or .npz graph.")
    if path.is_dir():
        raise GraphFileError(f"{path}: is a folder; give a graph file (.pcd, .json or .npz).")
    suffix = path.suffix.lower()
    try:
        if suffix in (".ply", ".csv", ".txt"):  # readers with options: sgloc.io.inputs
            from sgloc.io.inputs import read_graph_with

            return read_graph_with(path)
        if suffix == ".pcd":
            from sgloc.io.pcd import read_pcd

            return read_pcd(path)
        if suffix == ".json":
            data = json.loads(path.read_text())
            if not isinstance(data, dict) or "positions" not in data or "labels" not in data:
                raise GraphFileError(
                    f"{path}: JSON graph needs keys 'positions' (list of [x, y, z]) and 'labels'."
                )
            return _as_arrays(path, data["positions"], data["labels"])
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                if "positions" not in z or "labels" not in z:
                    raise GraphFileError(
                        f"{path}: .npz graph needs arrays 'positions' and 'labels'."
                    )
                return _as_arrays(path, z["positions"], z["labels"])
    except GraphFileError:
        raise
    except (ValueError, OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise GraphFileError(f"{path}: cannot read graph ({type(e).__name__}: {e}).") from e
    raise GraphFileError(
        f"{path}: unknown graph format {suffix!r}; use one of {', '.join(SUFFIXES)}."
    )


def _as_arrays(path: Path, positions, labels) -> tuple[np.ndarray, np.ndarray]:
    try:
        pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        lab = np.asarray(labels, dtype=np.float64).reshape(-1)
    except (ValueError, TypeError) as e:
        raise GraphFileError(f"{path}: positions must be rows of 3 numbers ({e}).") from e
    if np.any(lab != np.round(lab)):
        raise GraphFileError(f"{path}: labels must be integer class ids.")
    return pos, lab.astype(np.int64)


def write_graph(
    path: str | Path, positions: np.ndarray, labels: np.ndarray, edge_radius: float | None = None
) -> Path:
    """Write a graph; the format follows the suffix (.pcd, .json, .npz)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise GraphFileError(
            f"{path}: unknown graph format {suffix!r}; use one of {', '.join(SUFFIXES)}."
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".pcd":
        from sgloc.io.pcd import write_pcd

        write_pcd(path, positions, labels)
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
