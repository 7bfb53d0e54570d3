"""Where the real data lives: `$SGLOC_DATA`, default `../shared/data` beside the project."""

from __future__ import annotations

import os
from pathlib import Path

from sgloc.errors import DatasetError

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def data_root(must_exist: bool = True) -> Path:
    """The data folder: `$SGLOC_DATA`, else `<project>/../shared/data`."""
    env = os.environ.get("SGLOC_DATA")
    root = Path(env) if env else PROJECT_ROOT.parent / "shared" / "data"
    if must_exist and not root.is_dir():
        raise DatasetError(
            f"data folder {root} not found; set SGLOC_DATA to the folder holding airsim_guo/ "
            "and kitti00/."
        )
    return root


def data_path(*parts: str) -> Path:
    """A path inside the data folder; raises DatasetError naming it when it is missing."""
    p = data_root().joinpath(*parts)
    if not p.exists():
        raise DatasetError(f"{p} not found; is SGLOC_DATA ({data_root()}) the right folder?")
    return p
