"""A localization result in standard forms: a 4x4 matrix, a KITTI pose line, a TUM pose line,
a compact JSON summary; and the results folder `sgloc localize --out DIR` writes."""

from __future__ import annotations

import json
import re
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.io.files import naming, staged_folder
from sgloc.io.poses import write_kitti_poses, write_tum_poses

FORMATS = ("kitti", "tum", "json", "matrix")
#: File names in a results folder, by format.
FILES = {
    "matrix": "T_target_query.txt",
    "kitti": "T_target_query_kitti.txt",
    "tum": "T_target_query_tum.txt",
    "json": "result.json",
}


#: Version of the JSON result document (`--json`, result.json, `--format json`); docs/formats.md.
#: Version 2 renamed the key "success" of version 1 to "accepted" (`LocalizationResult.accepted`);
#: every other key means the same.
SCHEMA = "sgloc.result/2"


def is_result_document(path: Path) -> bool:
    """True if `path` holds a JSON result document sgloc wrote (`--json FILE`), of any schema
    version: it may be replaced by the next one."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096).decode("utf-8", "replace")
    except OSError:
        return False
    return re.match(r'\{\s*"schema":\s*"sgloc\.result/', head) is not None


def _array(a: Any, decimals: int | None = None) -> list | None:
    if a is None:
        return None
    a = np.asarray(a)
    return (np.round(a, decimals) if decimals is not None else a).tolist()


def summary(result: Any, **extra: Any) -> dict[str, Any]:
    """The JSON result document without per-match lists (result.json, `--format json`):
    schema, accepted, reason, confidence, T_target_query (4x4, metres), covariance (6x6 or
    None), counts, timings_ms, then `extra` (query, target, seed)."""
    d = {
        "schema": SCHEMA,
        "accepted": bool(result.accepted),
        "reason": result.reason,
        "confidence": None if result.confidence is None else round(float(result.confidence), 6),
        "T_target_query": _array(result.transform, 9),
        "covariance": _array(getattr(result, "covariance", None)),
        "n_candidates": int(len(result.candidates)),
        "n_survivors": int(len(result.survivors)),
        "n_matches": int(len(result.matches)),
        "timings_ms": {k: round(v * 1e3, 3) for k, v in result.timings.items()},
        "scale": scale_summary(result),
    }
    d.update(extra)
    return d


def scale_summary(result: Any) -> dict[str, Any] | None:
    """The scene scale a result used: {"unit_m", "estimated"} and, when estimated from the
    target map (scale="auto"), the "scene", "spacing_m" and "extent_m" it was estimated from;
    None for a result without its settings."""
    estimate = getattr(result, "scale_estimate", None)
    if estimate is not None:
        return estimate.to_dict()
    settings = getattr(result, "settings", None)
    if settings is None:
        return None
    return {"unit_m": float(settings.scale), "estimated": False}


def document(result: Any, full: bool = False, **extra: Any) -> dict[str, Any]:
    """The JSON result document: `summary`, and with `full` the index pairs (query index,
    target index) of the matches, survivors and candidates, the candidates' scores and the
    configuration (`--json FILE`, `LocalizationResult.to_dict`)."""
    d = summary(result, **extra)
    if full:
        for name in ("matches", "survivors", "candidates"):
            d[name] = np.asarray(getattr(result, name), dtype=np.int64).reshape(-1, 2).tolist()
        d["scores"] = _array(np.asarray(result.scores, dtype=np.float64), 9)
        d["config"] = result.config
    return d


#: An innermost JSON array (no nested array, object or string): printed on one line.
_INNER_ARRAY = re.compile(r"\[\s*([^\[\]{}\"]*?)\s*\]")


def compact_json(d: dict[str, Any]) -> str:
    """JSON with two-space indent, but each innermost array (a matrix row, a match) on one
    line."""
    text = json.dumps(d, indent=2)
    return _INNER_ARRAY.sub(lambda m: "[" + re.sub(r"\s*\n\s*", " ", m.group(1)) + "]", text) + "\n"


def write_matrix(path: str | Path, T: np.ndarray) -> Path:
    """Write a 4x4 transform as 4 rows of 4 numbers."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(p, np.asarray(T, dtype=np.float64).reshape(4, 4), fmt="%.9f")
    return p


def write_transform(path: str | Path, T: np.ndarray, fmt: str) -> Path:
    """Write T in `fmt`: matrix (4x4), kitti (one 12-value line), tum (`0 x y z qx qy qz qw`)."""
    if fmt == "kitti":
        return write_kitti_poses(path, np.asarray(T)[None])
    if fmt == "tum":
        return write_tum_poses(path, np.zeros(1), np.asarray(T)[None])
    return write_matrix(path, T)


def render(result: Any, fmt: str, **extra: Any) -> str:
    """The text `--format fmt` prints: one of FORMATS."""
    if fmt == "json":
        return compact_json(summary(result, **extra))
    with tempfile.TemporaryDirectory() as d:
        return write_transform(Path(d) / "T.txt", result.transform, fmt).read_text()


def write_results(
    out: str | Path,
    result: Any,
    config: Any,
    picture: Callable[[Path], Path] | None = None,
    **extra: Any,
) -> dict[str, Path]:
    """Write the results folder atomically: result.json, config.yaml and, when localized,
    T_target_query.txt (4x4), T_target_query_kitti.txt, T_target_query_tum.txt; `picture`
    (folder -> the PNG it wrote) adds a picture. Returns the files by kind."""
    out = Path(out)
    with staged_folder(out) as stage:  # the folder appears complete or not at all
        files = write_results_into(stage, result, config, **extra)
        if picture is not None:
            files["png"] = picture(stage)
    return {k: out / p.relative_to(stage) for k, p in files.items()}


def write_results_into(out: Path, result: Any, config: Any, **extra: Any) -> dict[str, Path]:
    """write_results' files, written into the existing folder `out`."""
    files = {"json": out / FILES["json"], "config": out / "config.yaml"}
    with naming(files["json"]):
        files["json"].write_text(compact_json(summary(result, **extra)))
    with naming(files["config"]):
        config.to_yaml(files["config"])
    if result.accepted:
        for fmt in ("matrix", "kitti", "tum"):
            with naming(out / FILES[fmt]):
                files[fmt] = write_transform(out / FILES[fmt], result.transform, fmt)
    return files
