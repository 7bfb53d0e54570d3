"""Graph files with reader options (class field, colour table), by suffix; the formats without
options go through `sgloc.io.graph_files.read_graph`."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sgloc.maps.classes import AIRSIM_COLORS

if TYPE_CHECKING:
    from sgloc.maps.graph import SemanticGraph


def read_graph_with(
    path: str | Path,
    label_field: str | None = None,
    colour_table: str | Path | None = None,
    class_table: str | Path | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(positions (n,3), labels (n,)) of a graph file; `label_field` names the class field of
    .ply/.csv/.txt files; `colour_table` maps colours to classes (.pcd rgb, .ply red/green/blue);
    `class_table` maps class names to ids (.csv/.txt class columns of names)."""
    from sgloc.io.files import check_regular_file
    from sgloc.io.graph_files import read_graph
    from sgloc.validation import check_graph_arrays

    path = Path(path)
    suffix = path.suffix.lower()
    if label_field is None and colour_table is None and class_table is None:
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

        classes = None
        if class_table is not None:
            from sgloc.io.class_table import read_class_table

            classes = read_class_table(class_table)
        arrays = read_table(path, label_field, classes)
    elif suffix == ".pcd":
        from sgloc.io.pcd import read_pcd

        arrays = read_pcd(path, colours)
    else:
        return read_graph(path)
    return check_graph_arrays(str(path), *arrays)


def check_reader_options(paths, label_field=None, colour_table=None, class_table=None) -> None:
    """Refuse a reader option that applies to none of the graph files `paths` (rather than
    ignore it): --label-field to .ply/.csv/.txt, --colour-table to .pcd/.ply, --class-table to
    .csv/.txt."""
    from sgloc.errors import GraphFileError

    suffixes = {Path(p).suffix.lower() for p in paths}
    options = [
        (label_field, "--label-field", (".ply", ".csv", ".txt")),
        (colour_table, "--colour-table", (".pcd", ".ply")),
        (class_table, "--class-table", (".csv", ".txt")),
    ]
    for value, option, kinds in options:
        if value is not None and not suffixes & set(kinds):
            raise GraphFileError(
                f"{option} applies to {'/'.join(kinds)} graphs only, and none is given "
                f"({', '.join(str(p) for p in paths)}); drop it."
            )


def read_graph_file(
    path: str | Path,
    edge_radius: float | None = None,
    label_field: str | None = None,
    colour_table: str | Path | None = None,
    class_table: str | Path | None = None,
) -> SemanticGraph:
    """The SemanticGraph of a graph file read with the reader options (`read_graph_with`),
    edges within `edge_radius` (m; None: `DEFAULT_EDGE_RADIUS`), named by the file's name."""
    from sgloc.maps.graph import DEFAULT_EDGE_RADIUS, SemanticGraph

    positions, labels = read_graph_with(path, label_field, colour_table, class_table)
    radius = DEFAULT_EDGE_RADIUS if edge_radius is None else edge_radius
    return SemanticGraph(positions, labels, radius, name=Path(path).name)
