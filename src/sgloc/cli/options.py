"""Options shared by several commands, as type aliases (`preset: Preset = None` declares
`--preset`): localizer settings (`--preset`, `--config`, `--set`), graph inputs
(`--label-field`, `--colour-table`, `--class-table`), `--seed`, `--edge-radius`; and the
localizer settings they give."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from sgloc.errors import SglocError
from sgloc.io.settings_file import read_settings_data
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.presets import LOCALIZER_PRESETS

PRESET_HELP = f"Named settings: {' | '.join(LOCALIZER_PRESETS)} (see sgloc.pipeline.presets)."
CONFIG_HELP = "Localizer settings from a YAML file (as written by --out DIR/config.yaml)."
SET_HELP = "A localizer setting NAME=VALUE (repeatable), e.g. --set tau=3 --set top_k=2."
LABEL_HELP = "Class column of .ply/.csv/.txt graphs: a field name or a 0-based column index."
COLOURS_HELP = "Colour table (lines `class r g b \\[name]`) for graphs whose classes are colours."
CLASSES_HELP = "Class table (lines `class_id name`; names match in any case)"

def file_path(raw: str) -> Path:
    """The path of an option that writes one file: refused when it ends with a slash (a
    folder's name, which the path type would silently drop)."""
    if raw.endswith(("/", "\\")):
        raise typer.BadParameter(f"{raw} ends with a slash, which names a folder; give the path "
                                 "of the file to write (a folder plus a file name).")
    return Path(raw)


# The shared options as type aliases: `preset: Preset = None` declares `--preset`.
Preset = Annotated[str | None, typer.Option("--preset", help=PRESET_HELP)]
ConfigFile = Annotated[Path | None, typer.Option("--config", help=CONFIG_HELP, exists=False)]
Settings = Annotated[
    list[str] | None, typer.Option("--set", metavar="NAME=VALUE", help=SET_HELP)
]
LabelField = Annotated[str | None, typer.Option(help=LABEL_HELP)]
ColourTable = Annotated[Path | None, typer.Option(help=COLOURS_HELP)]
ClassTable = Annotated[Path | None, typer.Option(
    "--class-table", help=f"{CLASSES_HELP} for .csv/.txt graphs whose classes are names."
)]
Seed = Annotated[int, typer.Option(min=0, help="Random seed.")]
EdgeRadius = Annotated[float | None, typer.Option(
    help="Graph edge radius (m); default 4 x the scene scale (20 m for streets)."
)]


ONLINE_PREFIX = "online."
ONLINE_SET_HELP = (f"{SET_HELP} online.NAME=VALUE sets the online session's OnlineConfig field "
                   "NAME (e.g. --set online.submap_length=60), odometry.NAME=VALUE the odometry "
                   "noise model's (e.g. --set odometry.translation_per_metre=0.002).")
OnlineSettings = Annotated[
    list[str] | None, typer.Option("--set", metavar="NAME=VALUE", help=ONLINE_SET_HELP)
]


def split_online_settings(items: list[str] | None) -> tuple[list[str], dict[str, Any]]:
    """(the localizer's --set items, the online session's settings) of `--set` items:
    `online.NAME` -> NAME, `odometry.NAME` kept (`OnlineConfig.with_overrides` reads both)."""
    from sgloc.online.config import ODOMETRY_PREFIX

    mine = [i for i in items or [] if i.startswith((ONLINE_PREFIX, ODOMETRY_PREFIX))]
    online = {k.removeprefix(ONLINE_PREFIX): v for k, v in parse_settings(mine).items()}
    return [i for i in items or [] if i not in mine], online


def parse_settings(items: list[str] | None) -> dict[str, Any]:
    """{NAME: value} from `NAME=VALUE` strings (`sgloc.io.settings_file.parse_assignments`)."""
    from sgloc.io.settings_file import parse_assignments

    return parse_assignments(items or [])


_NESTED = {"matching", "ransac", "acceptance", "descriptor_params", "rejection_params"}


def flat_settings(cfg: LocalizerConfig) -> dict[str, Any]:
    """The flat settings (as `--set` and `localize(**settings)` take them) in which `cfg`
    differs from the defaults: `LocalizerConfig().with_overrides(**flat) == cfg`."""
    return cfg.flat_settings()


def read_settings_file(path: Path) -> dict[str, Any]:
    """Flat settings from a YAML (or .json) file: either flat (`tau: 3`) or a whole
    LocalizerConfig as `--out DIR/config.yaml` holds it (then the settings that differ from the
    defaults). Read by `sgloc.io.settings_file`, as `LocalizerConfig.load` reads."""
    data = read_settings_data(path)
    if not isinstance(data, dict):
        raise SglocError(f"{path}: expected a mapping of settings (NAME: value).")
    bad = next((k for k in data if not isinstance(k, str)), None)
    if bad is not None:
        raise SglocError(f"{path}: setting name {bad!r} is not a name; write NAME: value lines.")
    if _NESTED & set(data):
        try:
            return flat_settings(LocalizerConfig.from_dict(data))
        except SglocError as e:
            raise type(e)(f"{path}: {e}") from None
    return data


def merged_settings(
    preset: str | None = None,
    config_file: Path | None = None,
    settings: list[str] | None = None,
    **named: Any,
) -> dict[str, Any]:
    """Flat settings in the order they apply: the YAML file, the preset, every --set, then the
    named options that were given (not None)."""
    from sgloc.pipeline.presets import localizer_settings

    out = read_settings_file(config_file) if config_file else {}
    out |= localizer_settings(preset) if preset else {}
    out |= parse_settings(settings or [])
    return out | {k: v for k, v in named.items() if v is not None}


def localizer_config(
    preset: str | None = None,
    config_file: Path | None = None,
    settings: list[str] | None = None,
    **named: Any,
) -> LocalizerConfig:
    """The LocalizerConfig a command runs with (`merged_settings` over the defaults); an error
    caused by a setting of `config_file` names that file."""
    merged = merged_settings(preset, config_file, settings, **named)
    try:
        return LocalizerConfig().with_overrides(**merged)
    except SglocError as e:
        if config_file is None:
            raise
        try:  # the same settings without the file's: do they pass?
            LocalizerConfig().with_overrides(**merged_settings(preset, None, settings, **named))
        except SglocError:
            raise e from None
        raise type(e)(f"{config_file}: {e}") from None
