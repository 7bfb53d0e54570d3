"""The fleet of robots' graph files (`sgloc fleet`): each file read with the reader options, the
robots named by their files' stems, the fleet placed and written (`sgloc.online.fleet`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from sgloc.online.fleet import FleetConfig, FleetResult, localize_fleet


def localize_fleet_files(
    paths: Sequence[str | Path],
    config: FleetConfig | None = None,
    *,
    edge_radius: float | None = None,
    label_field: str | None = None,
    colour_table: str | Path | None = None,
    class_table: str | Path | None = None,
    root: str | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    out: str | Path | None = None,
) -> FleetResult:
    """`localize_fleet` on the graph files `paths`, read with the reader options
    (`sgloc.io.inputs.read_graph_with`; an option that applies to none of the files is refused),
    edges within `edge_radius` m (default: the localizer's), each robot named by its file's stem
    (parent-stem when two files share a stem)."""
    from sgloc.io.inputs import check_reader_options, read_graph_file
    from sgloc.io.names import robot_names

    cfg = config or FleetConfig()
    check_reader_options(paths, label_field, colour_table, class_table)
    radius = cfg.localizer.edge_radius if edge_radius is None else edge_radius
    graphs = [read_graph_file(p, radius, label_field, colour_table, class_table) for p in paths]
    return localize_fleet(graphs, cfg, names=robot_names(paths), root=root, scheduler=scheduler,
                          workers=workers, out=out)
