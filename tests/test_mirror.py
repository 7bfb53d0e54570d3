"""A map mirrored (x -> -x) against itself is refused, not accepted through the part of it that
is nearly its own mirror image; true pairs stay accepted."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc import SemanticGraph, localize
from sgloc.acceptance.mirror import looks_mirrored, reflect_across_line
from sgloc.geometry import apply, make_transform


@pytest.mark.parametrize("which", [0, 1])
@pytest.mark.parametrize("axis", [0, 1])
def test_mirrored_map_against_itself_is_refused(airsim_graphs, which, axis):
    g = airsim_graphs[which]
    flip = np.ones(3)
    flip[axis] = -1.0
    r = localize(SemanticGraph(g.positions * flip, g.labels), g, seed=0)
    assert not r.accepted and r.transform is None
    assert "mirrored" in r.reason


def test_true_pairs_are_not_taken_for_mirrors(airsim_graphs):
    q, t = airsim_graphs
    T = make_transform(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), [40, 7, 1])
    moved = SemanticGraph(apply(T, t.positions), t.labels)
    for query, target in ((q, t), (t, q), (q, moved)):
        r = localize(query, target, seed=0)
        assert r.accepted, r.reason
        mirrored, plain, flipped = looks_mirrored(query, target, r.transform,
                                                  np.unique(r.matches[:, 0]), 5.0)  # fmt: skip
        assert not mirrored and plain > 2 * flipped


def test_reflection_keeps_the_line_and_flips_across_it():
    line = np.array([[0.0, 0.0, 0.0], [10.0, 10.0, 1.0], [20.0, 20.0, 2.0]])
    out = reflect_across_line(np.array([[0.0, 10.0, 3.0], [5.0, 5.0, 0.0]]), line)
    np.testing.assert_allclose(out, [[10.0, 0.0, 3.0], [5.0, 5.0, 0.0]], atol=1e-12)


def test_mirrored_crops_are_refused_and_true_crops_kept(airsim_graphs):
    """Crops of 4-120 objects: mirrored ones against the map they were cut from are refused;
    the true crops accepted as often as without the mirror test. (A mirrored crop of the other
    robot's map can still be accepted at a wrong place, as any negative can: 1 of 30 here.)"""
    import sgloc.acceptance.mirror as mirror

    q, t = airsim_graphs
    rng = np.random.default_rng(1)
    accepted = {"mirror": 0, "true": 0, "true without the test": 0}
    for s in range(12):
        src, dst = (q, t) if s % 2 else (t, q)
        c = src.positions[rng.integers(len(src))]
        for radius in (20, 40, 100):
            idx = np.flatnonzero(np.linalg.norm(src.positions[:, :2] - c[:2], axis=1) < radius)
            if len(idx) < 4:
                continue
            crop = SemanticGraph(src.positions[idx], src.labels[idx])
            flipped = SemanticGraph(src.positions[idx] * [-1, 1, 1], src.labels[idx])
            accepted["mirror"] += localize(flipped, src, seed=s).accepted
            accepted["true"] += localize(crop, dst, seed=s).accepted
            mirror.MIRROR_MARGIN, old = 10**9, mirror.MIRROR_MARGIN
            try:
                accepted["true without the test"] += localize(crop, dst, seed=s).accepted
            finally:
                mirror.MIRROR_MARGIN = old
    assert accepted["mirror"] == 0
    assert accepted["true"] == accepted["true without the test"] > 5
