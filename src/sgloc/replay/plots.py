"""Pictures of a replay: a timeline of events and a top-down picture of the placed fleet."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.geometry import apply
from sgloc.io.keyframes import RobotLog

#: Event kinds -> (marker, colour, legend label).
EVENT_STYLE = {
    "robot_joined": ("o", "#2CA02C", "robot joined"),
    "link_accepted": ("^", "#0072B2", "link accepted"),
    "link_revoked": ("x", "#D62728", "link revoked"),
}


def robot_colours(n: int) -> list[Any]:
    """n distinct colours (tab10, then tab20 beyond 10 robots)."""
    import matplotlib

    cmap = matplotlib.colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


def path_widths(n: int) -> list[float]:
    """Line widths (points) of n robots' paths drawn in order: each narrower than the one
    before by up to 1.5 points, so that a path drawn over an earlier one (robots driving the same
    street) leaves the earlier one showing along both its sides."""
    step = min(1.5, 9.0 / max(n - 1, 1))
    return [1.4 + step * (n - 1 - k) for k in range(n)]


def timeline_figure(logs: Sequence[RobotLog], events: Sequence[Any]) -> Any:
    """Figure: one row per robot (its keyframe span as a bar), events as markers at their
    stamps on the rows of the robots they concern; x: seconds since the run's first stamp
    (which the axis label gives in full)."""
    import matplotlib.pyplot as plt

    from sgloc.io.keyframes import format_stamp

    start_ns = min(int(g.stamps_ns[0]) for g in logs)
    start = start_ns * 1e-9
    row = {g.name: i for i, g in enumerate(logs)}
    fig, ax = plt.subplots(figsize=(9, 1.2 + 0.45 * len(logs)))
    for g, c in zip(logs, robot_colours(len(logs)), strict=True):
        span = (g.stamps_ns[[0, -1]] - start_ns) * 1e-9
        ax.plot(span, [row[g.name]] * 2, lw=6, color=c, alpha=0.35, solid_capstyle="butt")
    seen = set()
    for e in events:
        marker, colour, label = EVENT_STYLE.get(e.kind, ("s", "grey", e.kind))
        ys = [row[r] for r in e.robots if r in row]
        ax.plot([e.stamp - start] * len(ys), ys, ls=":" if len(ys) > 1 else "", marker=marker,
                color=colour, ms=7, label=None if e.kind in seen else label)
        seen.add(e.kind)
    ax.set_yticks(range(len(logs)), [g.name for g in logs])
    ax.set_ylim(-0.7, len(logs) - 0.3)
    ax.invert_yaxis()
    ax.ticklabel_format(axis="x", useOffset=False, style="plain")
    ax.set_xlabel(f"seconds since the run's start (stamp {format_stamp(start_ns)} s)")
    ax.set_title("replay timeline")
    ax.grid(True, axis="x", lw=0.3, alpha=0.5)
    if seen:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    return fig


def plot_timeline(logs: Sequence[RobotLog], events: Sequence[Any], path: str | Path) -> Path:
    """PNG of `timeline_figure`."""
    return _save(timeline_figure(logs, events), path)


def fleet_figure(
    logs: Sequence[RobotLog], frames: dict[str, np.ndarray], maps: dict[str, np.ndarray]
) -> Any:
    """Figure, top-down in the fleet frame (metres): each placed robot's keyframe path (line,
    `path_widths`) and confirmed objects (dots, its own marker) in its own colour, with a
    legend; unplaced robots are listed."""
    import matplotlib.pyplot as plt

    from sgloc.io.pictures import ROBOT_MARKERS, top_down

    fig, ax = plt.subplots(figsize=(8, 7))
    widths = path_widths(len(logs))
    for k, (g, c) in enumerate(zip(logs, robot_colours(len(logs)), strict=True)):
        T = frames.get(g.name)
        if T is None:
            ax.plot([], [], color="lightgrey", label=f"{g.name} (not placed)")
            continue
        path_xy = apply(T, g.xyz)[:, :2]
        ax.plot(path_xy[:, 0], path_xy[:, 1], color=c, lw=widths[k], label=g.name, zorder=2 + k,
                solid_capstyle="butt")
        ax.plot(*path_xy[0], marker="o", color=c, mec="black", ms=3 + 1.5 * widths[k],
                zorder=2 + k)
        obj = maps.get(g.name)
        if obj is not None and len(obj):
            p = apply(T, obj)
            ax.scatter(p[:, 0], p[:, 1], s=8, color=c, alpha=0.5, lw=0,
                       marker=ROBOT_MARKERS[k % len(ROBOT_MARKERS)], zorder=1)
    top_down(ax)
    ax.set_title("fleet frame: robot paths (start = circle) and their objects")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    return fig


def plot_replay_fleet(
    logs: Sequence[RobotLog],
    frames: dict[str, np.ndarray],
    maps: dict[str, np.ndarray],
    path: str | Path,
) -> Path:
    """PNG of `fleet_figure`."""
    return _save(fleet_figure(logs, frames, maps), path)


def _save(fig: Any, path: str | Path) -> Path:
    import matplotlib.pyplot as plt

    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path
