"""3D scene graphs of the Hydra / Kimera ecosystem (spark-dsg's `DynamicSceneGraph`, saved as
`.json` or binary `.sparkdsg`) read as object maps: the objects layer's node positions (metres,
the scene graph's world frame) and semantic labels. Needs the extra `pip install 'sgloc[dsg]'`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.errors import GraphFileError
from sgloc.optional import require

#: What a spark-dsg JSON file starts with (its header key), to tell it from sgloc's own JSON.
DSG_JSON_HEADER = b'"SPARK_DSG_header"'


def is_scene_graph_json(head: bytes) -> bool:
    """Whether the first bytes of a JSON file are those of a spark-dsg scene graph."""
    return DSG_JSON_HEADER in head[:256]


def read_scene_graph(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(positions (n,3) metres, labels (n,) int64) of the objects layer of the scene graph at
    `path`; GraphFileError when it cannot be read or holds no object."""
    dsg = require("spark_dsg", "dsg", "reading 3D scene graphs (Hydra / spark-dsg)")
    try:
        graph = dsg.DynamicSceneGraph.load(str(path))
    except Exception as e:  # the bindings raise plain RuntimeErrors of several kinds
        raise GraphFileError(
            f"{path}: not a readable spark-dsg scene graph ({type(e).__name__}: {e})."
        ) from None
    if not graph.has_layer(dsg.DsgLayers.OBJECTS):
        raise GraphFileError(f"{path}: the scene graph has no objects layer.")
    nodes = list(graph.get_layer(dsg.DsgLayers.OBJECTS).nodes)
    if not nodes:
        raise GraphFileError(f"{path}: the scene graph's objects layer is empty.")
    positions = np.array([n.attributes.position for n in nodes], dtype=np.float64)
    labels = np.array([n.attributes.semantic_label for n in nodes], dtype=np.int64)
    return positions.reshape(-1, 3), labels
