"""Compiled kernels equal their plain numpy references (tests/references) exactly."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest
from references import acceptance as acceptance_reference
from references import consistency as consistency_reference
from references import matching as matching_reference
from references.consistency import consistency_bool
from references.descriptors import random_walks
from references.rejection import prune_by_support as prune_by_support_reference
from scipy.spatial.distance import cdist

from sgloc.acceptance import ChanceModel
from sgloc.consistency.pairwise import (
    common_partner_count,
    consistency_bits,
    consistency_matrix,
    consistent_pairs,
    pack_rows,
    unpack_rows,
)
from sgloc.errors import UnknownNameError
from sgloc.maps.graph import SemanticGraph
from sgloc.matching.candidates import MatchingConfig, match_descriptors, match_flagged
from sgloc.rejection import NeighborRejector
from sgloc.rejection.neighbor import prune_bits, prune_by_support
from sgloc.sim.correspondences import make_correspondences


def dense_reference(src, dst, tau, form):
    dq, dt = cdist(src, src), cdist(dst, dst)
    M = np.abs(dq - dt) < tau if form == "distance" else (dq < tau) == (dt < tau)
    np.fill_diagonal(M, False)
    return M


@pytest.mark.parametrize("m", [0, 1, 2, 63, 64, 65, 129, 700])
@pytest.mark.parametrize("form", ["distance", "neighbor"])
def test_consistency_bits_equal_dense_float64(m, form):
    rng = np.random.default_rng(m)
    cs = make_correspondences(m, 0.8, rng, "structured" if m % 2 else "random")
    tau = 4.0
    bits, degree = consistency_bits(cs.src, cs.dst, tau, form)
    ref = dense_reference(cs.src, cs.dst, tau, form)
    assert bits.shape == (m, (m + 63) // 64) and bits.dtype == np.uint64
    assert np.array_equal(unpack_rows(bits, m), ref)
    assert np.array_equal(degree, ref.sum(axis=1))
    assert np.array_equal(consistency_matrix(cs.src, cs.dst, tau, form), ref)
    assert np.array_equal(consistency_bool(cs.src, cs.dst, tau, form), ref)


@pytest.mark.parametrize("form", ["distance", "neighbor"])
def test_consistency_at_tau_equal_to_actual_distances(form):
    """tau set to distances (or differences) that occur: the strict < decides as float64 does,
    also with duplicate points and a large offset (float32 rounding of the coordinates)."""
    rng = np.random.default_rng(3)
    src = rng.uniform(-500, 500, (300, 3)) + 1e4
    src[200:] = src[:100]
    dst = src + rng.normal(0, 1.0, src.shape)
    dq, dt = cdist(src, src), cdist(dst, dst)
    values = np.abs(dq - dt) if form == "distance" else dq
    for tau in values[np.triu_indices(300, 1)][::4001][:6]:
        ref = dense_reference(src, dst, tau, form)
        assert np.array_equal(consistency_matrix(src, dst, tau, form), ref)


def test_unknown_form():
    with pytest.raises(UnknownNameError, match="consistency form"):
        consistency_bits(np.zeros((3, 3)), np.zeros((3, 3)), 1.0, "angle")


def test_pack_unpack_round_trip():
    rng = np.random.default_rng(0)
    for shape in [(5, 1), (7, 64), (3, 65), (4, 200)]:
        M = rng.random(shape) < 0.3
        assert np.array_equal(unpack_rows(pack_rows(M), shape[1]), M)


@pytest.mark.parametrize("density", [0.02, 0.3, 0.9])
def test_prune_equals_reference_on_random_graphs(density):
    rng = np.random.default_rng(int(density * 100))
    for m in (1, 2, 3, 64, 65, 300):
        R = rng.random((m, m)) < density
        R = np.triu(R, 1)
        R = R | R.T
        for eta in (0.2, 0.5, 0.8):
            ref = prune_by_support_reference(R, eta)
            assert np.array_equal(prune_by_support(R, eta), ref)
            assert np.array_equal(prune_bits(pack_rows(R), R.sum(axis=1), eta), ref)


def test_prune_ties_go_to_the_lowest_index():
    # A 4-cycle plus an isolated vertex: after the isolated one, all supports tie at 2 -> then
    # at eta = 0.9 the lowest index goes first, each time.
    R = np.zeros((5, 5), dtype=bool)
    for a, b in [(0, 1), (1, 2), (2, 3), (3, 0)]:
        R[a, b] = R[b, a] = True
    assert np.array_equal(prune_by_support(R, 0.9), prune_by_support_reference(R, 0.9))
    assert np.array_equal(prune_by_support(R, 0.6), [0, 1, 2, 3])


@pytest.mark.parametrize("m", [300, 2000])
@pytest.mark.parametrize("ratio", [0.5, 0.8, 0.95])
@pytest.mark.parametrize("form", ["distance", "neighbor"])
def test_neighbor_rejector_same_survivors_as_numpy_pipeline(m, ratio, form):
    rng = np.random.default_rng([m, int(ratio * 100)])
    cs = make_correspondences(m, ratio, rng, "structured")
    tau, eta = 5.0, 0.5
    ref = prune_by_support_reference(consistency_bool(cs.src, cs.dst, tau, form), eta)
    assert np.array_equal(NeighborRejector(tau, eta, form)(cs.src, cs.dst), ref)


def test_edges_and_triangles_equal_numpy():
    from sgloc.consistency.triangle_kernels import common_counts, upper_edges

    rng = np.random.default_rng(4)
    for m, p in [(1, 0.5), (5, 0.5), (64, 0.3), (130, 0.1), (300, 0.6)]:
        R = np.triu(rng.random((m, m)) < p, 1)
        R = R | R.T
        bits = pack_rows(R)
        ii, jj = upper_edges(bits, R.sum(axis=1))
        ref_i, ref_j = np.nonzero(np.triu(R))
        assert np.array_equal(ii, ref_i) and np.array_equal(jj, ref_j)
        common = (R[ref_i] & R[ref_j]).sum()
        assert common_counts(bits, ii, jj) == common
        pi, pj = consistent_pairs(bits, R.sum(axis=1))
        assert np.array_equal(pi, ref_i) and np.array_equal(pj, ref_j)
        assert common_partner_count(bits, pi, pj) == common
        assert consistency_reference.common_partner_count(bits, pi, pj) == common
        ref_pairs = consistency_reference.upper_pairs(bits)
        assert np.array_equal(ref_pairs[0], ref_i) and np.array_equal(ref_pairs[1], ref_j)
        assert (
            common % 3 == 0
            and common // 3 == np.trace(np.linalg.matrix_power(R.astype(np.int64), 3)) // 6
        )


@pytest.mark.parametrize("m, ratio", [(1, 0.0), (3, 0.0), (300, 0.8), (1000, 0.5), (2000, 0.9)])
@pytest.mark.parametrize("kind", ["random", "structured"])
def test_spectral_kernels_same_survivors_as_numpy(m, ratio, kind):
    from references.rejection import affinity_and_consistency, spectral

    from sgloc.rejection import SpectralRejector
    from sgloc.rejection import spectral_kernels as kernels

    rej = SpectralRejector()
    for seed in range(2):
        cs = make_correspondences(m, ratio, np.random.default_rng([m, seed]), kind)
        assert np.array_equal(rej(cs.src, cs.dst), spectral(rej, cs.src, cs.dst))
    if m >= 300:  # affinities: float64 here, float32 tiles in the reference
        A_ref, _ = affinity_and_consistency(cs.src, cs.dst, rej.tau, rej.sigma)
        bits, degree = consistency_bits(cs.src, cs.dst, rej.tau, "distance")
        indptr, indices, data = kernels.affinity_csr(cs.src, cs.dst, bits, degree, rej.sigma)
        A = np.zeros((m, m), dtype=np.float32)
        A[np.repeat(np.arange(m), np.diff(indptr)), indices] = data
        assert np.abs(A - A_ref).max() < 1e-3
        assert np.array_equal(A > 0, A_ref > 0)


def test_clique_kernels_equal_numpy():
    from references.rejection import core_numbers, greedy_clique, max_clique

    from sgloc.rejection import CliqueRejector
    from sgloc.rejection import clique_kernels as kernels

    rng = np.random.default_rng(6)
    for m, p in [(1, 0.5), (5, 0.5), (70, 0.3), (300, 0.05), (300, 0.9)]:
        R = np.triu(rng.random((m, m)) < p, 1)
        R = R | R.T
        bits, degree = pack_rows(R), R.sum(axis=1)
        core = kernels.core_numbers(bits, degree)
        assert np.array_equal(core, core_numbers(R))
        rank = core * (m + 1) + degree
        seeds = np.argsort(-rank, kind="stable")[:16]
        assert np.array_equal(kernels.greedy_clique(bits, rank, seeds),
                              greedy_clique(R, rank, seeds))  # fmt: skip
    rej = CliqueRejector()
    for m, ratio, kind in [(300, 0.8, "random"), (1000, 0.5, "structured"), (2000, 0.9, "random")]:
        cs = make_correspondences(m, ratio, np.random.default_rng(m), kind)
        ref = max_clique(rej, consistency_bool(cs.src, cs.dst, rej.tau, "distance"))
        assert np.array_equal(rej(cs.src, cs.dst), ref)


def _descriptor_pair(seed: int, n_q: int, n_t: int, d: int = 24):
    """Sparse-ish non-negative descriptors with exact ties (duplicated rows), zero rows, and
    class ids that are large, unsorted and partly present on one side only."""
    rng = np.random.default_rng(seed)
    dq = rng.random((n_q, d)) * (rng.random((n_q, d)) < 0.4)
    dt = rng.random((n_t, d)) * (rng.random((n_t, d)) < 0.4)
    dt[1::7] = dt[::7][: len(dt[1::7])]  # duplicated targets: tied similarities
    dq[3::11] = dt[5::11][: len(dq[3::11])]  # exact copies: similarity 1
    dq[::13] = 0.0
    ids = np.array([7, 1_000_003, 2, 40])
    lq = ids[rng.integers(0, 3, n_q)]
    lt = ids[rng.integers(1, 4, n_t)]
    return dq, dt, lq, lt


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize(
    "cfg, flag_ratio",
    [
        (MatchingConfig(), None),
        (MatchingConfig(), 0.8),
        (MatchingConfig(min_similarity=0.2, top_k=3), 0.9),
        (MatchingConfig(min_similarity=0.3, top_k=2, mutual=True), None),
        (MatchingConfig(min_similarity=0.1, top_k=4, max_ratio=0.9), 0.7),
        (MatchingConfig(min_similarity=0.0, max_ratio=0.95), None),
    ],
)
def test_compiled_top_k_equals_reference(seed, cfg, flag_ratio):
    """The kernel (`sgloc.matching.similarity_kernels`) keeps the same candidates, in the same
    order, with the same flags and similarities to rounding, as the numpy blocks (ties included)."""
    dq, dt, lq, lt = _descriptor_pair(seed, 90 + 17 * seed, 120)
    ma, sa, fa = matching_reference.match_flagged(dq, dt, lq, lt, cfg, flag_ratio)
    mb, sb, fb = match_flagged(dq, dt, lq, lt, cfg, flag_ratio)
    assert len(ma) > 20
    np.testing.assert_array_equal(ma, mb)
    np.testing.assert_allclose(sa, sb, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(fa, fb)


def test_compiled_top_k_handles_empty_and_disjoint_classes():
    d = np.ones((3, 4))
    m, s = match_descriptors(d, d, np.array([0, 0, 0]), np.array([1, 1, 1]))
    assert m.shape == (0, 2) and s.shape == (0,)
    m, s = match_descriptors(d[:0], d, np.zeros(0, int), np.array([1, 1, 1]))
    assert m.shape == (0, 2)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("radius", [0.7, 5.0, 40.0])
def test_near_counts_equal_kd_tree_reference(seed, radius):
    """The compiled per-class neighbour counts (`sgloc.maps.neighbor_kernels`) equal scipy's
    cKDTree ones, also for pairs exactly `radius` apart (counted: distance <= radius), far
    away and coincident points, and a large coordinate offset."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-60, 60, (400, 3)) * [1, 1, 0.1] + [3e5, -2e5, 10]
    pts[:40, :2] = np.round(pts[:40, :2])  # an integer lattice: exact distances occur
    labels = rng.integers(0, 5, len(pts))
    moved = np.concatenate([pts[:40] + [3.0, 4.0, 0.0], pts[40:60],  # 5 m apart, coincident
                            rng.uniform(-90, 90, (300, 3)) + [3e5, -2e5, 10],
                            [[1e6, 1e6, 0.0], [-1e6, 3e5, 5.0]]])  # fmt: skip
    usage = rng.integers(0, 4, len(pts)).astype(np.float64)
    model = ChanceModel(SemanticGraph(pts, labels), radius, 6)
    got = model.near_counts(moved, (None, usage))
    ref = acceptance_reference.near_counts(model, moved, (None, usage))
    assert got[0][40:60].sum() >= 20  # coincident points
    if radius == 5.0:
        assert got[0][:40].sum() >= 40  # exactly the radius apart: counted
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_array_equal(a, b)
    (alone,) = model.near_counts(moved)
    np.testing.assert_array_equal(alone, ref[0])
    empty = model.near_counts(np.zeros((0, 3)), (None, usage))
    assert [x.shape for x in empty] == [(0, 6), (0, 6)]


@pytest.mark.parametrize("path", ["compiled", "reference"])
def test_near_targets_equal_usage_weighted_counts(path):
    """`ChanceModel.near_targets` (a search among the candidates' targets only) gives the
    usage-weighted counts of the whole map's search, for repeated targets too; the class
    counts are the map's."""
    rng = np.random.default_rng(7)
    pts = rng.uniform(-100, 100, (3000, 3)) * [1, 1, 0.05]
    labels = rng.integers(0, 6, len(pts))
    targets = rng.integers(0, len(pts), 400)  # repeats included
    moved = pts[rng.integers(0, len(pts), 200)] + rng.normal(0, 2.0, (200, 3))
    model = ChanceModel(SemanticGraph(pts, labels), 4.0, 7)
    usage = np.bincount(targets, minlength=len(pts)).astype(np.float64)
    near_targets = model.near_targets if path == "compiled" else (
        lambda moved, targets: acceptance_reference.near_targets(model, moved, targets))
    got = near_targets(moved, targets)
    want = acceptance_reference.near_counts(model, moved, (usage,))[0]
    assert got.shape == (200, 7) and got.sum() > 50
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(model.class_count, np.bincount(labels, minlength=7))


@pytest.mark.parametrize("radius", [0.5, 3.0, 40.0, 1e-4])
def test_grid_order_is_the_stable_sort_of_its_cells(radius):
    """A grid's points are in np.argsort(kind="stable")'s order of their cells (a counting
    sort on a small grid, numpy's sort on a sparse one), with their coordinates and labels;
    the runs of `start` (when kept) bound each cell's points."""
    from sgloc.maps.neighbor_kernels import cell_grid

    rng = np.random.default_rng(5)
    pos = np.round(rng.uniform(-50, 50, (500, 3)), 0)  # repeated cells and coordinates
    lab = rng.integers(0, 4, 500)
    g = cell_grid(pos, lab, radius)
    assert np.all(np.diff(g.sorted_keys) >= 0)
    same = g.sorted_keys[1:] == g.sorted_keys[:-1]
    assert np.all(g.order[1:][same] > g.order[:-1][same])  # stable: ties in index order
    np.testing.assert_array_equal(np.sort(g.order), np.arange(500))
    np.testing.assert_array_equal(g.xyz, pos[g.order].T)
    np.testing.assert_array_equal(g.labels, lab[g.order])
    if len(g.start) > 1:
        np.testing.assert_array_equal(g.sorted_keys, np.repeat(np.arange(len(g.start) - 1),
                                                               np.diff(g.start)))  # fmt: skip


def test_grid_kept_by_a_prepared_graph():
    """A prepared graph builds its neighbour grid once per radius and keeps it (a query then
    costs its neighbourhood, not the map); `cell_grid` itself keeps nothing; the counts are
    the same with the kept grid or without one."""
    from sgloc.maps.neighbor_kernels import cell_grid, near_class_counts
    from sgloc.maps.prepared_graph import PreparedGraph

    rng = np.random.default_rng(3)
    g = SemanticGraph(rng.uniform(-50, 50, (2000, 3)), rng.integers(0, 4, 2000))
    prepared = PreparedGraph(g)
    assert prepared.grid(3.0) is prepared.grid(3.0)
    assert prepared.grid(3.0) is not prepared.grid(5.0)
    assert PreparedGraph(g).grid(3.0) is not prepared.grid(3.0)
    assert cell_grid(g.positions, g.labels, 3.0) is not cell_grid(g.positions, g.labels, 3.0)
    moved = rng.uniform(-60, 60, (300, 3))
    w = rng.uniform(0, 1, 2000)
    pos, lab = g.positions.copy(), g.labels.copy()
    for a, b in zip(near_class_counts(moved, g.positions, g.labels, 4, 3.0, w,
                                      prepared.grid(3.0)),
                    near_class_counts(moved, pos, lab, 4, 3.0, w), strict=True):  # fmt: skip
        np.testing.assert_array_equal(a, b)
    gone = weakref.ref(prepared.grid(3.0))
    del prepared
    gc.collect()
    assert gone() is None  # the grid goes with the object that holds it


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_yaw_runner_up_equals_reference(monkeypatch, seed):
    """The compiled 4-dof runner-up search (`sgloc.acceptance.runner_up_kernels`) finds the
    alternative the numpy reference finds: the same inlier count and transform (to rounding)."""
    import sgloc.acceptance.rivals as rivals
    from sgloc.acceptance import AcceptanceConfig, pair_consistency, runner_up
    from sgloc.consistency.pairwise import ConsistentPairs
    from sgloc.estimation import rot_z
    from sgloc.geometry import apply, make_transform

    rng = np.random.default_rng(seed)
    src = rng.uniform(-80, 80, (150, 3)) * [1, 1, 0.05]
    T = make_transform(rot_z(np.array([0.3]))[0], np.array([5.0, -2.0, 0.5]))
    T_alt = make_transform(rot_z(np.array([1.9]))[0], np.array([-30.0, 12.0, 0.0]))
    outliers = rng.uniform(-80, 80, (40, 3))
    dst = np.concatenate([apply(T, src[:60]), apply(T_alt, src[60:110]), outliers])
    dst += rng.normal(0, 0.5, dst.shape)
    radius = 5.0 if seed < 3 else 0.01  # (a radius that leaves no inliers at all)
    res2 = np.sum((apply(T, src) - dst) ** 2, axis=1)
    exclude = res2 < (2 * radius) ** 2
    bits, _ = pair_consistency(src, dst, radius)
    cfg = AcceptanceConfig(distinct_rotation=5.0 + 10 * seed)
    out = {}
    for path in ("reference", "compiled"):
        if path == "reference":  # the same pairs drawn, then the numpy search
            monkeypatch.setattr(rivals, "_compiled_yaw_runner_up",
                                acceptance_reference.yaw_runner_up)  # fmt: skip
        edges = ConsistentPairs(bits)
        out[path] = runner_up(src, dst, T, exclude, bits, edges, radius, cfg,
                               np.random.default_rng(seed), dof=4)  # fmt: skip
        monkeypatch.undo()
    (ka, Ta), (kb, Tb) = out["reference"], out["compiled"]
    assert ka == kb
    assert (Ta is None) == (Tb is None)
    if Ta is not None:
        np.testing.assert_allclose(Ta, Tb, rtol=0, atol=1e-9)
    if seed < 3:
        assert ka >= 40  # the second alignment is found


@pytest.mark.parametrize("n_q, n_t", [(90, 120), (150, 900)])
def test_compiled_top_k_one_tile_and_tiled_classes_equal_reference(n_q, n_t):
    """Classes of at most one tile of targets (scored row by row) and of several tiles (scored
    tile by tile) keep the reference's candidates, flags and similarities."""
    dq, dt, lq, lt = _descriptor_pair(5, n_q, n_t)
    sizes = np.unique(lt, return_counts=True)[1]
    # a tile: 256 targets (sgloc.matching.similarity_kernels)
    assert (sizes.min() > 256) == (n_t == 900)
    cfg = MatchingConfig(min_similarity=0.1, top_k=2)
    ma, sa, fa = matching_reference.match_flagged(dq, dt, lq, lt, cfg, 0.8)
    mb, sb, fb = match_flagged(dq, dt, lq, lt, cfg, 0.8)
    assert len(ma) > 20
    np.testing.assert_array_equal(ma, mb)
    np.testing.assert_allclose(sa, sb, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(fa, fb)


def _walk_graph(kind: str) -> tuple[SemanticGraph, int]:
    """(graph, n_classes) for the random-walk kernel tests."""
    rng = np.random.default_rng(len(kind))
    if kind == "airsim":
        from sgloc.datasets.downloads import airsim_guo

        return airsim_guo()[0], 11
    if kind == "isolated":  # a cluster plus far-apart vertices without neighbours
        pos = np.concatenate([rng.uniform(0, 50, (30, 3)), 1000.0 * np.arange(1, 6)[:, None]
                              * np.ones(3)])  # fmt: skip
        return SemanticGraph(pos, rng.integers(0, 4, 35)), 4
    if kind == "one_class":
        return SemanticGraph(rng.uniform(0, 60, (25, 3)), np.zeros(25, dtype=int)), 1
    if kind == "many_classes":  # 50**4 sequences: the kernel's sorted (not dense) counting
        return SemanticGraph(rng.uniform(0, 80, (40, 3)), rng.integers(0, 50, 40)), 50
    if kind == "all_isolated":
        return SemanticGraph(1000.0 * np.arange(4)[:, None] * np.ones(3), [0, 1, 0, 1]), 2
    raise ValueError(kind)


@pytest.mark.parametrize("kind", ["airsim", "isolated", "one_class", "many_classes",
                                  "all_isolated"])  # fmt: skip
@pytest.mark.parametrize("walk_length", [1, 3, 4])
@pytest.mark.parametrize("bit_generator", [np.random.PCG64, np.random.MT19937])
def test_random_walk_kernel_equals_reference_bit_for_bit(kind, walk_length, bit_generator):
    from sgloc.descriptors import RandomWalkDescriptor

    g, n_classes = _walk_graph(kind)
    rw = RandomWalkDescriptor(n_walks=300 if kind != "airsim" else 1000, walk_length=walk_length)
    rng_a, rng_b = np.random.Generator(bit_generator(5)), np.random.Generator(bit_generator(5))
    got, ref = rw(g, n_classes, rng_a), random_walks(rw, g, n_classes, rng_b)
    assert got.shape == ref.shape == (len(g), n_classes**walk_length)
    for field in ("indptr", "indices", "data"):
        a, b = getattr(got, field), getattr(ref, field)
        assert a.dtype == b.dtype and np.array_equal(a, b), field
    # The same draws consumed: the generators go on alike.
    assert np.array_equal(rng_a.integers(0, 2**62, 16), rng_b.integers(0, 2**62, 16))
    empty = np.diff(got.indptr) == 0
    assert np.array_equal(empty, g.degrees == 0)  # rows of vertices without neighbours only
    assert np.all(got.sum(axis=1)[~empty] == rw.n_walks)
