"""Cosine-similarity matching: same class only, threshold, top-k, mutual."""

import numpy as np

from sgloc.matching import MatchingConfig, cosine_similarity, match_descriptors


def test_cosine_similarity_same_class_only():
    dq = np.array([[1.0, 0.0], [1.0, 1.0]])
    dt = np.array([[2.0, 0.0], [0.0, 3.0], [1.0, 1.0]])
    S = cosine_similarity(dq, dt, np.array([0, 0]), np.array([0, 0, 1]))
    np.testing.assert_allclose(S[0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(S[1], [np.sqrt(0.5), np.sqrt(0.5), 0.0])  # class 1 masked


def test_zero_descriptor_never_matches():
    dq = np.array([[0.0, 0.0]])
    dt = np.array([[0.0, 0.0]])
    m, s = match_descriptors(dq, dt, np.array([0]), np.array([0]), MatchingConfig(0.0))
    assert len(m) == 0


def test_threshold_and_best_per_query():
    dq = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    dt = np.array([[1.0, 0.1], [0.2, 1.0]])
    lq, lt = np.zeros(3, int), np.zeros(2, int)
    m, s = match_descriptors(dq, dt, lq, lt, MatchingConfig(min_similarity=0.9))
    np.testing.assert_array_equal(m, [[0, 0], [1, 1]])  # query 2 is at most 0.83 similar
    assert np.all(s >= 0.9)


def test_top_k_and_mutual():
    dq = np.array([[1.0, 0.0], [0.9, 0.1]])
    dt = np.array([[1.0, 0.0], [0.8, 0.3]])
    lq, lt = np.zeros(2, int), np.zeros(2, int)
    m2, _ = match_descriptors(dq, dt, lq, lt, MatchingConfig(min_similarity=0.5, top_k=2))
    assert len(m2) == 4
    np.testing.assert_array_equal(m2[:2], [[0, 0], [0, 1]])  # ordered by score per query
    m1, _ = match_descriptors(dq, dt, lq, lt, MatchingConfig(min_similarity=0.5, mutual=True))
    # Both queries prefer target 0; target 0 prefers query 0: only (0, 0) is mutual.
    np.testing.assert_array_equal(m1, [[0, 0]])
