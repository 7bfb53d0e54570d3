"""Graph files with reader options (class field, colour table), by suffix; the formats without
options go through `sgloc.io.graph_files.read_graph`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.classes import AIRSIM_COLORS


def read_graph_with(
    path: str | Path, label_field: str | None = None, colour_table: str | Path | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(positions (n,3), labels (n,)) of a graph file; `label_field` names the class field of
    .ply/.csv/.txt files; `colour_table` maps colours to classes (.pcd rgb, .ply red/green/blue)."""
    from sgloc.io.graph_files import read_graph

    path = Path(path)
    suffix = path.suffix.lower()
    colours = AIRSIM_COLORS
    if colour_table is not None:
        from sgloc.io.colour_table import read_colour_table

        colours = read_colour_table(colour_table)[0]
    if path.is_file() and suffix == ".ply":
        from sgloc.io.ply import read_ply

        return read_ply(path, label_field, colours)
    if path.is_file() and suffix in (".csv", ".txt"):
        from sgloc.io.table import read_table

        return read_table(path, label_field)
    if path.is_file() and suffix == ".pcd" and colour_table is not None:
        from sgloc.io.pcd import read_pcd

        return read_pcd(path, colours)
    return read_graph(path)
