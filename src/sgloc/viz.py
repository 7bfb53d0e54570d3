"""Top-down pictures of semantic maps, one convention everywhere: x to the right, y up, equal
axes, metres. Classes get a qualitative palette whose 11 colours are told apart (any two at
least 42 apart in CIELAB, against 22 for the Airsim segmentation colours; picked greedily from
the Okabe-Ito, Kelly and Tableau sets); robots differ by marker and appear in the legend with
the matches."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sgloc.geometry import apply
from sgloc.graph import SemanticGraph

#: 11 distinct class colours (hex), class k -> CLASS_PALETTE[k % 11].
CLASS_PALETTE: tuple[str, ...] = (
    "#0072B2", "#F38400", "#2CA02C", "#D62728", "#6A3D9A", "#654522",
    "#E68FAC", "#F0E442", "#000000", "#17BECF", "#C2B280",
)
ROBOT_MARKERS: tuple[str, ...] = ("o", "^", "s", "D", "v", "P", "X", "*")


def class_colours(labels: np.ndarray) -> list[str]:
    """A palette colour for each class id."""
    return [CLASS_PALETTE[int(c) % len(CLASS_PALETTE)] for c in np.asarray(labels)]


def top_down(ax, points_xy: np.ndarray | None = None) -> None:
    """Apply the convention: x right, y up, equal axes, axis labels in metres."""
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m) →")
    ax.set_ylabel("y (m) ↑")
    ax.grid(True, lw=0.3, alpha=0.4)


def class_legend_handles(labels: np.ndarray, names: Sequence[str] | None = None) -> list:
    """Legend entries (one coloured dot per class present)."""
    from matplotlib.lines import Line2D

    out = []
    for c in np.unique(labels):
        name = names[c] if names is not None and c < len(names) else f"class {c}"
        out.append(Line2D([], [], ls="", marker="o", ms=5, color=CLASS_PALETTE[c % 11],
                          label=name))
    return out


def plot_aligned_maps(
    target: SemanticGraph,
    query: SemanticGraph,
    T_target_query: np.ndarray,
    matches: np.ndarray,
    path: str | Path,
    title: str,
    class_names: Sequence[str] | None = None,
    routes: tuple[np.ndarray, np.ndarray] | None = None,
) -> Path:
    """PNG: robot A's map (target, circles) and robot B's map (query, triangles) placed by
    `T_target_query`, classes in colour, the final matches as lines, optional routes (positions
    (n,3) in each robot's own frame). Top-down: x right, y up."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D

    t = target.positions
    q = apply(T_target_query, query.positions)
    both = np.concatenate([t, q])
    w, h = np.ptp(both[:, 0]) + 20.0, np.ptp(both[:, 1]) + 20.0
    fig, ax = plt.subplots(figsize=(float(np.clip(6.0 * w / h, 4.5, 10.0)) + 2.0, 6.0))
    ax.scatter(t[:, 0], t[:, 1], s=16, c=class_colours(target.labels), marker="o",
               edgecolors="none", alpha=0.85)
    ax.scatter(q[:, 0], q[:, 1], s=26, facecolors="none", edgecolors=class_colours(query.labels),
               marker="^", linewidths=1.0)
    handles = [
        Line2D([], [], ls="", marker="o", color="0.3", label=f"robot A (target), {len(t)} objects"),
        Line2D([], [], ls="", marker="^", mfc="none", color="0.3",
               label=f"robot B (query), {len(q)} objects"),
    ]
    m = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    if len(m):
        segs = np.stack([q[m[:, 0], :2], t[m[:, 1], :2]], axis=1)
        ax.add_collection(LineCollection(segs, colors="#FF00FF", lw=1.6, alpha=0.9))
        # matched pairs usually lie on top of each other once aligned: ring them
        ax.scatter(t[m[:, 1], 0], t[m[:, 1], 1], s=90, facecolors="none", edgecolors="#FF00FF",
                   linewidths=1.1)
    handles.append(Line2D([], [], ls="-", marker="o", mfc="none", color="#FF00FF", lw=1.6,
                          label=f"{len(m)} final matches"))
    if routes is not None:
        ra, rb = routes[0], apply(T_target_query, routes[1])
        ax.plot(ra[:, 0], ra[:, 1], "-", c="0.35", lw=1.0)
        ax.plot(rb[:, 0], rb[:, 1], "--", c="0.55", lw=1.0)
        handles += [Line2D([], [], c="0.35", lw=1.0, label="robot A route"),
                    Line2D([], [], c="0.55", ls="--", lw=1.0, label="robot B route")]
    handles += class_legend_handles(np.concatenate([target.labels, query.labels]), class_names)
    ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              borderaxespad=0.0, frameon=False)
    ax.set_title(title, fontsize=9)
    top_down(ax)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_fleet(result, graphs: Sequence, path) -> Path:
    """PNG of a fleet result's merged map, top-down (x right, y up): each placed robot's
    objects (`graphs`, each in its own frame) with its own marker and colour, the fused objects
    as rings; unplaced robots named in the title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 6), dpi=100)
    for i in result.placed:
        p = apply(result.T_world_robot[i], graphs[i].positions)
        root = " (world frame)" if i == result.root else ""
        ax.scatter(p[:, 0], p[:, 1], s=9, color=CLASS_PALETTE[i % len(CLASS_PALETTE)],
                   marker=ROBOT_MARKERS[i % len(ROBOT_MARKERS)], alpha=0.75,
                   label=f"{result.names[i]}{root}")
    if result.merged is not None and len(result.merged):
        ax.scatter(*result.merged.positions[:, :2].T, s=20, facecolors="none", edgecolors="k",
                   linewidths=0.3, label=f"merged map, {len(result.merged)} objects")
    title = f"{len(result.placed)} of {len(result.names)} robots placed"
    if result.unplaced:
        title += " (unplaced: " + ", ".join(result.names[i] for i in result.unplaced) + ")"
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, markerscale=1.5, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              frameon=False)
    top_down(ax)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
