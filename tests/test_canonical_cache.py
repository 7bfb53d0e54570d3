"""The localizer's canonical form: built for every call (no module keeps it: a target used
again is prepared once, `sgloc.prepare`), the same for the same graphs, and its class table."""

from __future__ import annotations

import gc
import weakref

import numpy as np

from sgloc import SemanticGraph, localize
from sgloc.maps.canonical import CanonicalPair
from sgloc.pipeline.config import LocalizerConfig


def test_canonical_form_is_built_per_call_and_the_same(airsim_graphs):
    q, t = airsim_graphs
    cfg = LocalizerConfig()
    a, b = CanonicalPair(q, t, cfg), CanonicalPair(q, t, cfg)
    assert a.query is not b.query and a.target is not b.target  # nothing kept between calls
    for x, y in ((a.query, b.query), (a.target, b.target)):
        assert np.array_equal(x.positions, y.positions) and np.array_equal(x.labels, y.labels)
    assert np.array_equal(a.query_order, b.query_order)
    assert a.prepared_target is None  # a graph target: prepared for the call by the localizer
    # Another class table (a partner with other classes) gives another canonical graph.
    few = SemanticGraph(t.positions[:20], np.full(20, int(q.labels.max()) + 1), t.edge_radius)
    c = CanonicalPair(q, few, cfg)
    assert int(q.labels.max()) + 1 in c.classes and int(q.labels.max()) + 1 not in a.classes


def test_repeated_localize_gives_the_same_answer(airsim_graphs):
    q, t = airsim_graphs
    first, second = localize(q, t, seed=2), localize(q, t, seed=2)
    assert first.accepted and second.accepted
    assert np.array_equal(first.transform, second.transform)
    assert np.array_equal(first.matches, second.matches)


def test_the_pair_keeps_no_graph_alive():
    rng = np.random.default_rng(0)
    g = SemanticGraph(rng.uniform(0, 50, (30, 3)), rng.integers(0, 3, 30))
    h = SemanticGraph(rng.uniform(0, 50, (30, 3)), rng.integers(0, 3, 30))
    localize(g, h)
    refs = [weakref.ref(g), weakref.ref(h)]
    del g, h
    gc.collect()
    assert all(r() is None for r in refs)  # no module holds the graphs (or their forms)


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
