"""Pictures a roboticist reads at a glance: lines between matched objects, query drawn above
the target, class names, axes with units on every panel, n on every statistic, plain log
ticks, medians coloured as the legend, titles that fit."""

from __future__ import annotations

import matplotlib.figure
import numpy as np
import pytest

from sgloc.evaluation import plots
from sgloc.io.pictures import MATCH_COLOUR, plot_aligned_maps


@pytest.fixture
def figures(monkeypatch):
    """The figures the plotting functions save (they close them afterwards)."""
    saved = []
    real = matplotlib.figure.Figure.savefig

    def keep(self, *a, **k):
        saved.append(self)
        return real(self, *a, **k)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", keep)
    return saved


def _texts(fig) -> list[str]:
    return [t.get_text() for t in fig.findobj(matplotlib.text.Text)]


def test_matches_are_lines_between_objects_and_query_is_on_top(tmp_path, airsim_graphs, figures):
    c1, c2 = airsim_graphs
    m = np.stack([np.arange(10), np.arange(10)], axis=1)
    names = [f"kind{i}" for i in range(11)]
    plot_aligned_maps(c2, c1, np.eye(4), m, tmp_path / "a.png", "title", names)
    fig = figures[-1]
    axes = fig.axes
    assert len(axes) == 2
    lines = [c for c in axes[0].collections if hasattr(c, "get_segments")]
    assert lines and len(lines[0].get_segments()) == 10
    assert all(np.ptp(np.asarray(seg)[:, 0]) > 1.0 for seg in lines[0].get_segments())
    target, query = axes[1].collections[:2]
    assert query.get_zorder() > target.get_zorder()
    assert not any(c.get_sizes().max() >= 90 for c in axes[1].collections)  # no rings
    for ax in axes:
        assert "m" in ax.get_xlabel() and "m" in ax.get_ylabel()
    legend = [t.get_text() for t in axes[1].get_legend().get_texts()]
    assert "kind3" in legend and "class 3" not in legend
    assert MATCH_COLOUR


def test_no_matches_no_legend_entry_and_the_title_fits(tmp_path, airsim_graphs, figures):
    c1, c2 = airsim_graphs
    reason = "not localized: " + "a long reason that goes on " * 12
    plot_aligned_maps(c2, c1, np.eye(4), [], tmp_path / "a.png", reason)
    fig = figures[-1]
    assert len(fig.axes) == 1
    legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert not any("final matches" in t for t in legend)
    title = fig._suptitle
    fig.canvas.draw()
    box = title.get_window_extent()
    assert box.x0 >= 0 and box.x1 <= fig.bbox.width


def _rows(n: int = 4) -> list[dict]:
    rng = np.random.default_rng(0)
    rows = []
    for d in ("histogram", "fast"):
        for rej in ("none", "neighbor"):
            for thr in (1.0, 5.0, 10.0):
                for s in range(n):
                    ok = thr > 1.0 or s % 2 == 0
                    rows.append({
                        "descriptor": d, "rejection": rej, "ransac_threshold": thr, "seed": s,
                        "overlap": 0.5 if s % 2 else 0.2, "localized": ok, "failed": not ok,
                        "translation_error_m": float(rng.uniform(0.5, 30)) if ok else np.nan,
                        "rotation_error_deg": float(rng.uniform(0.1, 3)) if ok else np.nan,
                        "recall": float(rng.uniform(0.2, 1)),
                        "precision": float(rng.uniform(0.7, 1)),
                        "n_matches": 10, "n_correct": 8,
                    })  # fmt: skip
    return rows


def test_statistics_carry_n_and_plain_log_ticks(tmp_path, figures):
    rows = _rows()
    plots.error_distribution(rows, tmp_path / "e.png", 5.0)
    fig = figures[-1]
    labels = " ".join(t.get_text() for t in fig.axes[0].get_xticklabels())
    assert "n = 4" in labels
    fig.canvas.draw()
    ticks = [t.get_text() for ax in fig.axes for t in ax.get_yticklabels() if t.get_text()]
    assert ticks and not any("10^" in t or "times" in t for t in ticks)
    plots.pr_curves(rows, tmp_path / "p.png")
    assert any("n = 4" in t for t in _texts(figures[-1]))
    plots.error_vs_threshold(rows, tmp_path / "t.png")
    fig = figures[-1]
    assert any("n = 4" in t for t in _texts(fig)) and fig.axes[1].get_ylim()[0] == 0


def test_box_medians_take_the_legend_colour_and_failures_start_at_zero(tmp_path, figures):
    rows = [r for r in _rows() if r["ransac_threshold"] == 5.0]
    plots.overlap_boxplots(rows, tmp_path / "o.png")
    ax, ax2 = figures[-1].axes
    handles = ax.get_legend().legend_handles
    colours = {h.get_color() for h in handles if hasattr(h, "get_color")}
    medians = {ln.get_color() for ln in ax.lines if ln.get_linewidth() == 2.0}
    assert medians and medians <= colours
    assert ax2.get_ylim()[0] == 0


def test_localize_picture_names_classes_from_the_class_table(tmp_path, airsim_graphs, figures):
    from sgloc.cli import main

    names = ["vehicle", "trunk", "pole"] + [f"c{i}" for i in range(3, 11)]
    (tmp_path / "classes.txt").write_text("".join(f"{i} {n}\n" for i, n in enumerate(names)))
    files = []
    for k, g in enumerate(airsim_graphs):
        files.append(tmp_path / f"g{k}.csv")
        rows = [f"{x},{y},{z},{names[c]}\n" for (x, y, z), c in zip(g.positions, g.labels,
                                                                       strict=True)]  # fmt: skip
        files[-1].write_text("x,y,z,label\n" + "".join(rows))
    argv = ["localize", *map(str, files), "--class-table", str(tmp_path / "classes.txt"),
            "--out", str(tmp_path / "out")]  # fmt: skip
    assert main(argv) == 0
    legend = [t.get_text() for t in figures[-1].axes[-1].get_legend().get_texts()]
    assert {"vehicle", "trunk", "pole"} <= set(legend)
