"""Figures of the paper's experiments (matplotlib, Agg backend; small PNGs).

Each function takes trial rows (flat dicts as `run_task` returns them) or one trial's data and
writes one PNG, returning its path.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from sgloc.evaluation.metrics import correct_matches  # noqa: E402
from sgloc.evaluation.report import column, group_rows, setting_label, summarize  # noqa: E402
from sgloc.geometry import apply  # noqa: E402
from sgloc.io.files import naming  # noqa: E402

DPI = 110
COLORS = {"histogram": "tab:blue", "fast": "tab:orange", "random_walk": "tab:green"}


def _style(descriptor: str, rejection: str) -> dict[str, Any]:
    return {
        "color": COLORS.get(descriptor, "tab:gray"),
        "linestyle": "-" if rejection != "none" else "--",
        "marker": "o" if rejection != "none" else "s",
        "markersize": 3,
    }


def _plain_log_ticks(ax, axis: str = "y") -> None:
    """Log-scale ticks written as plain numbers (0.5, 2, 10), not as 5x10^-1."""
    from matplotlib.ticker import FuncFormatter, LogLocator

    which = ax.yaxis if axis == "y" else ax.xaxis
    which.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    which.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    which.set_minor_formatter(FuncFormatter(lambda v, _: ""))


def _failure_axis(ax, values: Sequence[float]) -> None:
    """A failures-% axis from 0 (never -0.05..0.05 when nothing failed)."""
    top = max([float(v) for v in values if np.isfinite(v)] + [0.0])
    ax.set_ylim(0, max(5.0, top * 1.1))


def _trials_per_point(rows: Sequence[dict[str, Any]], by: list[str]) -> str:
    """"n = k" (or "n = a-b") trials per plotted point, for titles."""
    sizes = sorted({len(g) for g in group_rows(rows, by).values()})
    if not sizes:
        return "n = 0"
    return f"n = {sizes[0]}" if len(sizes) == 1 else f"n = {sizes[0]}-{sizes[-1]}"


def _save(fig: plt.Figure, path: str | Path, top: float = 1.0, dpi: int = DPI) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout(rect=(0, 0, 1, top))
    try:
        with naming(path):
            fig.savefig(path, dpi=dpi)
    finally:
        plt.close(fig)
    return path


def error_vs_threshold(rows: Sequence[dict[str, Any]], path: str | Path) -> Path:
    """Fig. 4: mean +- std translation error (localized trials) against the RANSAC threshold,
    one line per descriptor x rejection; the failure rate below."""
    fig, (ax, ax2) = plt.subplots(
        2, 1, figsize=(6.4, 5.6), sharex=True, gridspec_kw={"height_ratios": [3, 1.3]}
    )
    fails: list[float] = []
    for (d, r), g in group_rows(rows, ["descriptor", "rejection"]).items():
        s = summarize(g, ["ransac_threshold"])
        x = np.array([c["ransac_threshold"] for c in s])
        m = np.array([c["te_mean"] for c in s])
        sd = np.array([c["te_std"] for c in s])
        st = _style(d, r)
        ax.plot(x, m, label=setting_label(d, r), **st)
        ax.fill_between(x, m - sd, m + sd, color=st["color"], alpha=0.08)
        fails += [100 * c["failures"] / c["trials"] for c in s]
        ax2.plot(x, [100 * c["failures"] / c["trials"] for c in s], **st)
    n = _trials_per_point(rows, ["descriptor", "rejection", "ransac_threshold"])
    ax.set_title(f"Translation error vs RANSAC threshold (mean ± std, {n} trials a point)",
                 fontsize=10)  # fmt: skip
    _failure_axis(ax2, fails)
    ax.set_ylabel("translation error (m)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax2.set(xlabel="RANSAC threshold T_error (m)", ylabel="failures %")
    ax2.grid(alpha=0.3)
    return _save(fig, path)


def error_distribution(
    rows: Sequence[dict[str, Any]], path: str | Path, threshold: float = 5.0
) -> Path:
    """Distribution of translation and rotation error at one RANSAC threshold, per setting
    (box plots; failed or unlocalized trials counted in the labels)."""
    sel = [r for r in rows if abs(float(r["ransac_threshold"]) - threshold) < 1e-9]
    groups = group_rows(sel, ["descriptor", "rejection"])
    labels, te, re = [], [], []
    for (d, r), g in groups.items():
        fails = sum(bool(x["failed"]) for x in g)
        labels.append(f"{setting_label(d, r)}\n(n = {len(g)}, {fails} failed)")
        te.append(column(g, "translation_error_m")[np.isfinite(column(g, "translation_error_m"))])
        re.append(column(g, "rotation_error_deg")[np.isfinite(column(g, "rotation_error_deg"))])
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8))
    for ax, data, name in ((axes[0], te, "translation error (m)"), (axes[1], re, "rotation (deg)")):
        ax.boxplot([x if x.size else np.array([np.nan]) for x in data], showfliers=True,
                   medianprops={"color": "k", "lw": 1.5})  # fmt: skip
        ax.set_xticks(range(1, len(labels) + 1), labels, rotation=35, ha="right", fontsize=7)
        ax.set(yscale="log", ylabel=name)
        _plain_log_ticks(ax)
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle(f"Error distribution at T_error = {threshold:g} m (boxes: localized trials; "
                 "line: median)", fontsize=10)  # fmt: skip
    return _save(fig, path, top=0.93)


def pr_curves(rows: Sequence[dict[str, Any]], path: str | Path) -> Path:
    """Fig. 5: mean precision against mean recall of the final matches, sweeping the RANSAC
    threshold; one curve per descriptor x rejection, thresholds annotated at the ends."""
    fig, ax = plt.subplots(figsize=(5.6, 4.6))
    for (d, r), g in group_rows(rows, ["descriptor", "rejection"]).items():
        s = summarize(g, ["ransac_threshold"])
        rec = np.array([100 * c["recall"] for c in s])
        pre = np.array([100 * c["precision"] for c in s])
        st = _style(d, r)
        ax.plot(rec, pre, label=setting_label(d, r), **st)
        for c, x, y, dy in ((s[0], rec[0], pre[0], -10), (s[-1], rec[-1], pre[-1], -10)):
            ax.annotate(f"{c['ransac_threshold']:g} m", (x, y), xytext=(4, dy),
                        textcoords="offset points", fontsize=7, color=st["color"])  # fmt: skip
    ax.set(xlabel="recall of the final matches (%)", ylabel="precision of the final matches (%)")
    n = _trials_per_point(rows, ["descriptor", "rejection", "ransac_threshold"])
    ax.set_title(f"Precision-recall over the RANSAC threshold\n(means, {n} trials a point; "
                 "the end points' thresholds in m)", fontsize=9)  # fmt: skip
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, path)


def overlap_boxplots(
    rows: Sequence[dict[str, Any]], path: str | Path, title: str = "", failure_m: float = 20.0
) -> Path:
    """Fig. 6: box plots of the translation error of the localized trials per overlap rate,
    baseline beside +neighbor; above each box the count of unlocalized trials (`k/n` not
    localized; they have no error to draw); failure rates in the lower panel (solid: localized
    but wrong by more than `failure_m`; hatched: not localized)."""
    rejections = list(dict.fromkeys(r["rejection"] for r in rows))
    overlaps = sorted({float(r["overlap"]) for r in rows})
    fig, (ax, ax2) = plt.subplots(
        2, 1, figsize=(7.5, 5.4), sharex=True, gridspec_kw={"height_ratios": [3, 1.2]}
    )
    width = 0.8 / max(len(rejections), 1)
    bars: list[float] = []
    for k, rej in enumerate(rejections):
        data, wrong, unloc, counts = _overlap_statistics(rows, rej, overlaps)
        pos = np.arange(len(overlaps)) + (k - (len(rejections) - 1) / 2) * width
        _draw_overlap_boxes(ax, ax2, rej, pos, width, data, wrong, unloc, counts)
        bars += [w + u for w, u in zip(wrong, unloc, strict=True)]
    ax.axhline(failure_m, color="k", lw=0.8, ls=":", label=f"failure ({failure_m:g} m)")
    ax.set_yscale("log")
    _plain_log_ticks(ax)
    lo, hi = ax.get_ylim()
    ax.set_ylim(lo, hi * 4)  # room for the unlocalized counts
    ax.set_ylabel("translation error of localized trials (m)")
    ax.set_title(title or "Translation error vs overlap")
    ax.legend(fontsize=7, title="k/n over a box: k of n not localized", title_fontsize=7)
    ax.grid(alpha=0.3, axis="y")
    _overlap_failure_panel(ax2, overlaps, bars, failure_m)
    return _save(fig, path)


def _overlap_statistics(
    rows: Sequence[dict[str, Any]], rejection: str, overlaps: list[float]
) -> tuple[list[np.ndarray], list[float], list[float], list[tuple[int, int]]]:
    """Per overlap rate, for one rejection: the localized trials' translation errors (m; [nan]
    when none), the % localized but wrong, the % not localized and (not localized, trials)."""
    data, wrong, unloc, counts = [], [], [], []
    for o in overlaps:
        g = [r for r in rows if r["rejection"] == rejection and float(r["overlap"]) == o]
        te = column(g, "translation_error_m")
        localized = np.array([bool(r["localized"]) for r in g], dtype=bool)
        te = te[localized & np.isfinite(te)] if len(g) else te
        data.append(te if len(te) else np.array([np.nan]))
        n = max(len(g), 1)
        counts.append((int(np.sum(~localized)), len(g)))
        unloc.append(100 * counts[-1][0] / n)
        wrong.append(100 * sum(bool(r["localized"] and r["failed"]) for r in g) / n)
    return data, wrong, unloc, counts


def _draw_overlap_boxes(
    ax,
    ax2,
    rejection: str,
    pos: np.ndarray,
    width: float,
    data: list[np.ndarray],
    wrong: list[float],
    unloc: list[float],
    counts: list[tuple[int, int]],
) -> None:
    """One rejection's boxes at x = pos with their `k/n` counts on `ax`, and its failure bars
    (solid wrong, hatched not localized) on `ax2`."""
    color = "tab:red" if rejection == "none" else "tab:blue"
    top = ax.get_xaxis_transform()  # x in data, y in axes fraction
    for x, (n_unloc, n) in zip(pos, counts, strict=True):
        ax.text(x, 0.985, f"{n_unloc}/{n}", transform=top, ha="center", va="top", fontsize=6,
                color=color)  # fmt: skip
    label = "baseline (RANSAC)" if rejection == "none" else f"+{rejection}"
    bp = ax.boxplot(
        data, positions=pos, widths=width * 0.9, patch_artist=True, showfliers=True,
        flierprops={"markersize": 2, "markeredgecolor": color},
        medianprops={"color": color, "lw": 2.0},
    )  # fmt: skip
    for b in bp["boxes"]:
        b.set(facecolor=color, alpha=0.35)
    ax.plot([], [], color=color, lw=6, alpha=0.35, label=f"{label} (line: median)")
    ax2.bar(pos, wrong, width=width * 0.9, color=color, alpha=0.8)
    ax2.bar(pos, unloc, bottom=wrong, width=width * 0.9, color=color, alpha=0.3, hatch="//")


def _overlap_failure_panel(ax2, overlaps: list[float], bars: list[float], failure_m: float) -> None:
    """Ticks, labels, limits and legend of the failure-rate panel (bars: stacked heights, %)."""
    ax2.set_xticks(range(len(overlaps)), [f"{o:g}" for o in overlaps])
    ax2.set(xlabel="overlap rate", ylabel="failures %")
    _failure_axis(ax2, bars)
    ax2.legend(
        handles=[
            Patch(facecolor="0.4", alpha=0.8, label=f"wrong (> {failure_m:g} m)"),
            Patch(facecolor="0.4", alpha=0.3, hatch="//", label="not localized"),
        ],
        fontsize=7,
    )
    ax2.grid(alpha=0.3, axis="y")


def matches_picture(
    query_positions: np.ndarray,
    target_positions: np.ndarray,
    T_target_query: np.ndarray,
    stages: dict[str, np.ndarray],
    path: str | Path,
    tol: float = 10.0,
    title: str = "",
) -> Path:
    """Fig. 7: both maps (target, and query placed by the ground truth and shifted aside) with
    the matches of each stage (e.g. original, after rejection, final) as lines, correct ones
    (within `tol` m under the ground truth) green and wrong ones red; one panel per stage."""
    q = apply(T_target_query, query_positions)[:, :2]
    t = np.asarray(target_positions)[:, :2]
    both = np.concatenate([q, t])
    ext = np.maximum(np.ptp(both, axis=0), 1.0)
    axis = int(np.argmin(ext))  # shift the query map aside along the maps' narrow axis
    shift = np.zeros(2)
    shift[axis] = 0.15 * ext[axis] + t[:, axis].max() - q[:, axis].min()
    qs = q + shift
    w, h = np.ptp(np.concatenate([qs, t]), axis=0) + 1.0
    panel_w = float(np.clip(4.0 * w / h, 2.5, 6.0))
    fig, axes = plt.subplots(1, len(stages), figsize=(panel_w * len(stages), 4.4), squeeze=False)
    for ax, (name, m) in zip(axes[0], stages.items(), strict=True):
        m = np.asarray(m, dtype=np.int64).reshape(-1, 2)
        ok = correct_matches(query_positions, target_positions, m, T_target_query, tol)
        ax.scatter(t[:, 0], t[:, 1], s=3, c="0.35", label="target map", zorder=3)
        ax.scatter(
            qs[:, 0], qs[:, 1], s=3, c="tab:purple", label="query map (GT, shifted)", zorder=3
        )
        segs = np.stack([qs[m[:, 0]], t[m[:, 1]]], axis=1) if len(m) else np.zeros((0, 2, 2))
        ax.add_collection(LineCollection(segs[~ok], colors="tab:red", lw=0.4, alpha=0.5))
        ax.add_collection(LineCollection(segs[ok], colors="tab:green", lw=0.5, alpha=0.7))
        ax.set_title(f"{name}\n{len(m)} matches, {int(ok.sum())} correct", fontsize=8)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m) →", fontsize=7)
        ax.set_ylabel("y (m) ↑", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.grid(True, lw=0.3, alpha=0.4)
    axes[0][0].legend(fontsize=6, loc="lower left")
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path, top=0.93 if title else 1.0, dpi=85)
