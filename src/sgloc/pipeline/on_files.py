"""One graph file localized in another (`sgloc localize`): both files read with the reader
options, the localizer run, and the outputs asked for written: a results folder with a picture
of the aligned maps, the full JSON document, a Rerun recording."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.maps.graph import SemanticGraph
from sgloc.maps.scale import AUTO, estimate_scale
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.localizer import LocalizationResult, Localizer
from sgloc.pipeline.presets import at_estimated_scale


@dataclass(frozen=True)
class FileLocalization:
    """A localization of graph files: the graphs read (query, target), the result, the fields
    naming the run in every output (`info`: query, target, seed), the results folder's files by
    kind (empty without a folder) and the ground truth T_target_query when known."""

    query: SemanticGraph
    target: SemanticGraph
    result: LocalizationResult
    info: dict[str, Any]
    files: dict[str, Path] = field(default_factory=dict)
    truth: np.ndarray | None = None


def localize_files(
    query: str | Path,
    target: str | Path,
    config: LocalizerConfig | None = None,
    seed: int = 0,
    *,
    edge_radius: float | None = None,
    label_field: str | None = None,
    colour_table: str | Path | None = None,
    class_table: str | Path | None = None,
    out: str | Path | None = None,
    json_out: str | Path | None = None,
    rerun: str | Path | None = None,
    truth: np.ndarray | None = None,
    inputs: Sequence[str | Path | None] = (),
) -> FileLocalization:
    """Place the graph file `query` in `target` (`Localizer(config)`, edges within `edge_radius`
    m, default the config's; reader options as `sgloc.io.inputs.read_graph_with` takes them)
    and write: the results folder `out` (`sgloc.io.results.write_results`, with a picture),
    the full JSON document `json_out`, the Rerun recording `rerun`. `truth`: the known
    T_target_query, shown in the picture's title; `inputs`: other input files no output may
    replace."""
    from sgloc.io.inputs import check_reader_options, read_graph_file

    cfg = config or LocalizerConfig()
    check_reader_options([query, target], label_field, colour_table, class_table)
    radius = cfg.edge_radius if edge_radius is None else edge_radius
    q = read_graph_file(query, radius, label_field, colour_table, class_table)
    t = read_graph_file(target, radius, label_field, colour_table, class_table)
    if cfg.scale == AUTO and edge_radius is None:  # the edges of the estimated scene's scale
        radius = at_estimated_scale(cfg, estimate_scale(t)).edge_radius
        q, t = (SemanticGraph(g.positions, g.labels, radius, name=g.name) for g in (q, t))
    res = Localizer(cfg)(q, t, seed)
    cfg = res.settings or cfg  # with scale="auto": the estimated scale's
    done = FileLocalization(q, t, res, {"query": str(query), "target": str(target), "seed": seed},
                            truth=truth)
    kept = [query, target, *inputs, colour_table, class_table]
    if out is not None:
        names = class_names(class_table, colour_table)
        done.files.update(_write_folder(Path(out), done, cfg, names))
    _write_files(done, json_out, rerun, kept)
    return done


def _write_folder(out: Path, done: FileLocalization, cfg: LocalizerConfig,
                  names: list[str] | None) -> dict[str, Path]:
    from sgloc.io.results import write_results

    def picture(folder: Path) -> Path:
        return aligned_picture(folder / "aligned_maps.png", done, names)

    return write_results(out, done.result, cfg, picture, **done.info)


def _write_files(done: FileLocalization, json_out, rerun, inputs: list) -> None:
    """The Rerun recording and the full JSON document, when asked for."""
    from sgloc.io.files import staged_file, write_text_atomic
    from sgloc.io.results import compact_json, document, is_result_document

    res = done.result
    if rerun is not None:
        from sgloc.io.rerun_file import write_rerun

        T = res.transform if res.accepted else np.eye(4)
        with staged_file(rerun, inputs, "--rerun") as tmp:
            write_rerun(tmp, done.target, done.query, T,
                        res.matches if res.accepted else np.zeros((0, 2)))
    if json_out is not None:
        text = compact_json(document(res, full=True, **done.info))
        write_text_atomic(json_out, text, inputs, "--json", ours=is_result_document)


def class_names(class_table: str | Path | None,
                colour_table: str | Path | None) -> list[str] | None:
    """Class names for the picture's legend (index = class id), from the class table or the
    colour table's names; None: "class k"."""
    if class_table is not None:
        from sgloc.io.class_table import class_names_by_id, read_class_table

        return class_names_by_id(read_class_table(class_table))
    if colour_table is not None:
        from sgloc.io.colour_table import read_colour_table

        return read_colour_table(colour_table)[1]
    return None


def aligned_picture(path: Path, done: FileLocalization, names: list[str] | None = None) -> Path:
    """The PNG of the two maps aligned by the result (`sgloc.io.pictures.plot_aligned_maps`),
    its title with the confidence and, when the truth is known, the error against it."""
    from sgloc.io.pictures import plot_aligned_maps

    q, t, res = done.query, done.target, done.result
    if res.accepted:
        conf = "" if res.confidence is None else f", confidence {res.confidence:.3f}"
        title = f"{t.name} (A) and {q.name} (B) aligned{conf}"
        if done.truth is not None:
            from sgloc.geometry import transform_error

            te, re = transform_error(res.transform, done.truth)
            title += f"\nerror vs ground truth {te:.2f} m / {re:.2f}°"
        T = res.transform
    else:
        title = f"not localized: {res.reason}\nB shown in its own frame (no transform)"
        T = np.eye(4)
    return plot_aligned_maps(t, q, T, res.matches if res.accepted else [], path, title, names)
