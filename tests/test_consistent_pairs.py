"""ConsistentPairs: the consistent pairs of packed rows, by position, without listing them; the
same pairs in the same order as np.nonzero(np.triu(M)) (and its masked form)."""

from __future__ import annotations

import numpy as np
import pytest
from references.consistency import upper_pairs

from sgloc.consistency.pairwise import ConsistentPairs, consistency_bits, pack_rows


def random_graph(m: int, p: float, rng: np.random.Generator) -> np.ndarray:
    R = np.triu(rng.random((m, m)) < p, 1)
    return R | R.T


@pytest.mark.parametrize("m, p", [(0, 0.5), (1, 0.5), (5, 0.5), (64, 0.3), (65, 0.0),
                                  (130, 0.1), (300, 0.6), (257, 1.0)])  # fmt: skip
def test_pairs_by_position_equal_numpy(m, p):
    rng = np.random.default_rng(m)
    R = random_graph(m, p, rng)
    pairs = ConsistentPairs(pack_rows(R) if m else np.zeros((0, 1), np.uint64))
    ref_i, ref_j = np.nonzero(np.triu(R))
    assert pairs.size == ref_i.size
    ii, jj = pairs.all()
    assert np.array_equal(ii, ref_i) and np.array_equal(jj, ref_j)
    if pairs.size:
        k = rng.integers(0, pairs.size, 50)  # unsorted, with repeats
        ii, jj = pairs.at(k)
        assert np.array_equal(ii, ref_i[k]) and np.array_equal(jj, ref_j[k])
        with pytest.raises(IndexError):
            pairs.at([pairs.size])


@pytest.mark.parametrize("m, p", [(70, 0.4), (300, 0.6), (129, 0.9)])
def test_masked_pairs_equal_numpy(m, p):
    rng = np.random.default_rng(m + 1)
    R = random_graph(m, p, rng)
    keep = rng.random(m) < 0.6
    sub = ConsistentPairs(pack_rows(R)).within(keep)
    ii, jj = np.nonzero(np.triu(R))
    ok = keep[ii] & keep[jj]
    ref_i, ref_j = ii[ok], jj[ok]
    assert sub.size == ref_i.size
    k = rng.integers(0, sub.size, 200)
    got = sub.at(k)
    assert np.array_equal(got[0], ref_i[k]) and np.array_equal(got[1], ref_j[k])
    assert np.array_equal(sub.all()[0], ref_i) and np.array_equal(sub.all()[1], ref_j)


def test_on_consistency_bits():
    rng = np.random.default_rng(3)
    src = rng.uniform(0, 100, (500, 3))
    dst = src + rng.normal(0, 2.0, src.shape)
    bits, degree = consistency_bits(src, dst, 3.0)
    pairs = ConsistentPairs(bits)
    assert pairs.size == degree.sum() // 2
    from sgloc.consistency.pairwise import consistent_pairs

    ref = consistent_pairs(bits, degree)
    assert all(np.array_equal(a, b) for a, b in zip(pairs.all(), ref, strict=True))
    assert all(np.array_equal(a, b) for a, b in zip(upper_pairs(bits), ref, strict=True))


def test_too_many_matches_is_a_clear_error(monkeypatch):
    # The limit lowered so the check runs on a small set; register names the fix in one line.
    import sgloc.consistency.pairwise as consistency
    from sgloc import register
    from sgloc.errors import TooManyMatchesError

    monkeypatch.setattr(consistency, "MAX_MATCHES", 50)
    pts = np.random.default_rng(0).uniform(-50, 50, (51, 3))
    with pytest.raises(TooManyMatchesError, match="51 matches are too many.*top_k"):
        consistency_bits(pts, pts, 1.0)
    with pytest.raises(TooManyMatchesError):
        register(pts, pts + 1.0, noise_bound=1.0, seed=0)
    consistency_bits(pts[:50], pts[:50], 1.0)  # at the limit: fine
