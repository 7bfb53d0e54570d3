"""`sgloc localize Q T`: localize one graph file against another."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from sgloc.cli.app import app, compile_note, not_localized
from sgloc.cli.options import (
    COLOURS_HELP,
    LABEL_HELP,
    class_table_option,
    config_option,
    load_graph,
    localizer_config,
    preset_option,
    set_option,
)
from sgloc.cli.outputs import claim_output
from sgloc.io.files import staged_file, write_text_atomic
from sgloc.io.inputs import check_reader_options
from sgloc.io.results import (
    FORMATS,
    compact_json,
    document,
    is_result_document,
    render,
    write_results,
)
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.scale import AUTO, estimate_scale
from sgloc.pipeline.localizer import Localizer
from sgloc.pipeline.presets import at_estimated_scale


@app.command("localize")
def localize_cmd(
    ctx: typer.Context,
    query: Path | None = typer.Argument(
        None, help="Query graph (.pcd .ply .csv .txt .json .npz): the map to place."
    ),
    target: Path | None = typer.Argument(None, help="Target graph: the map to place it in."),
    example: bool = typer.Option(
        False, "--example", help="Use the Airsim maps shipped with sgloc (cloud1 in cloud2)."
    ),
    descriptor: str | None = typer.Option(
        None, help="distance_histogram (default) | triangles | histogram | random_walk | fast"
    ),
    rejection: str | None = typer.Option(None, help="neighbor | none | any registered rejector"),
    ransac_threshold: float | None = typer.Option(None, help="RANSAC inlier distance (m)."),
    preset: str | None = preset_option(),
    config: Path | None = config_option(),
    setting: list[str] = set_option(),
    edge_radius: float | None = typer.Option(
        None, help="Graph edge radius (m); default 4 x the scene scale (20 m for streets)."
    ),
    seed: int = typer.Option(0, min=0, help="Random seed."),
    label_field: str | None = typer.Option(None, help=LABEL_HELP),
    colour_table: Path | None = typer.Option(None, help=COLOURS_HELP),
    class_table: Path | None = class_table_option(),
    out: Path | None = typer.Option(
        None, help="Results folder: result.json, T_target_query*.txt, config.yaml, PNG."
    ),
    fmt: str | None = typer.Option(
        None, "--format", help=f"Print only the result to stdout as {' | '.join(FORMATS)}."
    ),
    json_out: Path | None = typer.Option(
        None, "--json", help="Write the full result as JSON here: result.json's fields plus "
        "every match, candidate and the configuration (docs/formats.md)."
    ),
    rerun: Path | None = typer.Option(
        None, "--rerun", help="Write both maps, the matches and the transform as a Rerun "
        "recording (.rrd; needs pip install 'sgloc\\[rerun]')."
    ),
) -> None:
    """Find T_target_query, the rigid transform from QUERY's frame into TARGET's
    (p_target = T @ p_query).

    Settings are applied in order: --config FILE, --preset NAME, each --set NAME=VALUE, then
    --descriptor / --rejection / --ransac-threshold.

    Examples: sgloc localize --example --out results/example |
    sgloc localize cloud1.pcd cloud2.pcd --format kitti > T.txt
    """
    if fmt is not None and fmt not in FORMATS:
        ctx.fail(f"Invalid value for '--format': {fmt!r} is not one of {', '.join(FORMATS)}.")
    if rerun is not None:
        from sgloc.optional import require

        require("rerun", "rerun", "--rerun (a Rerun recording)")  # fail before the work
    if example:
        if query is not None or target is not None:
            ctx.fail("give either two graph files (QUERY TARGET) or --example, not both.")
        from sgloc.datasets.downloads import airsim_guo_paths

        query, target = airsim_guo_paths()
    elif query is None or target is None:
        ctx.fail(
            "Missing argument 'QUERY TARGET': give two graph files, or --example for the "
            "shipped maps."
        )
    cfg = localizer_config(
        preset, config, setting,
        descriptor=descriptor, rejection=rejection, ransac_threshold=ransac_threshold,
    )
    check_reader_options([query, target], label_field, colour_table, class_table)
    inputs = [query, target, config, colour_table, class_table]
    claim_output(ctx, out, inputs)
    claim_output(ctx, json_out, inputs, "--json", folder=False, ours=is_result_document)
    claim_output(ctx, rerun, inputs, "--rerun", folder=False)
    radius = cfg.edge_radius if edge_radius is None else edge_radius
    q = load_graph(query, radius, label_field, colour_table, class_table)
    t = load_graph(target, radius, label_field, colour_table, class_table)
    if cfg.scale == AUTO and edge_radius is None:  # the edges of the estimated scene's scale
        radius = at_estimated_scale(cfg, estimate_scale(t)).edge_radius
        q, t = (SemanticGraph(g.positions, g.labels, radius, name=g.name) for g in (q, t))
    res = Localizer(cfg)(q, t, seed)
    cfg = res.settings or cfg  # with scale="auto": the estimated scale's
    info = {"query": str(query), "target": str(target), "seed": seed}
    if out is not None:
        names = _class_names(class_table, colour_table)

        def picture(folder: Path) -> Path:
            return _picture(folder / "aligned_maps.png", q, t, res, example, names)

        files = write_results(out, res, cfg, picture, **info)
    if rerun is not None:
        from sgloc.io.rerun_file import write_rerun

        T = res.transform if res.success else np.eye(4)
        with staged_file(rerun, inputs, "--rerun") as tmp:
            write_rerun(tmp, t, q, T, res.matches if res.success else np.zeros((0, 2)))
    if json_out is not None:
        text = compact_json(document(res, full=True, **info))
        write_text_atomic(json_out, text, inputs, "--json", ours=is_result_document)
    console = Console(stderr=fmt is not None)
    _report(console, q, t, res, example)
    if out is not None:
        console.print(f"results in {out}/: " + ", ".join(sorted(p.name for p in files.values())))
    if fmt is not None and (res.success or fmt == "json"):
        typer.echo(render(res, fmt, **info), nl=False)
    if not res.success:
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
    if res.success:
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


def _class_names(class_table: Path | None, colour_table: Path | None) -> list[str] | None:
    """Class names for the picture's legend (index = class id), from the class table or the
    colour table's names; None: "class k"."""
    if class_table is not None:
        from sgloc.io.class_table import class_names_by_id, read_class_table

        return class_names_by_id(read_class_table(class_table))
    if colour_table is not None:
        from sgloc.io.colour_table import read_colour_table

        return read_colour_table(colour_table)[1]
    return None


def _picture(path: Path, q, t, res, example: bool, names: list[str] | None = None) -> Path:
    from sgloc.io.pictures import plot_aligned_maps

    if res.success:
        conf = "" if res.confidence is None else f", confidence {res.confidence:.3f}"
        title = f"{t.name} (A) and {q.name} (B) aligned{conf}"
        if example:
            from sgloc.geometry import transform_error

            te, re = transform_error(res.transform, np.eye(4))
            title += f"\nerror vs ground truth {te:.2f} m / {re:.2f}°"
        T = res.transform
    else:
        title = f"not localized: {res.reason}\nB shown in its own frame (no transform)"
        T = np.eye(4)
    return plot_aligned_maps(t, q, T, res.matches if res.success else [], path, title, names)
