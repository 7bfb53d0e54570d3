"""The one reader of settings files (localizer configs, `--config`): YAML, or JSON for a
`.json` file; a regular file of bounded size; a UTF-8 byte-order mark ignored; every failure an
SglocError naming the file."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sgloc.errors import SglocError
from sgloc.io.files import MAX_TEXT_FILE_BYTES, read_regular_file
from sgloc.io.text import BOM


def is_json(path: str | Path) -> bool:
    """True for a `.json` file (JSON), False for any other (YAML)."""
    return Path(path).suffix.lower() == ".json"


def read_settings_data(path: str | Path, kind: str | None = None) -> Any:
    """The parsed contents of the settings file `path`: `kind` "JSON" or "YAML" (default: JSON
    for `.json`, YAML otherwise; an empty YAML file reads as {}); SglocError when it is missing,
    too large or not parseable."""
    import yaml  # deferred: `import sgloc` reads no settings file

    kind = kind or ("JSON" if is_json(path) else "YAML")
    raw = read_regular_file(path, f"{kind} config file", MAX_TEXT_FILE_BYTES, SglocError)
    try:
        text = raw.decode("utf-8").removeprefix(BOM)
        return json.loads(text) if kind == "JSON" else (yaml.safe_load(text) or {})
    except (ValueError, yaml.YAMLError, UnicodeDecodeError, RecursionError) as e:
        raise SglocError(f"{path}: not a valid {kind} config ({type(e).__name__}).") from None


def write_settings_data(path: str | Path, data: Any, kind: str | None = None) -> None:
    """Write `data` (plain values) to `path` as `kind` "JSON" (mapping keys as strings) or
    "YAML" (default: JSON for `.json`, YAML otherwise)."""
    if (kind or ("JSON" if is_json(path) else "YAML")) == "JSON":
        Path(path).write_text(json.dumps(_json_ready(data), indent=2) + "\n")
    else:
        import yaml

        Path(path).write_text(yaml.safe_dump(data, sort_keys=False))


def _json_ready(data: Any) -> Any:
    """`data` with mapping keys as strings (JSON's only key type)."""
    if isinstance(data, dict):
        return {str(k): _json_ready(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [_json_ready(v) for v in data]
    return data


def parse_assignments(items: Sequence[str]) -> dict[str, Any]:
    """{NAME: value} from `NAME=VALUE` strings (`--set`, `--param`); values are read as YAML
    (3 -> int, a,b -> str, {0: 0.1} -> dict; none/None -> None). SglocError on an item
    without `=`."""
    if not items:  # the usual command line: no YAML reader to load
        return {}
    import yaml

    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise SglocError(f"--set expects NAME=VALUE, got {item!r}.")
        key, text = item.split("=", 1)
        if text.strip() in ("none", "None"):  # YAML's null, as Python users write it
            out[key.strip()] = None
            continue
        try:
            out[key.strip()] = yaml.safe_load(text)
        except yaml.YAMLError:
            out[key.strip()] = text
    return out
