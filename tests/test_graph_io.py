"""SemanticGraph construction, derived matrices and graph files."""

import json

import numpy as np
import pytest

from sgloc import SemanticGraph
from sgloc.errors import GraphFileError, InvalidGraphError
from sgloc.maps.classes import AIRSIM_COLORS, colors_to_labels, pack_rgb, unpack_rgb


def test_edges_within_radius_and_distance_matrix():
    g = SemanticGraph([[0, 0, 0], [15, 0, 0], [30, 0, 0], [45, 0, 0]], [0, 1, 0, 2])
    assert g.distances[0, 2] == pytest.approx(30.0)
    A = g.adjacency.toarray()
    np.testing.assert_array_equal(A, [[0, 1, 0, 0], [1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0]])
    assert g.n_edges == 3
    np.testing.assert_array_equal(g.degrees, [1, 2, 2, 1])


def test_edge_radius_is_strict():
    g = SemanticGraph([[0, 0, 0], [20, 0, 0]], [0, 0], edge_radius=20.0)
    assert g.n_edges == 0
    assert g.with_edge_radius(20.001).n_edges == 1


def test_transformed_preserves_distances(rng):
    from sgloc.geometry import random_rigid_transform

    g = SemanticGraph(rng.uniform(-50, 50, (30, 3)), rng.integers(0, 4, 30))
    h = g.transformed(random_rigid_transform(rng))
    np.testing.assert_allclose(g.distances, h.distances, atol=1e-9)
    np.testing.assert_array_equal(g.adjacency.toarray(), h.adjacency.toarray())


@pytest.mark.parametrize("suffix", [".pcd", ".json", ".npz"])
def test_save_load_round_trip(tmp_path, rng, suffix):
    g = SemanticGraph(rng.uniform(-50, 50, (25, 3)), rng.integers(0, 11, 25))
    path = g.save(tmp_path / f"g{suffix}")
    h = SemanticGraph.load(path)
    np.testing.assert_allclose(h.positions, g.positions, atol=1e-5)
    np.testing.assert_array_equal(h.labels, g.labels)


def test_load_and_save_work_from_the_graph_module_alone(tmp_path):
    """A program that imports only `sgloc.maps.graph` reads and writes graph files: the
    formats (`sgloc.io`) register themselves with the maps; maps import no file format."""
    import subprocess
    import sys

    path = tmp_path / "g.json"
    path.write_text(json.dumps({"positions": [[0, 0, 0], [3, 4, 0]], "labels": [2, 5]}))
    code = (
        "import json, sys; from sgloc.maps.graph import SemanticGraph; "
        "before = 'sgloc.io.graph_files' in sys.modules; "
        f"g = SemanticGraph.load({str(path)!r}); "
        f"h = SemanticGraph.load(g.save({str(tmp_path / 'h.npz')!r})); "
        "from sgloc.io.graph_files import read_graph; from sgloc.maps.files import GRAPH_FILES; "
        "print(json.dumps([before, g.name, g.labels.tolist(), h.positions.tolist(), "
        "GRAPH_FILES.reader is read_graph]))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == [False, "g.json", [2, 5], [[0, 0, 0], [3, 4, 0]], True]


def test_no_registered_graph_file_functions_is_a_clear_error(tmp_path, monkeypatch):
    from sgloc.errors import SglocError
    from sgloc.maps.files import GRAPH_FILES

    g = SemanticGraph([[0, 0, 0]], [1])
    monkeypatch.setattr(GRAPH_FILES, "reader", None)
    monkeypatch.setattr(GRAPH_FILES, "writer", None)
    with pytest.raises(SglocError, match="no graph-file reader is registered"):
        SemanticGraph.load(tmp_path / "g.json")
    with pytest.raises(SglocError, match="no graph-file writer is registered"):
        g.save(tmp_path / "g.json")
    assert not (tmp_path / "g.json").exists()


def test_airsim_pcd_reads_guo_colours(airsim_graphs):
    c1, c2 = airsim_graphs
    assert (len(c1), len(c2)) == (318, 328)
    assert c1.labels.min() >= 0 and c1.labels.max() < len(AIRSIM_COLORS)
    # The first point of cloud1.pcd has rgb 11470476 = (175, 6, 140), class 0.
    assert unpack_rgb(np.array([11470476]))[0].tolist() == [175, 6, 140]
    assert c1.labels[0] == 0


def test_colour_table_round_trip():
    labels = colors_to_labels(unpack_rgb(pack_rgb(AIRSIM_COLORS)))
    np.testing.assert_array_equal(labels, np.arange(len(AIRSIM_COLORS)))
    assert colors_to_labels(np.array([[1, 2, 3]]))[0] == -1


def test_binary_pcd(tmp_path):
    pos = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.5]], dtype=np.float32)
    rgb = pack_rgb(AIRSIM_COLORS[[2, 5, 10]]).astype(np.uint32)
    rec = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    rec["x"], rec["y"], rec["z"], rec["rgb"] = pos[:, 0], pos[:, 1], pos[:, 2], rgb
    header = (
        "VERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\n"
        "WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA binary\n"
    )
    p = tmp_path / "b.pcd"
    p.write_bytes(header.encode() + rec.tobytes())
    g = SemanticGraph.load(p)
    np.testing.assert_allclose(g.positions, pos)
    np.testing.assert_array_equal(g.labels, [2, 5, 10])


# -- bad input --------------------------------------------------------------------------------


def test_missing_file(tmp_path):
    with pytest.raises(GraphFileError, match="no such file"):
        SemanticGraph.load(tmp_path / "nope.pcd")


def test_unknown_suffix(tmp_path):
    p = tmp_path / "g.xyz"
    p.write_text("1 2 3")
    with pytest.raises(GraphFileError, match="unknown graph format"):
        SemanticGraph.load(p)
    p = tmp_path / "g.txt"  # a table without a class column
    p.write_text("1 2 3")
    with pytest.raises(GraphFileError, match="class column"):
        SemanticGraph.load(p)


def test_malformed_pcd(tmp_path):
    p = tmp_path / "bad.pcd"
    p.write_text("FIELDS x y z rgb\nPOINTS 3\nDATA ascii\n1 2 3 11470476\n")
    with pytest.raises(GraphFileError, match="malformed PCD header|truncated"):
        SemanticGraph.load(p)
    p.write_text("this is not a point cloud")
    with pytest.raises(GraphFileError, match="no DATA line"):
        SemanticGraph.load(p)


def test_truncated_pcd(tmp_path):
    p = tmp_path / "short.pcd"
    p.write_text(
        "FIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nPOINTS 3\nDATA ascii\n1 2 3 11470476\n"
    )
    with pytest.raises(GraphFileError, match="truncated"):
        SemanticGraph.load(p)


def test_unknown_colour(tmp_path):
    p = tmp_path / "colour.pcd"
    p.write_text(
        "FIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nPOINTS 2\nDATA ascii\n"
        f"1 2 3 11470476\n4 5 6 {pack_rgb(np.array([[1, 2, 3]]))[0]}\n"
    )
    with pytest.raises(GraphFileError, match=r"not in the class table.*\(1, 2, 3\)"):
        SemanticGraph.load(p)


def test_malformed_json(tmp_path):
    p = tmp_path / "g.json"
    p.write_text(json.dumps({"points": []}))
    with pytest.raises(GraphFileError, match="needs keys 'positions'"):
        SemanticGraph.load(p)
    p.write_text("{not json")
    with pytest.raises(GraphFileError, match="invalid JSON graph"):
        SemanticGraph.load(p)


def test_nan_positions():
    with pytest.raises(InvalidGraphError, match="NaN or infinite.*row 1"):
        SemanticGraph([[0, 0, 0], [np.nan, 0, 0]], [0, 1])


def test_bad_shapes_and_labels():
    with pytest.raises(InvalidGraphError, match=r"shape \(n, 3\)"):
        SemanticGraph([[0, 0], [1, 1]], [0, 1])
    with pytest.raises(InvalidGraphError, match="labels must have shape"):
        SemanticGraph([[0, 0, 0]], [0, 1])
    with pytest.raises(InvalidGraphError, match=">= 0"):
        SemanticGraph([[0, 0, 0]], [-1])
    with pytest.raises(InvalidGraphError, match="integer class ids"):
        SemanticGraph([[0, 0, 0]], [0.5])


def test_empty_graph_is_allowed_but_has_no_edges():
    g = SemanticGraph(np.zeros((0, 3)), np.zeros(0, int))
    assert len(g) == 0 and g.n_edges == 0
