"""spatially_distinctive: the ratio test with rivals only at other places."""

from __future__ import annotations

import numpy as np

from sgloc.acceptance import spatially_distinctive

# Query 0 matches target 0 (cosine 0.95); target 1 is a near tie (0.94), target 2 a clearly
# worse object (0.5). All of one class.
DQ = np.array([[1.0, 0.0]])
DT = np.array([[s, np.sqrt(1 - s**2)] for s in (0.95, 0.94, 0.5)])
LABELS = np.zeros(3, dtype=np.int64)
CAND = np.array([[0, 0]])


def _positions(rival_m: float) -> np.ndarray:
    return np.array([[0.0, 0, 0], [rival_m, 0, 0], [100.0, 0, 0]])


def test_a_near_tie_far_away_is_an_ambiguity():
    assert not spatially_distinctive(DQ, DT, LABELS, _positions(50.0), CAND, 0.8, 10.0)[0]


def test_a_near_tie_next_to_the_target_is_no_rival():
    # The look-alike 6 m from the target is the same place: the rival is target 2.
    assert spatially_distinctive(DQ, DT, LABELS, _positions(6.0), CAND, 0.8, 10.0)[0]
    # Without exclusion it is the usual ratio test, which the near tie fails.
    assert not spatially_distinctive(DQ, DT, LABELS, _positions(6.0), CAND, 0.8, 0.0)[0]


def test_rivals_are_of_the_candidates_class_and_none_passes():
    labels = np.array([0, 1, 1])  # the near tie is of another class: no rival of class 0
    assert spatially_distinctive(DQ, DT, labels, _positions(50.0), CAND, 0.8, 10.0)[0]
    none = spatially_distinctive(DQ, DT, LABELS, _positions(50.0), np.zeros((0, 2)), 0.8, 10.0)
    assert none.size == 0


def test_matches_the_plain_ratio_test_without_exclusion():
    from sgloc.matching.candidates import MatchingConfig, match_descriptors, match_flagged

    gen = np.random.default_rng(0)
    dq, dt = gen.random((30, 8)), gen.random((80, 8))
    lq, lt = gen.integers(0, 2, 30), gen.integers(0, 2, 80)
    cand, _, flags = match_flagged(dq, dt, lq, lt, MatchingConfig(min_similarity=0.0), 0.97)
    got = spatially_distinctive(dq, dt, lt, gen.random((80, 3)) * 100, cand, 0.97, 0.0)
    assert 0 < got.sum() < len(got)  # some pass, some fail: the comparison means something
    np.testing.assert_array_equal(got, flags)
    strict = match_descriptors(dq, dt, lq, lt, MatchingConfig(min_similarity=0.0, max_ratio=0.97))
    assert len(strict[0]) == got.sum()
