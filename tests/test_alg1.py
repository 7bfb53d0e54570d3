"""The paper's Algorithm 1 (neighbor-constraint rejection) on hand-checked cases."""

import numpy as np

from sgloc.rejection import NeighborRejector, consistency_matrix, prune_by_support


def test_consistency_distance_form():
    src = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [50, 50, 0]])
    dst = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [-40, 0, 0]])
    M = consistency_matrix(src, dst, tau=1.0, form="distance")
    # Match 3: |D(q3, q0)| = 70.7 vs |D(t3, t0)| = 40 etc.: agrees with nobody.
    expected = np.array([[0, 1, 1, 0], [1, 0, 1, 0], [1, 1, 0, 0], [0, 0, 0, 0]], dtype=bool)
    np.testing.assert_array_equal(M, expected)


def test_consistency_neighbor_form():
    src = np.array([[0.0, 0, 0], [5, 0, 0], [30, 0, 0]])
    dst = np.array([[0.0, 0, 0], [25, 0, 0], [5, 0, 0]])
    M = consistency_matrix(src, dst, tau=10.0, form="neighbor")
    # Nei in query: (0,1) T, (0,2) F, (1,2) F. In target: (0,1) F, (0,2) T, (1,2) F.
    expected = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 0]], dtype=bool)
    np.testing.assert_array_equal(M, expected)


def test_prune_removes_weakly_supported_match():
    # 0-3 form a clique (support 3 each); 4 agrees only with 0.
    M = np.zeros((5, 5), dtype=bool)
    M[:4, :4] = True
    M[0, 4] = M[4, 0] = True
    np.fill_diagonal(M, False)
    # r=5: bound 0.5*4 = 2, V4 = 1 -> removed; then r=4: bound 1.5, all V = 3 -> stop.
    np.testing.assert_array_equal(prune_by_support(M, 0.5), [0, 1, 2, 3])


def test_bound_shrinks_with_remaining_matches():
    # A clique of 3 among 10 matches, the other 7 isolated. Against the ORIGINAL m the clique's
    # support 2 < 0.5 * 9 would remove it too; against the remaining count it survives.
    M = np.zeros((10, 10), dtype=bool)
    M[np.ix_([2, 5, 7], [2, 5, 7])] = True
    np.fill_diagonal(M, False)
    np.testing.assert_array_equal(prune_by_support(M, 0.5), [2, 5, 7])


def test_eta_controls_strictness():
    # Two cliques {0,1,2} and {3,4}, joined by one edge 2-3.
    M = np.zeros((5, 5), dtype=bool)
    M[np.ix_([0, 1, 2], [0, 1, 2])] = True
    M[np.ix_([3, 4], [3, 4])] = True
    M[2, 3] = M[3, 2] = True
    np.fill_diagonal(M, False)
    # eta = 0.5: V = [2,2,3,2,1]; r=5 bound 2: remove 4 -> V3 = 1; r=4 bound 1.5: remove 3;
    # r=3 bound 1: V = [2,2,2] -> stop.
    np.testing.assert_array_equal(prune_by_support(M, 0.5), [0, 1, 2])
    # eta = 0.2: bound 0.8 at r=5; every V >= 1 -> nothing removed.
    np.testing.assert_array_equal(prune_by_support(M, 0.2), [0, 1, 2, 3, 4])


def test_rejector_drops_outliers_keeps_inliers(rng):
    from sgloc.geometry import apply, random_rigid_transform

    T = random_rigid_transform(rng)
    src = rng.uniform(-100, 100, (60, 3))
    dst = apply(T, src) + rng.normal(0, 0.3, src.shape)
    outliers = rng.choice(60, 40, replace=False)
    dst[outliers] = rng.uniform(-300, 300, (40, 3))
    kept = NeighborRejector(tau=3.0)(src, dst)
    inliers = np.setdiff1d(np.arange(60), outliers)
    assert set(inliers) <= set(kept)
    assert len(np.intersect1d(kept, outliers)) <= 2


def test_empty_input():
    assert len(NeighborRejector()(np.zeros((0, 3)), np.zeros((0, 3)))) == 0
