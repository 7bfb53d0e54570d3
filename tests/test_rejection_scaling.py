"""The scaled neighbor rejection equals the paper's naive O(m^2)-memory reference exactly, and
runs at m = 10,000 in bounded memory; helpers of the clique and spectral rejectors."""

from __future__ import annotations

import numpy as np
import pytest
from references import consistency as consistency_reference
from references.consistency import consistency_bool
from references.rejection import core_numbers, leading_eigenvector
from scipy.spatial.distance import cdist

from sgloc.rejection import NeighborRejector, consistency_matrix, prune_by_support
from sgloc.rejection.clique import exact_clique
from sgloc.sim.correspondences import make_correspondences


def naive_consistency(src, dst, tau, form):
    dq, dt = cdist(src, src), cdist(dst, dst)
    M = np.abs(dq - dt) < tau if form == "distance" else (dq < tau) == (dt < tau)
    np.fill_diagonal(M, False)
    return M


def naive_prune(M, eta):
    """Alg. 1 step 2 with the default bound (V_i without M_ii, against eta * (r - 1); the
    literal reading is tested in test_alg1.py), in plain numpy: float supports, full argmin,
    removed ones at +inf."""
    m = M.shape[0]
    V = M.sum(axis=1).astype(np.float64)
    alive = np.ones(m, dtype=bool)
    r = m
    while r > 1:
        i = int(np.argmin(V))
        if V[i] >= eta * (r - 1):
            break
        V -= M[i]
        V[i] = np.inf
        alive[i] = False
        r -= 1
    return np.flatnonzero(alive)


@pytest.mark.parametrize("seed", range(6))
def test_scaled_neighbor_equals_naive_reference(seed):
    rng = np.random.default_rng(seed)
    m = int(rng.integers(400, 600))
    kind = ["random", "structured"][seed % 2]
    form = ["distance", "neighbor"][seed % 3 == 2]
    cs = make_correspondences(m, rng.uniform(0.5, 0.97), rng, kind, extent=rng.uniform(50, 800))
    tau, eta = rng.uniform(1.0, 8.0), rng.uniform(0.3, 0.7)
    M_ref = naive_consistency(cs.src, cs.dst, tau, form)
    M = consistency_matrix(cs.src, cs.dst, tau, form)
    assert M.dtype == bool and M.shape == (m, m)
    assert np.array_equal(M, M_ref)
    expected = naive_prune(M_ref, eta)
    assert np.array_equal(prune_by_support(M, eta), expected)
    assert np.array_equal(NeighborRejector(tau, eta, form)(cs.src, cs.dst), expected)


def test_many_small_tiles_equal_reference(monkeypatch):
    """Tile seams (diagonal and off-diagonal tiles, ragged last tile) change nothing."""
    monkeypatch.setattr(consistency_reference, "TILE", 37)
    cs = make_correspondences(250, 0.7, np.random.default_rng(5), "structured")
    for form in ("distance", "neighbor"):
        M_ref = naive_consistency(cs.src, cs.dst, 4.0, form)
        assert np.array_equal(consistency_bool(cs.src, cs.dst, 4.0, form), M_ref)


def test_exact_near_threshold_and_with_coincident_points():
    """Pairs at distance differences within float32 rounding of tau, and duplicate points
    (squared distances that round negative), are decided as float64 decides them."""
    rng = np.random.default_rng(9)
    src = rng.uniform(-2000, 2000, (300, 3))
    src[150:] = src[:150]  # duplicates
    dst = src + rng.normal(0, 1.0, src.shape)
    tau = 2.5
    M_ref = naive_consistency(src, dst, tau, "distance")
    assert np.array_equal(consistency_matrix(src, dst, tau), M_ref)


@pytest.mark.parametrize("density", [0.05, 0.5, 0.95])
def test_prune_equals_naive_on_random_matrices(density):
    rng = np.random.default_rng(int(density * 100))
    for m in (1, 2, 3, 70, 400):
        R = rng.random((m, m)) < density
        R = R | R.T
        np.fill_diagonal(R, False)
        for eta in (0.25, 0.5, 0.75):
            assert np.array_equal(prune_by_support(R, eta), naive_prune(R, eta))


_MEMORY_SCRIPT = """
import json, resource
import numpy as np
from sgloc.rejection import NeighborRejector
from sgloc.sim.correspondences import make_correspondences
cs = make_correspondences(10_000, 0.9, np.random.default_rng(0), "structured")
NeighborRejector()(cs.src[:100], cs.dst[:100])  # compile / load the kernels first
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
kept = NeighborRejector()(cs.src, cs.dst)
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"grown_mb": (after - before) / 1e3, "all_inliers": bool(cs.inlier[kept].all()),
                  "kept": len(kept), "inliers": int(cs.inlier.sum()),
                  "inliers_kept": int(cs.inlier[kept].sum())}))
"""


def test_ten_thousand_candidates_bounded_memory():
    """The compiled kernels allocate outside Python's tracing, so the peak is read as the
    growth of the process's resident set, in a fresh process."""
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _MEMORY_SCRIPT], capture_output=True, text=True,
                         check=True)  # fmt: skip
    res = json.loads(out.stdout)
    # Packed rows are m^2 / 8 = 12.5 MB; a bool (m,m) matrix would be 100 MB, a float one 800 MB.
    assert res["grown_mb"] < 60, res
    assert res["inliers_kept"] == res["inliers"]
    assert res["kept"] < 1.1 * res["inliers"]


def test_core_numbers_and_exact_clique_against_networkx():
    nx = pytest.importorskip("networkx")
    rng = np.random.default_rng(1)
    for n, p in [(30, 0.3), (60, 0.5), (40, 0.9)]:
        R = rng.random((n, n)) < p
        R = np.triu(R, 1)
        R = R | R.T
        G = nx.from_numpy_array(R.astype(int))
        core = core_numbers(R)
        assert np.array_equal(core, [nx.core_number(G)[i] for i in range(n)])
        clique, complete = exact_clique(R, 0, 10**6)
        assert complete
        assert all(R[a, b] for a in clique for b in clique if a != b)
        assert len(clique) == max(len(c) for c in nx.find_cliques(G))


def test_leading_eigenvector_matches_eigh():
    rng = np.random.default_rng(2)
    A = rng.random((50, 50)).astype(np.float32)
    A = A + A.T
    x = leading_eigenvector(A, iterations=2000, tol=1e-7)
    w, v = np.linalg.eigh(A.astype(np.float64))
    ref = np.abs(v[:, -1])
    assert np.allclose(x, ref, atol=1e-4)
