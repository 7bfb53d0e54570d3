"""Top-down pictures of semantic maps, one convention everywhere: x to the right, y up, equal
axes, metres. Classes get a qualitative palette whose 11 colours are told apart (any two at
least 42 apart in CIELAB, against 22 for the Airsim segmentation colours; picked greedily from
the Okabe-Ito, Kelly and Tableau sets); robots differ by marker and appear in the legend with
the matches."""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from sgloc.errors import OutputPathError
from sgloc.geometry import apply
from sgloc.io.files import EXIF_SOFTWARE, PICTURE_MARK
from sgloc.maps.classes import CLASS_PALETTE, class_colours
from sgloc.maps.graph import SemanticGraph

ROBOT_MARKERS: tuple[str, ...] = ("o", "^", "s", "D", "v", "P", "X", "*")

#: The picture formats sgloc draws, by file ending: matplotlib's but raw pixels (raw, rgba),
#: which have no room to say that sgloc drew them, and pgf, which needs a LaTeX installation.
PICTURE_FORMATS: tuple[str, ...] = ("png", "jpg", "jpeg", "tif", "tiff", "webp", "avif", "gif",
                                    "pdf", "svg", "svgz", "eps", "ps")
#: How each format carries sgloc's mark (`sgloc.io.files.is_sgloc_picture` reads it back).
_MARK_FIELD = {"png": "Software", "pdf": "Creator", "svg": "Creator", "svgz": "Creator",
               "eps": "Creator", "ps": "Creator"}


def picture_formats() -> tuple[str, ...]:
    """PICTURE_FORMATS this installation writes (webp and avif need Pillow built with them)."""
    from PIL import features

    return tuple(f for f in PICTURE_FORMATS if f not in ("webp", "avif") or features.check(f))


def picture_path(out: str | Path, name: str = "aligned_maps.png", option: str = "--out") -> Path:
    """Where a picture asked for as `out` is drawn: `out`, or `out`/`name` when `out` is a
    folder (an existing one, or a path ending in '/'). OutputPathError, naming the formats
    sgloc draws, when the name's ending is not one of them."""
    text = os.fspath(out)
    path = Path(text)
    if text.endswith(("/", os.sep)) or path.is_dir():
        path = path / name
    fmt = path.suffix[1:].lower()
    formats = picture_formats()
    if fmt not in formats:
        what = f"'.{fmt}' is not a picture format sgloc draws" if fmt else "names no format"
        raise OutputPathError(
            f"{out}: {what}; give {option} a file ending in "
            + ", ".join("." + f for f in formats)
            + " (or a folder ending in '/', to get " + name + " in it)."
        )
    return path


def save_picture(fig, path: str | Path, **options) -> Path:
    """Save the matplotlib figure `fig` to `path` in the format its ending names, marked as
    drawn by sgloc (so that the next run may replace it); `options` go to `savefig` (dpi, ...)."""
    path = Path(path)
    fmt = path.suffix[1:].lower()
    if fmt in ("jpg", "jpeg", "tif", "tiff", "webp", "avif"):
        from PIL import Image

        exif = Image.Exif()
        exif[EXIF_SOFTWARE] = PICTURE_MARK
        options["pil_kwargs"] = {"exif": exif.tobytes()}
    elif fmt == "gif":
        options["pil_kwargs"] = {"comment": PICTURE_MARK.encode()}
    elif fmt in _MARK_FIELD:
        options["metadata"] = {_MARK_FIELD[fmt]: PICTURE_MARK}
    with _quiet_postscript(fmt):
        fig.savefig(path, format=fmt or None, **options)
    return path


@contextlib.contextmanager
def _quiet_postscript(fmt: str) -> Iterator[None]:
    """PostScript has no transparency: its backend logs that it draws the maps' translucent
    dots opaque, which is all the picture needs; that note is not the user's concern."""
    if fmt not in ("eps", "ps"):
        yield
        return
    log = logging.getLogger("matplotlib.backends.backend_ps")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(level)


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


#: Colour of the lines joining matched objects.
MATCH_COLOUR = "#FF00FF"


def _draw_maps(ax, t: np.ndarray, q: np.ndarray, target: SemanticGraph, query: SemanticGraph):
    """Robot A's objects (filled circles) under robot B's (hollow triangles, drawn on top)."""
    ax.scatter(t[:, 0], t[:, 1], s=14, c=class_colours(target.labels), marker="o",
               edgecolors="none", alpha=0.7, zorder=2)
    ax.scatter(q[:, 0], q[:, 1], s=30, facecolors="none", edgecolors=class_colours(query.labels),
               marker="^", linewidths=1.1, zorder=3)


def _draw_matches(ax, q: np.ndarray, t: np.ndarray, m: np.ndarray) -> None:
    """A line from each matched query object to its target object."""
    from matplotlib.collections import LineCollection

    segs = np.stack([q[m[:, 0], :2], t[m[:, 1], :2]], axis=1)
    ax.add_collection(LineCollection(segs, colors=MATCH_COLOUR, lw=0.8, alpha=0.8, zorder=4))


def _beside(t: np.ndarray, q: np.ndarray, gap: float = 30.0) -> np.ndarray:
    """The query's points (its own frame) moved to the right of the target's, for the matches
    panel: the same shape, only shifted."""
    shift = np.zeros(3)
    shift[0] = t[:, 0].max() + gap - q[:, 0].min()
    shift[1] = np.median(t[:, 1]) - np.median(q[:, 1])
    return q + shift


def _wrapped(title: str, width: int) -> str:
    import textwrap

    return "\n".join(textwrap.fill(line, width) for line in title.splitlines())


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
    """The picture `path` (any of `picture_formats`): robot A's map (target, circles) and
    robot B's map (query, triangles, on top), classes in colour and named by `class_names`.
    With final matches, two panels: the matches as lines from B (in its own frame, set beside
    A) to A, and B placed in A's map by `T_target_query`; without, the one panel. Optional
    routes (positions (n,3) in each robot's own frame). Top-down on every panel: x right,
    y up, metres."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    t = target.positions
    q = apply(T_target_query, query.positions)
    m = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    both = np.concatenate([t, q])
    w, h = np.ptp(both[:, 0]) + 20.0, np.ptp(both[:, 1]) + 20.0
    panel_w = float(np.clip(6.0 * w / h, 4.5, 10.0))
    n_panels = 2 if len(m) else 1
    fig, axes = plt.subplots(1, n_panels, figsize=(panel_w * n_panels + 2.2, 6.4), squeeze=False)
    ax = axes[0, -1]
    _draw_maps(ax, t, q, target, query)
    handles = [
        Line2D([], [], ls="", marker="o", color="0.3", label=f"robot A (target), {len(t)} objects"),
        Line2D([], [], ls="", marker="^", mfc="none", color="0.3",
               label=f"robot B (query), {len(q)} objects"),
    ]
    if len(m):
        handles.append(_matches_panel(axes[0, 0], t, target, query, m))
        ax.set_title("B placed in A's map", fontsize=9)
    if routes is not None:
        handles += _draw_routes(ax, routes, T_target_query)
    box = scan_zoom(t, q)
    if box is not None:
        _zoom_inset(ax, box, t, q, target, query)
    handles += class_legend_handles(np.concatenate([target.labels, query.labels]), class_names)
    ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              borderaxespad=0.0, frameon=False)
    top_down(ax)
    fig.suptitle(_wrapped(title, int(11 * fig.get_figwidth())), fontsize=9)  # ~11 chars an inch
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    save_picture(fig, path, dpi=110)
    plt.close(fig)
    return path


#: The placed query gets a zoomed inset when its extent is below this fraction of the panel's.
ZOOM_FRACTION = 0.15


def scan_zoom(t: np.ndarray, q: np.ndarray) -> tuple[float, float, float, float] | None:
    """(x0, x1, y0, y1), metres: a square around the placed query's objects `q` (n,3) when they
    cover less than ZOOM_FRACTION of the panel spanned with the target's `t` (a small scan in a
    large map, lost at the panel's scale); None when they are large enough to see."""
    if len(q) == 0 or len(t) == 0:
        return None
    both = np.concatenate([t[:, :2], q[:, :2]])
    panel = float(np.ptp(both, axis=0).max())
    lo, hi = q[:, :2].min(axis=0), q[:, :2].max(axis=0)
    side = max(float((hi - lo).max()) * 1.3, 10.0)
    if side >= ZOOM_FRACTION * panel:
        return None
    cx, cy = (lo + hi) / 2
    return cx - side / 2, cx + side / 2, cy - side / 2, cy + side / 2


def _zoom_inset(ax, box, t: np.ndarray, q: np.ndarray, target: SemanticGraph,
                query: SemanticGraph) -> None:
    """An inset in `ax`'s upper right showing both maps within `box` (x0, x1, y0, y1),
    its place marked on the panel."""
    inset = ax.inset_axes([0.62, 0.62, 0.36, 0.36])
    _draw_maps(inset, t, q, target, query)
    inset.set_xlim(box[0], box[1])
    inset.set_ylim(box[2], box[3])
    inset.set_aspect("equal", adjustable="box")
    inset.tick_params(labelsize=6)
    inset.set_title(f"B's area, {box[1] - box[0]:.0f} m across", fontsize=7)
    ax.indicate_inset_zoom(inset, edgecolor="0.3")


def _matches_panel(side, t: np.ndarray, target: SemanticGraph, query: SemanticGraph,
                   m: np.ndarray):
    """Draw the matches panel on `side`: both maps, B in its own frame set beside A (target
    positions `t`), the (k,2) query-target matches `m` as lines; return their legend entry."""
    from matplotlib.lines import Line2D

    own = _beside(t, query.positions)
    _draw_maps(side, t, own, target, query)
    _draw_matches(side, own, t, m)
    side.set_title(f"{len(m)} final matches (B in its own frame, beside A)", fontsize=9)
    top_down(side)
    return Line2D([], [], color=MATCH_COLOUR, lw=1.0, label=f"{len(m)} final matches")


def _draw_routes(ax, routes: tuple[np.ndarray, np.ndarray], T_target_query: np.ndarray) -> list:
    """Draw robot A's route (solid) and robot B's (dashed, moved into A's frame by
    T_target_query), positions (n,3) in metres; return their legend entries."""
    from matplotlib.lines import Line2D

    ra, rb = routes[0], apply(T_target_query, routes[1])
    ax.plot(ra[:, 0], ra[:, 1], "-", c="0.35", lw=1.0)
    ax.plot(rb[:, 0], rb[:, 1], "--", c="0.55", lw=1.0)
    return [Line2D([], [], c="0.35", lw=1.0, label="robot A route"),
            Line2D([], [], c="0.55", ls="--", lw=1.0, label="robot B route")]


def plot_fleet(result, graphs: Sequence, path) -> Path:
    """The picture `path` (any of `picture_formats`) of a fleet result's merged map,
    top-down (x right, y up): each placed robot's objects (`graphs`, each in its own frame) with
    its own marker and colour, the fused objects as rings; unplaced robots named in the
    title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 6), dpi=100)
    n = len(result.placed)
    for k, i in enumerate(result.placed):
        p = apply(result.T_fleet_robot[i], graphs[i].positions)
        root = " (world frame)" if i == result.root else ""
        # Hollow markers, smaller for each robot drawn later: where two robots mapped the same
        # objects, both stay visible (one inside the other).
        ax.scatter(p[:, 0], p[:, 1], s=10 + 34 * (n - 1 - k) / max(n - 1, 1),
                   facecolors="none", edgecolors=CLASS_PALETTE[i % len(CLASS_PALETTE)],
                   marker=ROBOT_MARKERS[i % len(ROBOT_MARKERS)], linewidths=0.9,
                   label=f"{result.names[i]}{root}", zorder=2 + k)
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
    save_picture(fig, path)
    plt.close(fig)
    return path
