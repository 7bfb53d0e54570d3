"""PLY files (ASCII or binary, via plyfile) holding objects as vertices: x, y, z plus a class,
either an integer field (`label`, `class`, ... or the one named by `label_field`) or a colour
(`red green blue`) looked up in a colour table (the Airsim table by default)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.errors import GraphFileError
from sgloc.maps.classes import AIRSIM_COLORS, colors_to_labels

#: Class fields tried in order when none is named.
LABEL_FIELDS = ("label", "class", "class_id", "semantic", "category", "scalar_label")


def read_ply(
    path: str | Path, label_field: str | None = None, colors: np.ndarray = AIRSIM_COLORS
) -> tuple[np.ndarray, np.ndarray]:
    """Read object positions (n,3) and class ids (n,) from the `vertex` element of a PLY."""
    from plyfile import PlyData, PlyParseError

    path = Path(path)
    try:
        ply = PlyData.read(str(path))
    except (PlyParseError, ValueError, OSError, EOFError) as e:
        raise GraphFileError(f"{path}: cannot read PLY ({type(e).__name__}: {e}).") from e
    if "vertex" not in ply:
        raise GraphFileError(f"{path}: PLY has no `vertex` element.")
    v = ply["vertex"].data
    names = list(v.dtype.names or ())
    if not {"x", "y", "z"} <= set(names):
        raise GraphFileError(f"{path}: PLY vertices need x y z, have {' '.join(names)}.")
    positions = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    field = label_field or next((f for f in LABEL_FIELDS if f in names), None)
    if field is not None:
        if field not in names:
            raise GraphFileError(
                f"{path}: no vertex field {field!r}; fields are {' '.join(names)} "
                "(choose one with --label-field)."
            )
        return positions, _integer_labels(path, np.asarray(v[field]), field)
    if {"red", "green", "blue"} <= set(names):
        rgb = np.stack([v["red"], v["green"], v["blue"]], axis=1)
        labels = colors_to_labels(rgb, colors)
        if np.any(labels < 0):
            i = int(np.flatnonzero(labels < 0)[0])
            raise GraphFileError(
                f"{path}: vertex {i} has colour {tuple(int(c) for c in rgb[i])}, not in the "
                "class colour table; pass the dataset's table (--colour-table)."
            )
        return positions, labels.astype(np.int64)
    raise GraphFileError(
        f"{path}: PLY has no class field; name one with --label-field (fields: {' '.join(names)})."
    )


def _integer_labels(path: Path, values: np.ndarray, field: str) -> np.ndarray:
    lab = values.astype(np.float64)
    if not np.all(np.isfinite(lab)) or np.any(lab != np.round(lab)):
        raise GraphFileError(f"{path}: field {field!r} must hold integer class ids.")
    return lab.astype(np.int64)


def write_ply(path: str | Path, positions: np.ndarray, labels: np.ndarray) -> Path:
    """Write objects as a binary PLY with vertex fields x y z (float64) and label (int32)."""
    from plyfile import PlyData, PlyElement

    pos = np.asarray(positions, dtype=np.float64)
    v = np.empty(len(pos), dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("label", "i4")])
    v["x"], v["y"], v["z"], v["label"] = pos[:, 0], pos[:, 1], pos[:, 2], labels
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    PlyData([PlyElement.describe(v, "vertex")]).write(str(path))
    return path
