"""The localizer's answer does not depend on the vertex order of either graph, nor on how large
the class ids are (they are renumbered to the classes present before anything is sized)."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sgloc import SemanticGraph, localize
from sgloc.maps.canonical import CanonicalPair, canonical_order
from sgloc.pipeline.config import LocalizerConfig


def as_set(pairs, q_index=None, t_index=None):
    pairs = np.asarray(pairs).reshape(-1, 2)
    q = pairs[:, 0] if q_index is None else q_index[pairs[:, 0]]
    t = pairs[:, 1] if t_index is None else t_index[pairs[:, 1]]
    return set(zip(q.tolist(), t.tolist(), strict=True))


@pytest.mark.parametrize("descriptor", ["histogram", "random_walk"])
@settings(
    max_examples=3, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(seed=st.integers(0, 2**32 - 1))
def test_same_result_for_any_vertex_order(airsim_graphs, descriptor, seed):
    q, t = airsim_graphs
    reference = localize(q, t, descriptor, seed=3)
    rng = np.random.default_rng(seed)
    pq, pt = rng.permutation(len(q)), rng.permutation(len(t))
    res = localize(q.subgraph(pq), t.subgraph(pt), descriptor, seed=3)
    assert res.accepted == reference.accepted
    if reference.accepted:
        np.testing.assert_allclose(res.transform, reference.transform, atol=1e-9, rtol=0)
        assert res.confidence == pytest.approx(reference.confidence, abs=1e-9)
    # Indices come back in the caller's order: map them to the unpermuted vertices to compare.
    assert as_set(res.matches, pq, pt) == as_set(reference.matches)
    assert as_set(res.candidates, pq, pt) == as_set(reference.candidates)


def test_large_class_ids_give_the_same_answer(airsim_graphs):
    q, t = airsim_graphs
    reference = localize(q, t, seed=1)
    big = 2**31 - 1 - 40 * 13  # monotone relabelling ending near the largest allowed id
    q2 = SemanticGraph(q.positions, q.labels * 40 + big - 40 * 12, q.edge_radius)
    t2 = SemanticGraph(t.positions, t.labels * 40 + big - 40 * 12, t.edge_radius)
    res = localize(q2, t2, seed=1)
    assert res.accepted and reference.accepted
    np.testing.assert_allclose(res.transform, reference.transform, atol=1e-9, rtol=0)


def test_class_weights_follow_the_renumbered_classes():
    rng = np.random.default_rng(0)
    q = SemanticGraph(rng.uniform(0, 50, (8, 3)), [500, 500, 7, 7, 7, 9, 9, 500])
    t = SemanticGraph(rng.uniform(0, 50, (6, 3)), [7, 9, 9, 12, 12, 7])
    cfg = LocalizerConfig().with_overrides(class_weights={500: 3.0, 12: 5.0, 4: 2.0})
    pair = CanonicalPair(q, t, cfg)
    assert pair.classes.tolist() == [7, 9, 12, 500]
    assert pair.config.class_weights == {3: 3.0, 2: 5.0}
    assert sorted(set(pair.query.labels.tolist())) == [0, 1, 3]
    assert pair.original_config.class_weights == {500: 3.0, 12: 5.0, 4: 2.0}


def test_canonical_order_sorts_by_class_then_position():
    g = SemanticGraph([[5, 0, 0], [1, 0, 0], [3, 0, 0], [0, 9, 0]], [2, 2, 1, 2])
    assert canonical_order(g).tolist() == [2, 3, 1, 0]


def test_memory_is_bounded_by_the_classes_present(airsim_graphs):
    """One class id of 1000 (or 2**31 - 1) must not size arrays by the id."""
    import tracemalloc

    q, t = airsim_graphs
    labels = q.labels.copy()
    labels[0] = 2**31 - 1
    q_big = SemanticGraph(q.positions, labels, q.edge_radius)
    tracemalloc.start()
    try:
        localize(q_big, t, "histogram", seed=0)
        localize(q_big, t, "random_walk", seed=0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 100 * 2**20


def test_cached_adjacency_is_carried_over_permuted(airsim_graphs):
    q, t = airsim_graphs
    _ = q.adjacency, t.adjacency, q.distances
    pair = CanonicalPair(q, t, LocalizerConfig())
    fresh = SemanticGraph(pair.query.positions, pair.query.labels, q.edge_radius)
    assert (pair.query.adjacency != fresh.adjacency).nnz == 0
    np.testing.assert_array_equal(pair.query.distances, fresh.distances)
