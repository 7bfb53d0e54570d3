"""Every problem runs the compiled kernels, an empty one handled by its stage; the library run
on the numpy references instead (`references.paths.on_references`) gives the same results to
rounding."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
from references import acceptance as acceptance_reference
from references.paths import on_references

from sgloc import localize
from sgloc.consistency.pairwise import ConsistentPairs, common_partner_count, consistency_bits


def _path(path: str):
    """The context running `path`: the compiled kernels or the numpy references."""
    return on_references() if path == "reference" else contextlib.nullcontext()


def test_empty_problems_are_handled_by_their_stage():
    """No kernel sees an empty problem: each stage returns the empty result of its reference
    (the same shapes, types and values)."""
    from references import consistency, maps

    from sgloc.acceptance.assessment import squared_residuals_of
    from sgloc.consistency import local
    from sgloc.estimation import irls_refine
    from sgloc.maps.canonical import canonical_order, without_duplicates
    from sgloc.maps.graph import SemanticGraph
    from sgloc.rejection.neighbor import prune_bits

    e3 = np.zeros((0, 3))
    bits = np.zeros((0, 0), np.uint64)
    graph = SemanticGraph(e3, np.zeros(0, np.int64))
    pairs = [
        (consistency_bits(e3, e3, 1.0), consistency.consistency_bits(e3, e3, 1.0)),
        (ConsistentPairs(bits).all(), consistency.upper_pairs(bits)),
        (local.local_counts(e3, e3, 1.0, 5.0), consistency.local_counts(e3, e3, 1.0, 5.0)),
        (local.prune_local(e3, e3, 1.0, 0.5, 5.0), consistency.prune_local(e3, e3, 1.0, 0.5, 5.0)),
        (prune_bits(bits, np.zeros(0, np.int64), 0.5), np.zeros(0, np.int64)),
        (canonical_order(graph), maps.canonical_order(graph)),
        (without_duplicates(graph, np.zeros(0, np.int64)), np.zeros(0, np.int64)),
        (squared_residuals_of(np.eye(4), e3, e3),
         acceptance_reference.squared_residuals_of(np.eye(4), e3, e3)),
    ]  # fmt: skip
    for got, want in pairs:
        got, want = (list(x) if isinstance(x, tuple) else [x] for x in (got, want))
        for a, b in zip(got, want, strict=True):
            assert a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b)
    assert common_partner_count(bits, np.zeros(0, np.int64), np.zeros(0, np.int64)) == 0
    T = np.eye(4)
    assert irls_refine(e3, e3, T) is T


@pytest.mark.parametrize("m", [0, 3, 200])
def test_consistency_layer_same_either_way(m):
    rng = np.random.default_rng(m)
    src = rng.uniform(0, 80, (m, 3))
    dst = src + rng.normal(0, 3.0, src.shape)
    out = {}
    for path in ("reference", "compiled"):
        with _path(path):
            bits, degree = consistency_bits(src, dst, 4.0)
            pairs = ConsistentPairs(bits)
            k = np.random.default_rng(1).integers(0, max(pairs.size, 1), 40 if pairs.size else 0)
            sub = pairs.within(np.arange(m) % 3 != 0)
            ii, jj = pairs.all()
            out[path] = (bits, degree, pairs.size, pairs.at(k), sub.all(),
                         common_partner_count(bits, ii, jj))  # fmt: skip
    a, b = out["reference"], out["compiled"]
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and a[2] == b[2]
    for x, y in zip(a[3] + a[4], b[3] + b[4], strict=True):
        assert np.array_equal(x, y)
    assert a[5] == b[5]


def test_localize_same_either_way(airsim_graphs):
    q, t = airsim_graphs
    results = []
    for path in ("reference", "compiled"):
        with _path(path):
            results.append(localize(q, t, seed=4))
    a, b = results
    assert a.accepted and b.accepted and a.confidence == pytest.approx(b.confidence, abs=1e-9)
    assert np.abs(a.transform - b.transform).max() < 1e-9  # compiled fits: equal to rounding
    assert np.array_equal(a.matches, b.matches)


def test_register_same_either_way():
    from sgloc import register
    from sgloc.sim.correspondences import make_correspondences

    cs = make_correspondences(200, 0.7, np.random.default_rng(5))
    out = []
    for path in ("reference", "compiled"):
        with _path(path):
            out.append(register(cs.src, cs.dst, seed=3))
    a, b = out
    assert a.success and b.success and np.array_equal(a.inliers, b.inliers)
    assert np.abs(a.transform - b.transform).max() < 1e-9
