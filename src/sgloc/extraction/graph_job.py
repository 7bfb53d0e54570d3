"""A robot's graph extracted from a data set and written to a file (`sgloc build-graph`): the
loader chosen by name with its own options, an extraction preset with overrides, the graph saved
through a temporary file."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sgloc.errors import DatasetError, SglocError, UnknownNameError
from sgloc.extraction.builder import build_graph
from sgloc.extraction.config import ExtractionConfig, extraction_preset
from sgloc.maps.graph import SemanticGraph

#: The loader options every loader may take, by the command line's names; `frames` is passed as
#: `scans` to a loader that counts scans.
LOADER_OPTIONS = ("robot", "frames", "start_frame")


@dataclass(frozen=True)
class GraphJob:
    """A checked extraction: the loader's registered name, its own options, the config."""

    dataset: str
    options: dict[str, Any] = field(default_factory=dict)
    config: ExtractionConfig = field(default_factory=ExtractionConfig)

    def run(
        self, path: str | Path, out: str | Path, progress: Callable[[int, int], None] | None = None
    ) -> tuple[SemanticGraph, int]:
        """Extract the graph from the data set at `path` and write it to `out` (any format
        SemanticGraph.save writes; a new file, written through a temporary one). Returns the
        graph and the number of frames read; `progress(done, total)` follows the frames.
        DatasetError when no object was extracted (nothing is written)."""
        from sgloc.datasets import make_dataset
        from sgloc.io.files import staged_file

        ds = make_dataset(self.dataset, path, **self.options)
        total, done = len(ds), [0]

        def step(_frame: Any) -> None:
            done[0] += 1
            progress(done[0], total)

        if progress is not None:
            progress(0, total)
        graph = build_graph(ds, self.config, Path(out).name, step if progress else None)
        if len(graph) == 0:
            raise DatasetError(
                f"no objects were extracted from {total} frames of {path}; check the images or "
                "lower --min-pixels / --min-observations."
            )
        with staged_file(Path(out), option="--out") as tmp:
            graph.save(tmp)
        return graph, total


def loader_options(dataset: str, given: dict[str, Any]) -> dict[str, Any]:
    """The options `given` (by LOADER_OPTIONS names; None: not given) under the loader's own
    parameter names; SglocError naming an option the loader does not take."""
    from sgloc.datasets import DATASETS

    if DATASETS.find(dataset) is None:
        raise UnknownNameError(DATASETS.unknown_message(dataset))
    key = DATASETS.key(dataset)
    params = set(inspect.signature(DATASETS[key]).parameters)
    out = {}
    for name, value in given.items():
        if value is None:
            continue
        target = ("scans" if "scans" in params else "frames") if name == "frames" else name
        if target not in params:
            raise SglocError(f"dataset {key!r} has no option --{name.replace('_', '-')}.")
        out[target] = value
    return out


def graph_job(
    dataset: str, preset: str | None = None, loader: dict[str, Any] | None = None, **settings: Any
) -> GraphJob:
    """The checked extraction of loader `dataset` with its options `loader` (see
    `loader_options`), the extraction preset `preset` (default: the one named like the loader)
    and the extraction `settings` given (None: the preset's value). Raises UnknownNameError or
    SglocError before anything is read."""
    from sgloc.pipeline.presets import EXTRACTION_PRESETS

    options = loader_options(dataset, loader or {})
    if preset is not None and EXTRACTION_PRESETS.find(preset) is None:
        raise UnknownNameError(EXTRACTION_PRESETS.unknown_message(preset))
    config = extraction_preset(preset or dataset).with_overrides(
        **{k: v for k, v in settings.items() if v is not None}
    )
    return GraphJob(dataset, options, config)
