"""Options shared by several commands: localizer settings (`--preset`, `--config`, `--set`)
and graph inputs (`--label-field`, `--colour-table`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from sgloc.config import LocalizerConfig
from sgloc.errors import SglocError
from sgloc.graph import SemanticGraph
from sgloc.presets import LOCALIZER_PRESETS

PRESET_HELP = f"Named settings: {' | '.join(LOCALIZER_PRESETS)} (see sgloc.presets)."
CONFIG_HELP = "Localizer settings from a YAML file (as written by --out DIR/config.yaml)."
SET_HELP = "A localizer setting NAME=VALUE (repeatable), e.g. --set tau=3 --set top_k=2."
LABEL_HELP = "Class column of .ply/.csv/.txt graphs: a field name or a 0-based column index."
COLOURS_HELP = "Colour table (lines `class r g b [name]`) for graphs whose classes are colours."


def preset_option() -> Any:
    return typer.Option(None, "--preset", help=PRESET_HELP)


def config_option() -> Any:
    return typer.Option(None, "--config", help=CONFIG_HELP, exists=False)


def set_option() -> Any:
    return typer.Option([], "--set", help=SET_HELP)


def parse_settings(items: list[str]) -> dict[str, Any]:
    """{NAME: value} from `NAME=VALUE` strings; values are read as YAML (3 -> int, a,b -> str,
    {0: 0.1} -> dict). Raises SglocError on an item without `=`."""
    import yaml

    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise SglocError(f"--set expects NAME=VALUE, got {item!r}.")
        key, text = item.split("=", 1)
        try:
            out[key.strip()] = yaml.safe_load(text)
        except yaml.YAMLError:
            out[key.strip()] = text
    return out


def localizer_config(
    preset: str | None = None,
    config_file: Path | None = None,
    settings: list[str] | None = None,
    **named: Any,
) -> LocalizerConfig:
    """The LocalizerConfig a command runs with: the YAML file (or the defaults), then the
    preset's settings, then every --set, then the named options that were given (not None)."""
    from sgloc.presets import localizer_settings

    cfg = LocalizerConfig.from_yaml(config_file) if config_file else LocalizerConfig()
    overrides = localizer_settings(preset) if preset else {}
    overrides |= parse_settings(settings or [])
    overrides |= {k: v for k, v in named.items() if v is not None}
    return cfg.with_overrides(**overrides) if overrides else cfg


def load_graph(
    path: Path,
    edge_radius: float = 20.0,
    label_field: str | None = None,
    colour_table: Path | None = None,
) -> SemanticGraph:
    """A graph file with the reader options of the command line."""
    from sgloc.io.inputs import read_graph_with

    positions, labels = read_graph_with(path, label_field=label_field, colour_table=colour_table)
    return SemanticGraph(positions, labels, edge_radius, name=Path(path).name)
