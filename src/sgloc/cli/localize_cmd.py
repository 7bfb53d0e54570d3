"""`sgloc localize Q T`: localize one graph file against another."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from sgloc.cli.app import app, compile_note, not_localized
from sgloc.cli.options import (
    ClassTable,
    ColourTable,
    ConfigFile,
    EdgeRadius,
    LabelField,
    Preset,
    Seed,
    Settings,
    file_path,
    localizer_config,
)
from sgloc.cli.outputs import claim_output
from sgloc.io.inputs import check_reader_options
from sgloc.io.results import FORMATS, is_result_document, render
from sgloc.pipeline.on_files import FileLocalization, localize_files

Query = Annotated[Path | None, typer.Argument(
    help="Query graph (.pcd .ply .csv .txt .json .npz): the map to place."
)]
Target = Annotated[Path | None, typer.Argument(help="Target graph: the map to place it in.")]
Example = Annotated[bool, typer.Option(
    "--example", help="Use the Airsim maps shipped with sgloc (cloud1 in cloud2)."
)]
Descriptor = Annotated[str | None, typer.Option(
    help="distance_histogram (default) | triangles | histogram | random_walk | fast"
)]
Rejection = Annotated[str | None, typer.Option(help="neighbor | none | any registered rejector")]
Threshold = Annotated[float | None, typer.Option(help="RANSAC inlier distance (m).")]
Out = Annotated[Path | None, typer.Option(
    help="Results folder: result.json, T_target_query*.txt, config.yaml, PNG."
)]
Format = Annotated[str | None, typer.Option(
    "--format", help=f"Print only the result to stdout as {' | '.join(FORMATS)}."
)]
JsonOut = Annotated[Path | None, typer.Option(
    "--json", parser=file_path, metavar="<path>",
    help="Write the full result as JSON here: result.json's fields plus every match, candidate "
    "and the configuration (docs/formats.md)."
)]
Rerun = Annotated[Path | None, typer.Option(
    "--rerun", parser=file_path, metavar="<path>",
    help="Write both maps, the matches and the transform as a Rerun recording (.rrd; needs "
    "pip install 'sgloc\\[rerun]')."
)]


@app.command("localize")
def localize_cmd(
    ctx: typer.Context,
    query: Query = None,
    target: Target = None,
    example: Example = False,
    descriptor: Descriptor = None,
    rejection: Rejection = None,
    ransac_threshold: Threshold = None,
    preset: Preset = None,
    config: ConfigFile = None,
    setting: Settings = None,
    edge_radius: EdgeRadius = None,
    seed: Seed = 0,
    label_field: LabelField = None,
    colour_table: ColourTable = None,
    class_table: ClassTable = None,
    out: Out = None,
    fmt: Format = None,
    json_out: JsonOut = None,
    rerun: Rerun = None,
) -> None:
    """Find T_target_query, the rigid transform from QUERY's frame into TARGET's
    (p_target = T @ p_query).

    Settings are applied in order: --config FILE, --preset NAME, each --set NAME=VALUE, then
    --descriptor / --rejection / --ransac-threshold.

    Examples: sgloc localize --example --out results/example |
    sgloc localize cloud1.pcd cloud2.pcd --format kitti > T.txt
    """
    query, target, truth = _graph_paths(ctx, query, target, example, fmt, rerun)
    cfg = localizer_config(preset, config, setting, descriptor=descriptor, rejection=rejection,
                           ransac_threshold=ransac_threshold)
    check_reader_options([query, target], label_field, colour_table, class_table)
    _claim(ctx, [query, target, config, colour_table, class_table], out, json_out, rerun)
    done = localize_files(query, target, cfg, seed, edge_radius=edge_radius, out=out, rerun=rerun,
                          label_field=label_field, colour_table=colour_table,
                          class_table=class_table, json_out=json_out, truth=truth, inputs=[config])
    _print(done, out, fmt, example)


def _graph_paths(ctx: typer.Context, query, target, example: bool, fmt, rerun):
    """(query, target, the true T_target_query or None) of the command line; usage errors for
    a bad --format, both graphs and --example, or neither; --rerun without its extra fails."""
    if fmt is not None and fmt not in FORMATS:
        ctx.fail(f"Invalid value for '--format': {fmt!r} is not one of {', '.join(FORMATS)}.")
    if rerun is not None:
        from sgloc.optional import require

        require("rerun", "rerun", "--rerun (a Rerun recording)")  # fail before the work
    if example:
        if query is not None or target is not None:
            ctx.fail("give either two graph files (QUERY TARGET) or --example, not both.")
        from sgloc.datasets.downloads import airsim_guo_paths

        return (*airsim_guo_paths(), np.eye(4))  # both maps in one frame: the truth is I
    if query is None or target is None:
        ctx.fail(
            "Missing argument 'QUERY TARGET': give two graph files, or --example for the "
            "shipped maps."
        )
    return query, target, None


def _claim(ctx: typer.Context, inputs: list, out, json_out, rerun) -> None:
    claim_output(ctx, out, inputs)
    claim_output(ctx, json_out, inputs, "--json", folder=False, ours=is_result_document)
    claim_output(ctx, rerun, inputs, "--rerun", folder=False)


def _print(done: FileLocalization, out: Path | None, fmt: str | None, example: bool) -> None:
    """The report (on stderr with --format), the result in --format; exit 1 if not localized."""
    res = done.result
    console = Console(stderr=fmt is not None)
    _report(console, done.query, done.target, res, example)
    if out is not None:
        files = sorted(p.name for p in done.files.values())
        console.print(f"results in {out}/: " + ", ".join(files))
    if fmt is not None and (res.accepted or fmt == "json"):
        typer.echo(render(res, fmt, **done.info), nl=False)
    if not res.accepted:
        raise not_localized(res.reason)


def _report(console: Console, q, t, res, example: bool) -> None:
    console.print(f"query  {q}\ntarget {t}")
    console.print(
        f"candidates {len(res.candidates)}  after rejection {len(res.survivors)}  "
        f"final matches {len(res.matches)}"
    )
    table = Table("stage", "ms", title="timings")
    for k, v in res.timings.items():
        table.add_row(k, f"{v * 1e3:.2f}")
    console.print(table)
    console.print(scale_line(res))
    if note := compile_note():
        console.print(note)
    if res.accepted:
        conf = "n/a" if res.confidence is None else f"{res.confidence:.4f}"
        with np.printoptions(precision=4, suppress=True):
            console.print(f"confidence {conf}\nT_target_query =\n{res.transform}")
        if example:
            from sgloc.geometry import transform_error, translation_error_at

            te, re = transform_error(res.transform, np.eye(4))
            tc = translation_error_at(res.transform, np.eye(4), q.positions.mean(axis=0))
            console.print(
                f"error against the ground truth (identity): {te:.2f} m at the target's origin, "
                f"{tc:.2f} m at the query objects' centroid, {re:.2f} deg (docs/formats.md)"
            )


def scale_line(res) -> str:
    """The scene scale a result used, and whether it was given or estimated (and from what)."""
    est = res.scale_estimate
    if est is None:
        unit = res.settings.scale if res.settings is not None else float("nan")
        return f"scene scale {unit:g} m (given)"
    return (
        f"scene scale {est.unit:g} m (estimated from the target map: {est.scene}; objects a "
        f"median {est.spacing:.2f} m apart, {est.extent:.0f} m across)"
    )
