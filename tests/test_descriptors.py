"""Hand-checked descriptors on a 3-vertex path 0 - 1 - 2 (labels 0, 1, 0) plus an isolated
vertex 3 (label 1). Edges: 0-1 and 1-2 (15 m); 0-2 is 30 m apart, no edge."""

import numpy as np
import pytest
from scipy import sparse

from sgloc import SemanticGraph
from sgloc.descriptors import DESCRIPTORS, make_descriptor
from sgloc.errors import UnknownNameError


@pytest.fixture
def path_graph():
    return SemanticGraph([[0, 0, 0], [15, 0, 0], [30, 0, 0], [100, 0, 0]], [0, 1, 0, 1])


def dense(D):
    return D.toarray() if sparse.issparse(D) else np.asarray(D)


def test_histogram_counts_two_hop_label_paths(path_graph, rng):
    H = dense(make_descriptor("histogram")(path_graph, 2, rng))
    # Bins are (l_j, l_k) -> l_j * 2 + l_k.
    # Vertex 0: paths 0-1-0 and 0-1-2, both (l_j, l_k) = (1, 0) -> bin 2, count 2.
    # Vertex 1: paths 1-0-1 and 1-2-1, both (0, 1) -> bin 1, count 2.
    np.testing.assert_array_equal(H, [[0, 0, 2, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 0]])


def test_histogram_three_classes(rng):
    # Star: centre 0 (class 2) with leaves 1 (class 0) and 2 (class 1), leaves 28 m apart.
    g = SemanticGraph([[0, 0, 0], [14, 0, 0], [-14, 0, 0]], [2, 0, 1])
    H = dense(make_descriptor("histogram")(g, 3, rng)).reshape(3, 3, 3)
    # Centre: 0->1->0 gives (l_j=0, l_k=2); 0->2->0 gives (1, 2).
    expected_centre = np.zeros((3, 3))
    expected_centre[0, 2] = expected_centre[1, 2] = 1
    np.testing.assert_array_equal(H[0], expected_centre)
    # Leaf 1: 1->0->1 (2, 0) and 1->0->2 (2, 1).
    expected_leaf = np.zeros((3, 3))
    expected_leaf[2, 0] = expected_leaf[2, 1] = 1
    np.testing.assert_array_equal(H[1], expected_leaf)


def test_fast_counts_direct_neighbour_labels(path_graph, rng):
    F = dense(make_descriptor("fast")(path_graph, 2, rng))
    np.testing.assert_array_equal(F, [[0, 1], [2, 0], [0, 1], [0, 0]])


def test_random_walk_label_sequences(path_graph, rng):
    D = dense(make_descriptor("random_walk", n_walks=50, walk_length=2)(path_graph, 2, rng))
    # From 0: step to 1 (label 1), then to 0 or 2 (label 0): sequence (1, 0) -> code 2.
    # From 1: to 0 or 2 (label 0), then back to 1 (label 1): sequence (0, 1) -> code 1.
    np.testing.assert_array_equal(D[0], [0, 0, 50, 0])
    np.testing.assert_array_equal(D[1], [0, 50, 0, 0])
    np.testing.assert_array_equal(D[2], [0, 0, 50, 0])
    np.testing.assert_array_equal(D[3], [0, 0, 0, 0])  # isolated: no descriptor


def test_random_walk_is_seeded():
    rng0 = np.random.default_rng(0)
    g = SemanticGraph(rng0.uniform(0, 60, (40, 3)), rng0.integers(0, 4, 40))
    rw = make_descriptor("random_walk")
    a = dense(rw(g, 4, np.random.default_rng(7)))
    b = dense(rw(g, 4, np.random.default_rng(7)))
    c = dense(rw(g, 4, np.random.default_rng(8)))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # Every vertex with a neighbour has n_walks walks.
    has_nb = g.degrees > 0
    np.testing.assert_array_equal(a.sum(axis=1)[has_nb], 200)


@pytest.mark.parametrize("name", list(DESCRIPTORS))
def test_isolated_vertex_has_no_descriptor(name, path_graph, rng):
    D = dense(make_descriptor(name)(path_graph, 2, rng))
    assert not D[3].any()
    assert D[:3].any(axis=1).all()


@pytest.mark.parametrize("name", list(DESCRIPTORS))
def test_descriptors_invariant_to_rigid_motion(name, rng):
    from sgloc.geometry import random_rigid_transform

    g = SemanticGraph(rng.uniform(0, 80, (50, 3)), rng.integers(0, 5, 50))
    h = g.transformed(random_rigid_transform(rng))
    a = dense(make_descriptor(name)(g, 5, np.random.default_rng(1)))
    b = dense(make_descriptor(name)(h, 5, np.random.default_rng(1)))
    np.testing.assert_array_equal(a, b)


def test_unknown_descriptor():
    with pytest.raises(UnknownNameError, match="histogram"):
        make_descriptor("sift")
