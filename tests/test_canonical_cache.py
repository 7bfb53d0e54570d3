"""The localizer's canonical form is built once per caller's graph: later calls with the same
map reuse it, and with it every cache the canonical graph holds (descriptors, adjacency)."""

from __future__ import annotations

import gc
import weakref

import numpy as np

from sgloc import SemanticGraph, localize
from sgloc.canonical import CANONICAL_FORMS, CanonicalPair
from sgloc.config import LocalizerConfig
from sgloc.descriptors import distance


def test_canonical_graph_is_reused_per_input_graph(airsim_graphs):
    q, t = airsim_graphs
    cfg = LocalizerConfig()
    a, b = CanonicalPair(q, t, cfg), CanonicalPair(q, t, cfg)
    assert a.query is b.query and a.target is b.target
    assert np.array_equal(a.query_order, b.query_order)
    # Another class table (a partner with other classes) gives another canonical graph.
    few = SemanticGraph(t.positions[:20], np.full(20, int(q.labels.max()) + 1), t.edge_radius)
    c = CanonicalPair(q, few, cfg)
    assert c.query is not a.query
    assert CanonicalPair(q, t, cfg).query is a.query


def test_repeated_localize_gives_the_same_answer(airsim_graphs):
    q, t = airsim_graphs
    first, second = localize(q, t, seed=2), localize(q, t, seed=2)
    assert first.success and second.success
    assert np.array_equal(first.transform, second.transform)
    assert np.array_equal(first.matches, second.matches)
    # The descriptors of later calls come from the canonical graphs' cache.
    pair = CanonicalPair(q, t, LocalizerConfig())
    assert pair.query in distance.DESCRIPTOR_CACHE and pair.target in distance.DESCRIPTOR_CACHE


def test_cache_entries_go_with_the_graph():
    rng = np.random.default_rng(0)
    g = SemanticGraph(rng.uniform(0, 50, (30, 3)), rng.integers(0, 3, 30))
    h = SemanticGraph(rng.uniform(0, 50, (30, 3)), rng.integers(0, 3, 30))
    CanonicalPair(g, h, LocalizerConfig())
    assert g in CANONICAL_FORMS and h in CANONICAL_FORMS
    refs = [weakref.ref(g), weakref.ref(h)]
    gc.collect()  # earlier tests' graphs may go too: count only these two
    n = len(CANONICAL_FORMS)
    del g, h
    gc.collect()
    assert all(r() is None for r in refs)  # nothing (the cache included) kept them alive
    assert len(CANONICAL_FORMS) == n - 2


def test_class_table_is_the_sorted_union_of_the_ids():
    """The pair's class table is np.union1d of both graphs' class ids, small ids (marked in a
    table) or large ones (sorted)."""
    rng = np.random.default_rng(2)
    cfg = LocalizerConfig()
    for top in (5, 40, 10**9):
        lq, lt = rng.integers(0, top, 30), rng.integers(0, top, 25)
        q = SemanticGraph(rng.uniform(-20, 20, (30, 3)), lq)
        t = SemanticGraph(rng.uniform(-20, 20, (25, 3)), lt)
        classes = CanonicalPair(q, t, cfg).classes
        assert classes.dtype == np.int64
        np.testing.assert_array_equal(classes, np.union1d(lq, lt))
