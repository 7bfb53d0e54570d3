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
    from sgloc.io.files import check_regular_file
    from sgloc.io.graph_files import read_graph
    from sgloc.validation import check_graph_arrays

    path = Path(path)
    suffix = path.suffix.lower()
    if label_field is None and colour_table is None:
        return read_graph(path)
    check_regular_file(path, "graph file")
    colours = AIRSIM_COLORS
    if colour_table is not None:
        from sgloc.io.colour_table import read_colour_table

        colours = read_colour_table(colour_table)[0]
    if suffix == ".ply":
        from sgloc.io.ply import read_ply

        arrays = read_ply(path, label_field, colours)
    elif suffix in (".csv", ".txt"):
        from sgloc.io.table import read_table

        arrays = read_table(path, label_field)
    elif suffix == ".pcd":
        from sgloc.io.pcd import read_pcd

        arrays = read_pcd(path, colours)
    else:
        return read_graph(path)
    return check_graph_arrays(str(path), *arrays)
