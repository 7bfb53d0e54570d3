"""`sgloc build-graph DATASET PATH -o GRAPH`: extract a robot's semantic graph with any loader."""

from __future__ import annotations

import inspect
from collections import Counter
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from sgloc.cli.app import app, fail
from sgloc.cli.outputs import claim_output
from sgloc.datasets import DATASETS, make_dataset
from sgloc.extraction import build_graph, extraction_preset


def _loader_options(dataset: str, given: dict) -> dict:
    """Route CLI options to the loader's own parameter names; fail on unsupported ones."""
    if DATASETS.find(dataset) is None:
        raise fail(DATASETS.unknown_message(dataset))
    key = DATASETS.key(dataset)
    params = set(inspect.signature(DATASETS[key]).parameters)
    out = {}
    for name, value in given.items():
        if value is None:
            continue
        if name == "frames":
            target = "scans" if "scans" in params else "frames"
        elif name == "robot":
            target = "robot"
        else:
            target = name
        if target not in params:
            raise fail(f"dataset {key!r} has no option --{name.replace('_', '-')}.")
        out[target] = value
    return out


@app.command("build-graph")
def build_graph_cmd(
    ctx: typer.Context,
    dataset: str = typer.Argument(..., help=f"Loader name: {' | '.join(sorted(DATASETS))}."),
    path: Path = typer.Argument(..., help="Dataset folder (or run folder with robot folders)."),
    out: Path = typer.Option(
        ..., "-o", "--out", help="Graph file to write (.pcd .json .npz .ply .csv .txt); a new "
        "path: sgloc never writes over an existing file."
    ),
    robot: str | None = typer.Option(
        None, help="Robot folder (airsim) or camera (synthia: Omni_F | Omni_B)."
    ),
    frames: str | None = typer.Option(
        None, "--frames", "--scans", help="Frame range FIRST-LAST inclusive, e.g. 0-800."
    ),
    start_frame: bool | None = typer.Option(
        None,
        "--start-frame/--world-frame",
        help="Express the map in the first frame's sensor frame (robot-local) or the dataset's.",
    ),
    association_radius: float | None = typer.Option(
        None, "--association-radius", "--merge-distance", help="Association radius (m)."
    ),
    min_observations: int | None = typer.Option(None, help="Drop vertices seen fewer times."),
    max_depth: float | None = typer.Option(None, help="Ignore pixels deeper than this (m)."),
    min_pixels: int | None = typer.Option(None, help="Smallest region at 1024x576 (scaled)."),
    position: str | None = typer.Option(None, help="Vertex position rule: mean | centre."),
    max_range: float | None = typer.Option(None, help="Ignore detections farther (m)."),
    edge_radius: float | None = typer.Option(None, help="Graph edge radius (m)."),
    preset: str | None = typer.Option(
        None,
        help="Extraction preset (sgloc.pipeline.presets; default: the one named like DATASET)."
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Build a robot's semantic graph from a dataset's frames and write it to a file.

    Example: sgloc build-graph kitti_objects "$(sgloc data path kitti00)" --scans 0-800
    --start-frame -o A.json
    """
    options = _loader_options(
        dataset, {"robot": robot, "frames": frames, "start_frame": start_frame}
    )
    overrides = {
        "association_radius": association_radius,
        "min_observations": min_observations,
        "max_depth": max_depth,
        "min_pixels": min_pixels,
        "position": position,
        "max_range": max_range,
        "edge_radius": edge_radius,
    }
    from sgloc.pipeline.presets import EXTRACTION_PRESETS

    if preset is not None and EXTRACTION_PRESETS.find(preset) is None:
        raise fail(EXTRACTION_PRESETS.unknown_message(preset))
    config = extraction_preset(preset or dataset).with_overrides(
        **{k: v for k, v in overrides.items() if v is not None}
    )
    claim_output(ctx, out, [path], folder=False)
    ds = make_dataset(dataset, path, **options)
    console = Console(stderr=True)
    with Progress(
        TextColumn("[bold]extracting"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        disable=quiet,
    ) as bar:
        task = bar.add_task("frames", total=len(ds))
        graph = build_graph(ds, config, name=out.name, progress=lambda _f: bar.advance(task))
    if len(graph) == 0:
        raise fail(
            f"no objects were extracted from {len(ds)} frames of {path}; check the images or "
            "lower --min-pixels / --min-observations."
        )
    written = _save(graph, out)
    per_class = dict(sorted(Counter(graph.labels.tolist()).items()))
    Console().print(f"{graph} from {len(ds)} frames -> {written}\nvertices per class: {per_class}")


def _save(graph, out: Path) -> Path:
    """Write the graph (every format SemanticGraph.save writes) through a temporary file."""
    from sgloc.io.files import staged_file

    with staged_file(out, option="--out") as tmp:
        graph.save(tmp)
    return out
