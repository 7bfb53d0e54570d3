"""A localization result in standard forms: a 4x4 matrix, a KITTI pose line, a TUM pose line,
a compact JSON summary; and the results folder `sgloc localize --out DIR` writes."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.io.poses import write_kitti_poses, write_tum_poses

FORMATS = ("kitti", "tum", "json", "matrix")
#: File names in a results folder, by format.
FILES = {
    "matrix": "T_target_query.txt",
    "kitti": "T_target_query_kitti.txt",
    "tum": "T_target_query_tum.txt",
    "json": "result.json",
}


def summary(result: Any, **extra: Any) -> dict[str, Any]:
    """The compact JSON summary of a LocalizationResult (no per-match lists). `covariance`:
    the (6,6) covariance of T_target_query (tangent [rx, ry, rz, tx, ty, tz] in rad and m, in
    the query frame: T_true = T_target_query @ Exp(xi); `sgloc.covariance`), None when not
    localized."""
    T = result.transform
    C = getattr(result, "covariance", None)
    d = {
        "success": bool(result.success),
        "reason": result.reason,
        "confidence": None if result.confidence is None else round(float(result.confidence), 6),
        "T_target_query": None if T is None else np.round(T, 9).tolist(),
        "covariance": None if C is None else [[float(f"{v:.9g}") for v in row] for row in C],
        "n_candidates": int(len(result.candidates)),
        "n_survivors": int(len(result.survivors)),
        "n_matches": int(len(result.matches)),
        "timings_ms": {k: round(v * 1e3, 3) for k, v in result.timings.items()},
    }
    d.update(extra)
    return d


def compact_json(d: dict[str, Any]) -> str:
    """JSON with two-space indent, but each matrix row (transform, covariance) on one line."""
    matrices = {k: d[k] for k in ("T_target_query", "covariance") if d.get(k) is not None}
    text = json.dumps({**d, **{k: f"@{k}@" for k in matrices}}, indent=2)
    for key, M in matrices.items():
        rows = ",\n    ".join(json.dumps(r) for r in M)
        text = text.replace(f'"@{key}@"', "[\n    " + rows + "\n  ]")
    return text + "\n"


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


def write_results(out: str | Path, result: Any, config: Any, **extra: Any) -> dict[str, Path]:
    """Write the results folder: result.json, config.yaml and, when localized,
    T_target_query.txt (4x4), T_target_query_kitti.txt, T_target_query_tum.txt."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = {"json": out / FILES["json"], "config": out / "config.yaml"}
    files["json"].write_text(compact_json(summary(result, **extra)))
    config.to_yaml(files["config"])
    if result.success:
        for fmt in ("matrix", "kitti", "tum"):
            files[fmt] = write_transform(out / FILES[fmt], result.transform, fmt)
    return files
