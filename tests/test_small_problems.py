"""Every problem runs the compiled kernels (`sgloc.kernels.use_compiled`); the numpy references
give the same results to rounding."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from sgloc import kernels, localize
from sgloc.consistency.pairwise import ConsistentPairs, common_partner_count, consistency_bits


def test_rule(monkeypatch):
    """Not whether numba is loaded, nor how many problems ran before: every non-empty problem
    runs the kernels unless FORCE says otherwise."""
    monkeypatch.setattr(kernels, "FORCE", None)
    monkeypatch.delitem(sys.modules, "numba", raising=False)
    calls = [kernels.use_compiled(10) for _ in range(30)]
    assert calls == [True] * 30 and not kernels.use_compiled(0)
    monkeypatch.setattr(kernels, "FORCE", "reference")
    assert not kernels.use_compiled(10)


@pytest.mark.parametrize("m", [0, 3, 200])
def test_consistency_layer_same_either_way(monkeypatch, m):
    rng = np.random.default_rng(m)
    src = rng.uniform(0, 80, (m, 3))
    dst = src + rng.normal(0, 3.0, src.shape)
    out = {}
    for path in ("reference", "compiled"):
        monkeypatch.setattr(kernels, "FORCE", path)
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


def test_localize_same_either_way(monkeypatch, airsim_graphs):
    q, t = airsim_graphs
    results = []
    for path in ("reference", "compiled"):
        monkeypatch.setattr(kernels, "FORCE", path)
        results.append(localize(q, t, seed=4))
    a, b = results
    assert a.success and b.success and a.confidence == pytest.approx(b.confidence, abs=1e-9)
    assert np.abs(a.transform - b.transform).max() < 1e-9  # compiled fits: equal to rounding
    assert np.array_equal(a.matches, b.matches)


def test_register_same_either_way(monkeypatch):
    from sgloc import register
    from sgloc.sim.correspondences import make_correspondences

    cs = make_correspondences(200, 0.7, np.random.default_rng(5))
    out = []
    for path in ("reference", "compiled"):
        monkeypatch.setattr(kernels, "FORCE", path)
        out.append(register(cs.src, cs.dst, seed=3))
    a, b = out
    assert a.success and b.success and np.array_equal(a.inliers, b.inliers)
    assert np.abs(a.transform - b.transform).max() < 1e-9
