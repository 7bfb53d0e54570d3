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
    np.testing.assert_array_equal(a.sum(axis=1)[has_nb], rw.n_walks)


@pytest.mark.parametrize("name", [n for n in DESCRIPTORS if n != "triangles"])
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
    # Soft binning is continuous in the distances: equal up to the rounding of the motion.
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_unknown_descriptor():
    with pytest.raises(UnknownNameError, match="histogram"):
        make_descriptor("sift")


def test_distance_histogram_hand_checked(path_graph, rng):
    # radius 40 m, 4 bins of 10 m centred at 5, 15, 25, 35 m; layout (class, bin) -> class*4+bin.
    D = dense(
        make_descriptor("distance_histogram", radius=40.0, n_bins=4, taper=0.0)(path_graph, 2, rng)
    )
    expected = np.zeros((4, 8))
    expected[0, 4 + 1] = 1.0  # 0 sees 1 (class 1) at 15 m: exactly the centre of bin 1
    expected[0, 0 + 2] = 0.5  # 0 sees 2 (class 0) at 30 m: halfway between bins 2 and 3
    expected[0, 0 + 3] = 0.5
    expected[1, 0 + 1] = 2.0  # 1 sees 0 and 2 (class 0) at 15 m
    expected[2] = expected[0]  # 2 mirrors 0
    np.testing.assert_allclose(D, expected)  # 3 is 70 m from everything: no descriptor


def test_distance_histogram_taper_weighs_near_neighbours_more(path_graph, rng):
    desc = make_descriptor("distance_histogram", radius=40.0, n_bins=4, taper=0.5)
    D = dense(desc(path_graph, 2, rng))
    # Vertex 0: the neighbour at 15 m weighs 1 - 0.5 * 15/40, the one at 30 m 1 - 0.5 * 30/40.
    np.testing.assert_allclose(D[0, 4 + 1], 1 - 0.5 * 15 / 40)
    np.testing.assert_allclose(D[0, 2:4], 0.5 * (1 - 0.5 * 30 / 40))


def test_distance_histogram_soft_binning_is_continuous(rng):
    g = SemanticGraph([[0, 0, 0], [12.0, 0, 0]], [0, 0])
    h = SemanticGraph([[0, 0, 0], [12.5, 0, 0]], [0, 0])
    desc = make_descriptor("distance_histogram", radius=40.0, n_bins=4, taper=0.0)
    a, b = dense(desc(g, 1, rng))[0], dense(desc(h, 1, rng))[0]
    np.testing.assert_allclose(a, [0.3, 0.7, 0, 0])  # 12 m: 30 % bin 0 (5 m), 70 % bin 1
    np.testing.assert_allclose(b, [0.25, 0.75, 0, 0])
    assert a @ b / np.linalg.norm(a) / np.linalg.norm(b) > 0.99


def test_triangles_hand_checked(rng):
    # Vertex 0 (class 0) at the origin, 1 (class 1) at 5 m, 2 (class 0) at 15 m on the y axis.
    g = SemanticGraph([[0, 0, 0], [5, 0, 0], [0, 15, 0]], [0, 1, 0])
    D = dense(make_descriptor("triangles", radius=20.0, n_bins=2)(g, 2, rng)).reshape(3, 2, 2, 2, 2)
    # Signature (class a <= class b, then side a <= side b): bins of 10 m.
    # 0: others 1 (class 1, 5 m) and 2 (class 0, 15 m) -> classes (0, 1), sides (15, 5) -> (1, 0).
    assert D[0, 0, 1, 1, 0] == 1 and D[0].sum() == 1
    # 1: others 0 (class 0, 5 m) and 2 (class 0, 15.8 m) -> (0, 0), sides sorted (5, 15.8).
    assert D[1, 0, 0, 0, 1] == 1 and D[1].sum() == 1
    # 2: others 0 (class 0, 15 m) and 1 (class 1, 15.8 m) -> (0, 1), sides (15, 15.8).
    assert D[2, 0, 1, 1, 1] == 1 and D[2].sum() == 1
