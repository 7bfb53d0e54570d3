"""`sgloc fleet GRAPH...`: localize every pair of robots and place the fleet in one frame."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from sgloc.cli.app import app, not_localized
from sgloc.cli.options import (
    ClassTable,
    ColourTable,
    ConfigFile,
    EdgeRadius,
    LabelField,
    Preset,
    Seed,
    Settings,
    localizer_config,
)
from sgloc.cli.outputs import claim_output

if TYPE_CHECKING:
    from sgloc.online.fleet import FleetResult

Graphs = Annotated[list[Path], typer.Argument(
    metavar="GRAPH",
    help="Two or more robot graphs (.pcd .ply .csv .txt .json .npz)."
)]
Scheduler = Annotated[str | None, typer.Option(
    help="Address of an existing Dask scheduler (needs pip install 'sgloc\\[dask]'); "
    "default: local processes.",
)]
Out = Annotated[Path, typer.Option(
    help="Results folder (new, empty or an earlier one of sgloc) for merged.json, "
    "fleet.json, poses.tum, poses.kitti, poses/, links.g2o, config.yaml, fleet.png.",
)]
Root = Annotated[str | None, typer.Option(
    help="Robot whose frame is the fleet frame, by name (the file's stem; parent-stem when "
    "two files share a stem). Default: the best-connected robot of the largest group.",
)]
MinConfidence = Annotated[float | None, typer.Option(
    help="Acceptance strictness for each pair, 0-1 (default: the library's 0.9999)."
)]
Workers = Annotated[int | None, typer.Option(
    min=0, help="Local processes (default: CPU count; 0: in this process)."
)]


@app.command("fleet")
def fleet_cmd(
    ctx: typer.Context,
    graphs: Graphs,
    scheduler: Scheduler = None,
    out: Out = Path("results/fleet"),
    root: Root = None,
    min_confidence: MinConfidence = None,
    workers: Workers = None,
    edge_radius: EdgeRadius = None,
    seed: Seed = 0,
    preset: Preset = None,
    config: ConfigFile = None,
    setting: Settings = None,
    label_field: LabelField = None,
    colour_table: ColourTable = None,
    class_table: ClassTable = None,
) -> None:
    """Place N robots' graphs in one common frame and merge their maps.

    Every pair is localized (in parallel), pairs failing the acceptance test are dropped, links
    that disagree around loops are dropped, a pose graph over the remaining links places the
    robots, and the robots that cannot be placed are reported. Robots are named by their file's
    stem (r1/map.pcd and r2/map.pcd: r1-map and r2-map).

    Example: sgloc fleet a.pcd b.pcd c.json d.npz --out results/fleet --scheduler
    tcp://10.0.0.5:8786
    """
    from sgloc.online.fleet import FleetConfig  # deferred: the fleet layer, scipy.sparse.csgraph
    from sgloc.online.fleet_files import localize_fleet_files

    claim_output(ctx, out, [*graphs, config, colour_table, class_table])
    localizer = localizer_config(preset, config, setting, min_confidence=min_confidence)
    res = localize_fleet_files(
        graphs, FleetConfig(localizer=localizer, seed=seed), edge_radius=edge_radius,
        label_field=label_field, colour_table=colour_table, class_table=class_table, root=root,
        scheduler=scheduler, workers=workers, out=out,
    )
    _print(res, out)


def _print(res: FleetResult, out: Path) -> None:
    """The fleet's table and counts; exit 1 (not localized) when a robot was not placed."""
    console = Console()
    table = Table("robot", "placed", "x (m)", "y (m)", "yaw (deg)", "note", title="fleet")
    for i, name in enumerate(res.names):
        if i in res.T_fleet_robot:
            T = res.T_fleet_robot[i]
            yaw = np.degrees(np.arctan2(T[1, 0], T[0, 0]))
            note = "root (world frame)" if i == res.root else ""
            table.add_row(name, "yes", f"{T[0, 3]:.2f}", f"{T[1, 3]:.2f}", f"{yaw:.1f}", note)
        else:
            table.add_row(name, "NO", "", "", "", res.unplaced_reason.get(i, ""))
    console.print(table)
    kept = sum(lk.used in ("tree", "loop") for lk in res.links)
    dropped = sum(lk.used == "dropped" for lk in res.links)
    accepted = sum(lk.accepted for lk in res.links)
    console.print(
        f"pairs {len(res.links)}  accepted {accepted}  kept {kept}  dropped by loops {dropped}  "
        f"merged objects {len(res.merged) if res.merged is not None else 0}  "
        f"({res.timings['pairs']:.2f} s pairs)"
    )
    console.print(
        f"results in {out}/: merged.json, fleet.json, poses.tum, poses.kitti, poses/, "
        "links.g2o, config.yaml, fleet.png"
    )
    if len(res.T_fleet_robot) < len(res.names):
        unplaced = len(res.names) - len(res.T_fleet_robot)
        raise not_localized(f"{unplaced} of {len(res.names)} robots could not be placed.")
