"""Results on disk: CSV (one row per trial), summaries as Markdown tables, config as YAML.

Summaries follow the paper's Table 1: mean +- std over trials of final matches and pose errors,
mean recall and precision, and per-stage times. Times are medians (robust on a shared machine);
"total" is rejection + RANSAC (incl. the final fit) as in the paper, "pipeline" adds
descriptors and matching. Pose errors and precision average over the localized trials; failures
(not localized, or localized with translation error > 20 m: "wrong") are counted in their own
column. """

from __future__ import annotations

import csv
import json
import math
import platform
import subprocess
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sgloc import __version__
from sgloc.datasets.downloads import PROJECT_ROOT
from sgloc.io.files import naming

#: The paper's Table 1 (Airsim, T_error = 5 m; i7-9700, C++): descriptor, rejection -> values.
PAPER_TABLE1: dict[tuple[str, str], dict[str, str]] = {
    setting: dict(zip(("final matches", "recall %", "precision %", "rejection ms", "RANSAC ms",
                       "total ms", "trans. err m", "rot. err deg"), values, strict=True))
    for setting, values in {
        ("histogram", "none"): ("67.84+-1.55", "85.2", "77.3", "-", "19.2", "19.2", "3.02+-0.91",
                                "0.41+-0.32"),
        ("histogram", "neighbor"): ("72.67+-0.78", "91.4", "87.9", "1.2", "7.9", "9.1",
                                    "2.69+-0.43", "0.40+-0.22"),
        ("fast", "none"): ("24.84+-3.47", "65.4", "73.3", "-", "18.4", "18.4", "5.72+-6.53",
                           "3.88+-5.71"),
        ("fast", "neighbor"): ("36.69+-1.34", "85.0", "65.7", "1.0", "6.0", "7.0", "4.33+-1.31",
                               "0.85+-0.28"),
        ("random_walk", "none"): ("62.90+-1.91", "66.3", "83.0", "-", "18.3", "18.3",
                                  "2.76+-0.94", "0.61+-0.33"),
        ("random_walk", "neighbor"): ("68.13+-0.61", "71.3", "91.2", "0.7", "11.7", "12.4",
                                      "2.44+-0.49", "0.61+-0.15"),
    }.items()
}  # fmt: skip


# -- CSV --------------------------------------------------------------------------------------
def write_csv(rows: Sequence[dict[str, Any]], path: str | Path) -> Path:
    """Write trial rows (flat dicts with the same keys) as CSV, one row per trial."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with naming(path), path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        w.writeheader()
        w.writerows(rows)
    return path


def read_csv(path: str | Path) -> list[dict[str, Any]]:
    """Read rows written by `write_csv`, turning numbers and booleans back into values."""

    def parse(v: str) -> Any:
        if v in ("True", "False"):
            return v == "True"
        try:
            f = float(v)
        except ValueError:
            return v
        return int(f) if f.is_integer() and "." not in v and "e" not in v.lower() else f

    with Path(path).open(newline="") as f:
        return [{k: parse(v) for k, v in r.items()} for r in csv.DictReader(f)]


# -- summaries --------------------------------------------------------------------------------
def group_rows(
    rows: Iterable[dict[str, Any]], by: Sequence[str]
) -> dict[tuple, list[dict[str, Any]]]:
    """Rows grouped by the values of the `by` columns, groups in first-seen order."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in by), []).append(r)
    return groups


def column(rows: Sequence[dict[str, Any]], key: str) -> np.ndarray:
    """A column as float array (NaN where missing)."""
    return np.array([float(r.get(key, math.nan)) for r in rows], dtype=np.float64)


def _mean_std(x: np.ndarray) -> tuple[float, float]:
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan, math.nan
    return float(x.mean()), float(x.std())


def _median(x: np.ndarray) -> float:
    """Median of the finite values; NaN (without a warning) when there are none."""
    x = x[np.isfinite(x)]
    return float(np.median(x)) if x.size else math.nan


def summarize(rows: Sequence[dict[str, Any]], by: Sequence[str]) -> list[dict[str, Any]]:
    """One summary per group of `by` values: counts, means, stds and median times."""
    out = []
    for key, g in group_rows(rows, by).items():
        loc = [r for r in g if r["localized"]]
        rej = column(g, "t_rejection_ms")
        rs = column(g, "t_ransac_ms") + column(g, "t_estimation_ms")
        te_all = column(g, "translation_error_m")
        s = {
            **dict(zip(by, key, strict=True)),
            "trials": len(g),
            "localized": len(loc),
            "failures": int(sum(bool(r["failed"]) for r in g)),
            "not_localized": len(g) - len(loc),
            "wrong": int(sum(bool(r["failed"]) for r in loc)),
            "recall": _mean_std(column(g, "recall"))[0],
            "precision": _mean_std(column(loc, "precision"))[0],
            "rejection_ms": _median(rej),
            "ransac_ms": _median(rs),
            "total_ms": _median(rej + rs),
            "pipeline_ms": _median(column(g, "t_total_ms")),
            "te_median": _median(te_all),
        }
        for name, sel, col in (
            ("final", g, "n_final"),
            ("te", loc, "translation_error_m"),
            ("re", loc, "rotation_error_deg"),
        ):
            s[f"{name}_mean"], s[f"{name}_std"] = _mean_std(column(sel, col))
        if "pair_overlap" in g[0]:
            s["achieved_overlap"] = float(np.nanmean(column(g, "pair_overlap")))
        out.append(s)
    return out


def fmt(x: float, digits: int = 2) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def pm(mean: float, std: float, digits: int = 2) -> str:
    """'mean +- std' for a Markdown cell."""
    return "-" if not np.isfinite(mean) else f"{mean:.{digits}f} +- {std:.{digits}f}"


def markdown_table(header: Sequence[str], body: Sequence[Sequence[Any]]) -> str:
    """A GitHub Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in body]
    return "\n".join(lines) + "\n"


FAILURES = "failures (not loc. + wrong)"
SETTING_LABEL = {"histogram": "Histogram", "fast": "Fast", "random_walk": "Random Walk"}


def setting_label(descriptor: str, rejection: str) -> str:
    """'Histogram' / 'Histogram + neighbor' style row names."""
    base = SETTING_LABEL.get(descriptor, descriptor)
    return base if rejection == "none" else f"{base} + {rejection}"


#: Table columns: header -> the cell of a summary row (`summarize`).
COLUMNS: dict[str, Callable[[dict[str, Any]], Any]] = {
    "trials": lambda s: s["trials"],
    "achieved overlap": lambda s: fmt(s["achieved_overlap"]),
    FAILURES: lambda s: f"{s['failures']} ({s['not_localized']} + {s['wrong']})",
    "final matches": lambda s: pm(s["final_mean"], s["final_std"]),
    "final": lambda s: fmt(s["final_mean"], 1),
    "recall %": lambda s: fmt(100 * s["recall"], 1),
    "precision %": lambda s: fmt(100 * s["precision"], 1),
    "rejection ms": lambda s: fmt(s["rejection_ms"]) if s["rejection"] != "none" else "-",
    "RANSAC ms": lambda s: fmt(s["ransac_ms"]),
    "total ms": lambda s: fmt(s["total_ms"]),
    "pipeline ms": lambda s: fmt(s["pipeline_ms"]),
    "trans. err m": lambda s: pm(s["te_mean"], s["te_std"]),
    "median trans. err m": lambda s: fmt(s["te_median"]),
    "rot. err deg": lambda s: pm(s["re_mean"], s["re_std"]),
}


def table1_markdown(summary: Sequence[dict[str, Any]], with_paper: bool = True) -> str:
    """Table 1 layout for a descriptor x rejection summary; the paper's row under each of ours
    (when `with_paper` and the paper has that setting)."""
    header = [
        "trials", FAILURES, "final matches", "recall %", "precision %", "rejection ms",
        "RANSAC ms", "total ms", "pipeline ms", "trans. err m", "rot. err deg",
    ]  # fmt: skip
    body = []
    for s in summary:
        label = setting_label(s["descriptor"], s["rejection"])
        body.append([f"**{label}** (ours)", *(COLUMNS[h](s) for h in header)])
        p = PAPER_TABLE1.get((s["descriptor"], s["rejection"]))
        if with_paper and p:
            paper = {"trials": 100, **p}
            body.append([f"{label} (paper)", *(paper.get(h, "-") for h in header)])
    return markdown_table(["setting", *header], body)


def sweep_markdown(summary: Sequence[dict[str, Any]], by: Sequence[str]) -> str:
    """A compact table for sweeps: one row per cell."""
    extra = ["achieved overlap"] if summary and "achieved_overlap" in summary[0] else []
    header = [*extra, "trials", FAILURES, "final", "recall %", "precision %", "total ms",
              "trans. err m", "median trans. err m", "rot. err deg"]  # fmt: skip
    body = [[*(s[k] for k in by), *(COLUMNS[h](s) for h in header)] for s in summary]
    return markdown_table([*by, *header], body)


# -- config -----------------------------------------------------------------------------------
def _git_commit() -> str:
    try:
        out = subprocess.run(
            ["git", "-C", str(PROJECT_ROOT), "rev-parse", "HEAD"],
            capture_output=True, text=True, timeout=5, check=False,
        )  # fmt: skip
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def write_config_yaml(path: str | Path, experiment: dict[str, Any], configs: dict) -> Path:
    """Write what ran: the experiment (sweep) description, every localizer config by cell, and
    the software version; enough to re-run it exactly."""
    doc = {
        "experiment": experiment,
        "localizer_configs": configs,
        "software": {
            "sgloc": __version__,
            "git_commit": _git_commit(),
            "python": platform.python_version(),
            "numpy": np.__version__,
        },
    }
    path = Path(path)
    plain = json.loads(json.dumps(doc, default=lambda x: x.item()))  # numpy scalars, tuples
    with naming(path):
        path.write_text(yaml.safe_dump(plain, sort_keys=False))
    return path
