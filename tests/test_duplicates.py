"""Maps that list every object twice: exact copies localize as the map itself; copies side by
side are refused with a reason that says so (not "0 inliers lie within a few metres")."""

from __future__ import annotations

import numpy as np

from sgloc import SemanticGraph, localize


def _twice(g: SemanticGraph, offset: float) -> SemanticGraph:
    rng = np.random.default_rng(0)
    copy = g.positions + rng.normal(0.0, offset, g.positions.shape)
    return SemanticGraph(np.vstack([g.positions, copy]), np.concatenate([g.labels, g.labels]))


def test_every_object_listed_twice_in_both_maps_localizes(airsim_graphs):
    q, t = airsim_graphs
    plain = localize(q, t, seed=0)
    for query, target in ((_twice(q, 0.0), _twice(t, 0.0)), (_twice(q, 1e-5), t)):
        r = localize(query, target, seed=0)
        assert r.accepted, r.reason
        assert np.allclose(r.transform, plain.transform, atol=1e-4)  # copies 1e-5 m apart
        assert len(r.matches) == len(plain.matches)
    exact = localize(_twice(q, 0.0), _twice(t, 0.0), seed=0)
    assert exact.matches[:, 0].max() < len(q) and exact.matches[:, 1].max() < len(t)  # 1st copy


def test_copies_side_by_side_get_a_reason_that_names_them(airsim_graphs):
    q, t = airsim_graphs
    r = localize(_twice(q, 0.1), _twice(t, 0.1), seed=0)
    assert not r.accepted
    assert "no candidate match is distinctive" in r.reason and "distinct_ratio=null" in r.reason
    assert "0 inliers" not in r.reason
    assert localize(_twice(q, 0.1), _twice(t, 0.1), seed=0, distinct_ratio=None).accepted
