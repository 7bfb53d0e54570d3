"""3D scene graphs (Hydra / spark-dsg) read as object maps: the objects layer."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc import SemanticGraph, localize
from sgloc.datasets.downloads import airsim_guo
from sgloc.errors import GraphFileError

dsg = pytest.importorskip("spark_dsg", reason="the extra sgloc[dsg] (spark-dsg) is not installed")


def _scene_graph(positions: np.ndarray, labels: np.ndarray):
    graph = dsg.DynamicSceneGraph()
    for i, (p, c) in enumerate(zip(positions, labels, strict=True)):
        attrs = dsg.ObjectNodeAttributes()
        attrs.position = np.asarray(p, dtype=np.float64)
        attrs.semantic_label = int(c)
        graph.add_node(dsg.DsgLayers.OBJECTS, dsg.NodeSymbol("O", i), attrs)
    return graph


@pytest.mark.parametrize("suffix", [".json", ".sparkdsg"])
def test_objects_layer_read_as_a_graph(tmp_path, suffix):
    q, t = airsim_guo()
    path = tmp_path / f"dsg{suffix}"
    _scene_graph(q.positions, q.labels).save(str(path), include_mesh=False)
    g = SemanticGraph.load(path)
    np.testing.assert_array_equal(g.positions, q.positions)
    np.testing.assert_array_equal(g.labels, q.labels)
    assert localize(g, t).accepted == localize(q, t).accepted


def test_sgloc_json_is_still_sgloc_json(tmp_path):
    q, _ = airsim_guo()
    path = q.save(tmp_path / "map.json")
    np.testing.assert_array_equal(SemanticGraph.load(path).positions, q.positions)


def test_scene_graph_without_objects_is_a_clear_error(tmp_path):
    path = tmp_path / "empty.sparkdsg"
    dsg.DynamicSceneGraph().save(str(path), include_mesh=False)
    with pytest.raises(GraphFileError, match="objects layer"):
        SemanticGraph.load(path)
    bad = tmp_path / "bad.sparkdsg"
    bad.write_bytes(b"not a scene graph")
    with pytest.raises(GraphFileError, match="bad.sparkdsg"):
        SemanticGraph.load(bad)
