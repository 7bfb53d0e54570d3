"""A localization as a Rerun recording (.rrd, viewed with `rerun FILE.rrd`): both maps in 3D,
the query map under the estimated transform, and the final matches. Needs `sgloc[rerun]`.

Entities: `world/target` (robot A's objects, Points3D with class ids and palette colours),
`world/query` (Transform3D = T_target_query) with `world/query/objects` beneath it (robot B's
objects in its own frame, so the viewer places them), `world/matches` (LineStrips3D, target
frame)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.geometry import apply
from sgloc.maps.classes import class_colours
from sgloc.maps.graph import SemanticGraph
from sgloc.optional import require


def _rgb(labels: np.ndarray) -> np.ndarray:
    hexes = class_colours(labels)
    return np.array([[int(h[i : i + 2], 16) for i in (1, 3, 5)] for h in hexes], dtype=np.uint8)


def write_rerun(
    path: str | Path,
    target: SemanticGraph,
    query: SemanticGraph,
    T_target_query: np.ndarray,
    matches: np.ndarray,
) -> Path:
    """Write the recording to `path` (.rrd); returns the path."""
    rr = require("rerun", "rerun", "--rerun (a Rerun recording)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    T = np.asarray(T_target_query, dtype=np.float64)
    rec = rr.RecordingStream("sgloc")
    rec.save(str(path))
    rec.log("world/target", rr.Points3D(target.positions, class_ids=target.labels,
                                        colors=_rgb(target.labels), radii=0.6), static=True)
    rec.log("world/query", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
    rec.log("world/query/objects", rr.Points3D(query.positions, class_ids=query.labels,
                                               colors=_rgb(query.labels), radii=0.9),
            static=True)
    m = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    segs = np.stack([apply(T, query.positions[m[:, 0]]), target.positions[m[:, 1]]], axis=1)
    rec.log("world/matches", rr.LineStrips3D(segs, colors=[255, 0, 255]), static=True)
    rec.flush()
    rec.disconnect()
    return path
