"""`sgloc build-graph DATASET PATH -o GRAPH`: extract a robot's semantic graph with any loader."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn

from sgloc.cli.app import app
from sgloc.cli.options import file_path
from sgloc.cli.outputs import claim_output
from sgloc.cli.progress import progress_bar
from sgloc.datasets import DATASETS
from sgloc.io.graph_files import check_graph_suffix

Dataset = Annotated[str, typer.Argument(help=f"Loader name: {' | '.join(sorted(DATASETS))}.")]
Folder = Annotated[Path, typer.Argument(
    metavar="FOLDER", help="Dataset folder (or run folder with robot folders)."
)]
Out = Annotated[Path, typer.Option(
    "-o", "--out", parser=file_path, metavar="<path>",
    help="Graph file to write (.pcd .json .npz .ply .csv .txt); a new path: sgloc never "
    "writes over an existing file."
)]
Robot = Annotated[str | None, typer.Option(
    help="Robot folder (airsim) or camera (synthia: Omni_F | Omni_B)."
)]
Frames = Annotated[str | None, typer.Option(
    "--frames", "--scans", help="Frame range FIRST-LAST inclusive, e.g. 0-800."
)]
StartFrame = Annotated[bool | None, typer.Option(
    "--start-frame/--world-frame",
    help="Express the map in the first frame's sensor frame (robot-local) or the dataset's.",
)]
AssociationRadius = Annotated[float | None, typer.Option(
    "--association-radius", "--merge-distance", help="Association radius (m)."
)]
MinObservations = Annotated[int | None, typer.Option(help="Drop vertices seen fewer times.")]
MaxDepth = Annotated[float | None, typer.Option(help="Ignore pixels deeper than this (m).")]
MinPixels = Annotated[int | None, typer.Option(help="Smallest region at 1024x576 (scaled).")]
Position = Annotated[str | None, typer.Option(help="Vertex position rule: mean | centre.")]
MaxRange = Annotated[float | None, typer.Option(help="Ignore detections farther (m).")]
EdgeRadius = Annotated[float | None, typer.Option(help="Graph edge radius (m).")]
Preset = Annotated[str | None, typer.Option(
    help="Extraction preset (sgloc.pipeline.presets; default: the one named like DATASET)."
)]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")]


@app.command("build-graph")
def build_graph_cmd(
    ctx: typer.Context,
    dataset: Dataset,
    path: Folder,
    out: Out,
    robot: Robot = None,
    frames: Frames = None,
    start_frame: StartFrame = None,
    association_radius: AssociationRadius = None,
    min_observations: MinObservations = None,
    max_depth: MaxDepth = None,
    min_pixels: MinPixels = None,
    position: Position = None,
    max_range: MaxRange = None,
    edge_radius: EdgeRadius = None,
    preset: Preset = None,
    quiet: Quiet = False,
) -> None:
    """Build a robot's semantic graph from a dataset's frames and write it to a file.

    Example: sgloc build-graph kitti_objects "$(sgloc data path kitti00)" --scans 0-800
    --start-frame -o A.json
    """
    from sgloc.extraction.graph_job import graph_job  # deferred: scipy.ndimage, extraction

    loader = {"robot": robot, "frames": frames, "start_frame": start_frame}
    job = graph_job(
        dataset, preset, loader, association_radius=association_radius,
        min_observations=min_observations, max_depth=max_depth, min_pixels=min_pixels,
        position=position, max_range=max_range, edge_radius=edge_radius,
    )
    claim_output(ctx, out, [path], folder=False)
    check_graph_suffix(out)  # the format: before the extraction
    columns = (TextColumn("[bold]extracting"), BarColumn(), MofNCompleteColumn(),
               TimeRemainingColumn())
    with progress_bar(*columns, console=Console(stderr=True), disable=quiet) as progress:
        graph, frames_read = job.run(path, out, progress)
    per_class = dict(sorted(Counter(graph.labels.tolist()).items()))
    Console().print(f"{graph} from {frames_read} frames -> {out}\nvertices per class: {per_class}")
