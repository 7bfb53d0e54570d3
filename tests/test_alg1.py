"""The paper's Algorithm 1 (neighbor-constraint rejection) on hand-checked cases, and its
literal reading (`bound="literal"`, the `paper` preset) against a transcription of the
pseudo-code."""

import math

import numpy as np
import pytest

from sgloc.pipeline.presets import localizer_preset
from sgloc.rejection import NeighborRejector, consistency_matrix, make_rejector, prune_by_support


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


def alg1_transcribed(src: list, dst: list, tau: float) -> list[int]:
    """Alg. 1 line by line: M over every (i, j), the diagonal included; V = row sums;
    `while V_i < 0.5 * rows of M_0`: V -= M[i,:], V_i = m, delete match i from M_0."""
    m = len(src)
    M = [[0] * m for _ in range(m)]
    for i in range(m):
        for j in range(m):
            if abs(math.dist(src[i], src[j]) - math.dist(dst[i], dst[j])) < tau:
                M[i][j] = 1
    V = [sum(row) for row in M]
    M0 = list(range(m))
    i = V.index(min(V))
    while V[i] < 0.5 * len(M0):
        for j in range(m):
            V[j] -= M[i][j]
        V[i] = m
        M0.remove(i)
        i = V.index(min(V))
    return M0


def _random_matches(rng, m):
    src = rng.uniform(-60, 60, (m, 3))
    dst = src + rng.normal(0, 1.0, (m, 3))
    k = int(rng.integers(0, m + 1))
    dst[:k] = rng.uniform(-60, 60, (k, 3))  # outliers
    return src, dst


@pytest.mark.parametrize("seed", range(4))
def test_paper_preset_rejection_is_alg1_as_written(seed):
    rng = np.random.default_rng(seed)
    cfg = localizer_preset("paper")
    rejector = make_rejector(cfg.rejection, **cfg.rejection_params)
    differs = 0
    for _ in range(40):
        src, dst = _random_matches(rng, int(rng.integers(1, 120)))
        expected = alg1_transcribed(src.tolist(), dst.tolist(), 5.0)
        assert rejector(src, dst).tolist() == expected
        differs += NeighborRejector()(src, dst).tolist() != expected
    assert differs > 0  # the default bound is another rule, and these sets tell them apart


@pytest.fixture(params=["compiled", "reference"])
def kernel_path(request):
    """Each bound on both paths: the compiled kernel and the numpy reference
    (`references.paths.on_references`)."""
    if request.param == "compiled":
        yield request.param
        return
    from references.paths import on_references

    with on_references():
        yield request.param


def test_literal_and_remaining_bounds_differ_on_an_even_count(kernel_path):
    # A path 0-1-2 and an isolated 3 (supports without M_ii: 1, 2, 1, 0). Both rules remove
    # 3 at r = 4 ("remaining": 0 < 0.5 * 3; "literal": 1 + 0 < 0.5 * 4) and stop at r = 3.
    M = np.zeros((4, 4), dtype=bool)
    M[0, 1] = M[1, 0] = M[1, 2] = M[2, 1] = True
    assert prune_by_support(M, 0.5).tolist() == [0, 1, 2]
    assert prune_by_support(M, 0.5, bound="literal").tolist() == [0, 1, 2]
    # Four matches agreeing with nobody. "remaining": 0 < 1.5, 0 < 1, 0 < 0.5 remove 0, 1, 2.
    # "literal": 1 < 2 and 1 < 1.5 remove 0 and 1; at r = 2 (even), 1 < 1 is false: stop.
    E = np.zeros((4, 4), dtype=bool)
    assert prune_by_support(E, 0.5).tolist() == [3]
    assert prune_by_support(E, 0.5, bound="literal").tolist() == [2, 3]


def test_literal_bound_on_matrices_of_any_width(kernel_path):
    # Word boundaries of the packed rows: the literal rule appends one match.
    rng = np.random.default_rng(3)
    for m in (63, 64, 65, 127, 128):
        R = rng.random((m, m)) < 0.5
        R = R | R.T
        np.fill_diagonal(R, False)
        V = R.sum(axis=1).astype(float) + 1  # the diagonal counts
        alive = list(range(m))
        while True:
            i = int(np.argmin(V))
            if V[i] >= 0.5 * len(alive):
                break
            V -= R[i]
            V[i] = np.inf
            alive.remove(i)
        assert prune_by_support(R, 0.5, bound="literal").tolist() == alive
