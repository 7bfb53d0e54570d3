"""`sgloc localize Q T`: localize one graph file against another."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from sgloc.cli.app import app, not_localized
from sgloc.graph import SemanticGraph
from sgloc.localizer import localize


@app.command("localize")
def localize_cmd(
    query: Path = typer.Argument(..., help="Query graph (.pcd, .json, .npz): the map to place."),
    target: Path = typer.Argument(..., help="Target graph: the map to place it in."),
    descriptor: str = typer.Option("histogram", help="histogram | random_walk | fast"),
    rejection: str = typer.Option("neighbor", help="neighbor | none | any registered rejector"),
    ransac_threshold: float = typer.Option(5.0, help="RANSAC inlier distance T_error (m)."),
    edge_radius: float = typer.Option(20.0, help="Graph edge radius (m)."),
    seed: int = typer.Option(0, min=0, help="Random seed."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the result as JSON here."),
) -> None:
    """Find T_target_query, the rigid transform from QUERY's frame into TARGET's.

    Example: sgloc localize cloud1.pcd cloud2.pcd --descriptor histogram --json out.json
    """
    q = SemanticGraph.load(query, edge_radius=edge_radius)
    t = SemanticGraph.load(target, edge_radius=edge_radius)
    res = localize(q, t, descriptor, rejection, ransac_threshold, seed)
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(res.to_dict(), indent=1))
    console = Console()
    console.print(f"query  {q}\ntarget {t}")
    console.print(
        f"candidates {len(res.candidates)}  after rejection {len(res.survivors)}  "
        f"final matches {len(res.matches)}"
    )
    table = Table("stage", "ms", title="timings")
    for k, v in res.timings.items():
        table.add_row(k, f"{v * 1e3:.2f}")
    console.print(table)
    if not res.success:
        raise not_localized(res.reason)
    with np.printoptions(precision=4, suppress=True):
        console.print(f"T_target_query =\n{res.transform}")
