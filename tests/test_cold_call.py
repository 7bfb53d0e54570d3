"""A call on new graph objects: the same bits as on kept ones (and a prepared target), the
covariance and the settings dict computed only when read, and the shortcuts of the per-call
set-up (graph checks, duplicate search, mirror check) equal to their plain forms."""

from __future__ import annotations

import numpy as np
import pytest
from references import acceptance as acceptance_reference
from references import maps as maps_reference

from sgloc import SemanticGraph, localize, prepare
from sgloc.acceptance.mirror import looks_mirrored
from sgloc.errors import InvalidGraphError
from sgloc.estimation.covariance import transform_covariance
from sgloc.geometry import apply, random_rigid_transform
from sgloc.maps.canonical import DUPLICATE_RADIUS, canonical_order, without_duplicates
from sgloc.pipeline.config import LocalizerConfig


def _new(g: SemanticGraph) -> SemanticGraph:
    return SemanticGraph(g.positions.copy(), g.labels.copy(), g.edge_radius, g.name)


def _same_bits(a, b) -> None:
    assert a.accepted == b.accepted and a.reason == b.reason
    assert a.confidence == b.confidence
    for name in ("matches", "candidates", "survivors", "scores"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    if a.accepted:
        assert a.transform.tobytes() == b.transform.tobytes()
        assert a.covariance.tobytes() == b.covariance.tobytes()
    else:
        assert a.transform is None and b.transform is None and b.covariance is None


def _synthetic(seed: int, n: int) -> tuple[SemanticGraph, SemanticGraph]:
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0, 150, (n, 3)) * [1.0, 1.0, 0.05]
    lab = rng.integers(0, 6, n)
    keep = rng.random(n) < 0.7
    T = random_rigid_transform(rng, 50.0, 2.0)
    noisy = apply(T, pos[keep]) + rng.normal(0, 0.2, (int(keep.sum()), 3))
    return SemanticGraph(noisy, lab[keep]), SemanticGraph(pos, lab)


@pytest.mark.parametrize("seed", [0, 3])
def test_new_graph_objects_give_the_bits_of_kept_ones(airsim_graphs, seed):
    q, t = airsim_graphs
    kept = localize(q, t, seed=seed)
    assert kept.accepted
    _same_bits(kept, localize(_new(q), _new(t), seed=seed))
    _same_bits(kept, localize(_new(q), prepare(_new(t)), seed=seed))
    _same_bits(kept, localize(_new(q), _new(t), seed=seed))  # again: nothing carried over


@pytest.mark.parametrize("seed, n", [(0, 40), (1, 150), (2, 300), (4, 12)])
def test_new_graph_objects_give_the_bits_of_kept_ones_synthetic(seed, n):
    q, t = _synthetic(seed, n)
    kept = localize(q, t, seed=seed)
    _same_bits(kept, localize(_new(q), _new(t), seed=seed))
    plain = localize(q, t, seed=seed, acceptance=False)
    _same_bits(plain, localize(_new(q), _new(t), seed=seed, acceptance=False))


def test_covariance_and_settings_are_computed_when_first_read(airsim_graphs):
    q, t = airsim_graphs
    r = localize(_new(q), _new(t), seed=0, class_weights={3: 5.0})
    assert r.accepted
    assert "covariance" not in r.__dict__ and "config" not in r.__dict__
    f = r.fitted
    expected = transform_covariance(f.src, f.dst, r.transform, f.weights, f.dof, f.max_tilt)
    assert f.weights is not None and len(f.src) == len(r.matches)
    assert r.covariance.tobytes() == expected.tobytes()
    assert r.covariance is r.covariance  # computed once
    config = LocalizerConfig().with_overrides(class_weights={3: 5.0})
    assert r.config == config.to_dict() and r.config["class_weights"] == {3: 5.0}
    assert r.to_dict()["config"] == r.config
    refused = localize(_new(q), SemanticGraph(t.positions[:40], t.labels[:40]), seed=0)
    assert not refused.accepted and refused.covariance is None and refused.fitted is None
    assert refused.config == LocalizerConfig().to_dict()


def _strip_pair(seed: int):
    """(target, query, query's target indices, T_query_target): 60 of 120 objects moved, 1 m
    noise."""
    rng = np.random.default_rng(seed)
    target = SemanticGraph(rng.uniform(0, 80, (120, 3)) * [1, 1, 0.1], rng.integers(0, 4, 120))
    idx = rng.choice(120, 60, replace=False)
    T = random_rigid_transform(rng, 20.0, 2.0)
    query = SemanticGraph(apply(T, target.positions[idx]) + rng.normal(0, 1.0, (60, 3)),
                          target.labels[idx])  # fmt: skip
    return target, query, idx, T


def _landed_brute_force(moved, labels, target, radius) -> int:
    d2 = ((moved[:, None, :] - target.positions[None, :, :]) ** 2).sum(axis=2)
    same = labels[:, None] == target.labels[None, :]
    return int(np.count_nonzero(((d2 <= radius**2) & same).any(axis=1)))


@pytest.mark.parametrize("seed", range(6))
def test_mirror_counts_equal_a_brute_force_count(seed):
    target, query, idx, T = _strip_pair(seed)
    if seed % 2:
        query = SemanticGraph(query.positions * [-1, 1, 1], query.labels)
    T_tq = np.linalg.inv(T)
    inliers = np.arange(0, 60, 3)
    _, plain, mirror = looks_mirrored(query, target, T_tq, inliers, 5.0)
    from sgloc.acceptance.mirror import reflect_across_line

    moved = apply(T_tq, query.positions)
    flipped = apply(T_tq, reflect_across_line(query.positions, query.positions[inliers]))
    assert plain == _landed_brute_force(moved, query.labels, target, 5.0)
    assert mirror == _landed_brute_force(flipped, query.labels, target, 5.0)


def _first_of_each_duplicate_group(g: SemanticGraph) -> np.ndarray:
    """The plain form: every pair compared, groups joined, the first of each in canonical order."""
    order = canonical_order(g)
    p, lab = g.positions[order], g.labels[order]
    d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(axis=2)
    linked = (d2 <= DUPLICATE_RADIUS**2) & (lab[:, None] == lab[None, :])
    group = np.arange(len(p))
    for _ in range(len(p)):  # propagate the smallest member (test reference, small n)
        group = np.where(linked, group[None, :], len(p)).min(axis=1)
    return order[np.unique(group)]


@pytest.mark.parametrize("seed", range(40))
def test_duplicate_search_equals_every_pair_compared(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 50))
    pos = rng.uniform(0, 3, (n, 3)).round(int(rng.integers(0, 3)))  # shared coordinates
    if seed % 3 == 0:
        pos[:, 0] = rng.integers(0, 2, n)  # long runs of one x
    pos += rng.normal(0, 4e-4, pos.shape) * (rng.random((n, 1)) < 0.5)
    g = SemanticGraph(pos, rng.integers(0, 3, n))
    got = without_duplicates(g, canonical_order(g))
    assert np.array_equal(got, _first_of_each_duplicate_group(g))


@pytest.mark.parametrize(
    "value, message",
    [(np.nan, "NaN or infinite"), (np.inf, "NaN or infinite"), (-np.inf, "NaN or infinite"),
     (2e7, "beyond"), (-2e7, "beyond")],
)  # fmt: skip
def test_graph_checks_still_refuse_bad_positions(value, message):
    pos = np.zeros((4, 3))
    pos[2, 1] = value
    with pytest.raises(InvalidGraphError, match=message):
        SemanticGraph(pos, [0, 1, 2, 3])
    too_many = np.arange(70) * 1000  # ids past MAX_CLASSES: the classes are counted
    with pytest.raises(InvalidGraphError, match="distinct classes"):
        SemanticGraph(np.random.default_rng(0).uniform(0, 9, (70, 3)), too_many)


@pytest.mark.parametrize("seed", range(4))
def test_mirror_check_on_the_tests_landed_objects_equals_its_own_search(seed):
    """The acceptance test's aligned query objects on the target (`Assessment.landed`) are the
    mirror check's own count, and handing them over changes nothing."""
    from sgloc.acceptance.assessment import assess
    from sgloc.acceptance.chance import ChanceModel
    from sgloc.acceptance.mirror import landed

    target, query, idx, T = _strip_pair(seed)
    T_tq = np.linalg.inv(T)
    candidates = np.stack([np.arange(60), idx], axis=1)
    a = assess(query, target, candidates, T_tq, 5.0)
    chance = ChanceModel(target, 5.0, max(query.n_classes, target.n_classes))
    own = landed(apply(T_tq, query.positions), query.labels, chance)
    assert a.radius_m == 5.0 and np.array_equal(a.landed, own) and own.any()
    inliers = np.arange(0, 60, 3)
    assert looks_mirrored(query, target, T_tq, inliers, 5.0, a.landed) == looks_mirrored(
        query, target, T_tq, inliers, 5.0
    )


@pytest.mark.parametrize("seed", range(12))
def test_compiled_canonical_order_equals_lexsort(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 300))
    pos = rng.uniform(-3, 3, (n, 3)).round(int(rng.integers(0, 2)))  # many ties
    pos[rng.random(n) < 0.2, 0] = -0.0  # -0.0 ties with 0.0, as in lexsort
    g = SemanticGraph(pos, rng.integers(0, 4, n))
    p = g.positions
    assert np.array_equal(canonical_order(g), np.lexsort((p[:, 2], p[:, 1], p[:, 0], g.labels)))


@pytest.mark.parametrize("seed", range(6))
def test_compiled_restore_equals_its_numpy_form(seed):
    import types

    from sgloc.maps.canonical import CanonicalPair

    q, t = _synthetic(seed, 60)
    pair = CanonicalPair(q, t, LocalizerConfig())
    rng = np.random.default_rng(seed)

    def result():
        k = int(rng.integers(0, 80))
        cand = np.stack([rng.integers(0, len(pair.query), k),
                         rng.integers(0, len(pair.target), k)], axis=1)  # fmt: skip
        return types.SimpleNamespace(
            candidates=cand,
            scores=rng.integers(0, 4, k) / 4.0,  # tied scores
            survivors=cand[: k // 2],
            matches=cand[: k // 3],
        )

    for _ in range(5):
        r = result()
        plain = types.SimpleNamespace(**{k: np.copy(v) for k, v in vars(r).items()})
        pair.restore(r)
        maps_reference.restore(pair, plain)
        for name in ("candidates", "scores", "survivors", "matches"):
            assert np.array_equal(getattr(r, name), getattr(plain, name)), name


def test_reordered_graph_owns_its_arrays():
    g = SemanticGraph(np.arange(12.0).reshape(4, 3), [3, 1, 2, 1])
    labels = np.array([2, 0, 1], dtype=np.int64)
    r = g.reordered(np.array([2, 1, 3]), labels)
    assert np.array_equal(r.positions, g.positions[[2, 1, 3]])
    assert np.array_equal(r.labels, labels) and r.edge_radius == g.edge_radius
    assert labels.flags.writeable and not r.labels.flags.writeable  # the caller's stays theirs
    labels[0] = 9
    assert r.labels[0] == 2
    with pytest.raises(InvalidGraphError):
        g.reordered(np.array([0, 1]), labels)


def _nfa_over_radii_plain(res2, radius, lam, m, n_tests, sample):
    """The NFA over the radii as first written: a mask, a max and log10_nfa per radius."""
    from sgloc.acceptance.chance import MIN_RADIUS_FRACTION, RADIUS_FRACTIONS, log10_nfa

    best = (np.inf, 0, radius)
    for f in RADIUS_FRACTIONS:
        within = res2[res2 < (f * radius) ** 2]
        k = int(within.size)
        r_fit = float(np.sqrt(within.max())) if k else f * radius
        r_fit = max(r_fit, MIN_RADIUS_FRACTION * radius)
        shrink = min(r_fit / radius, 1.0) ** 2
        lg = log10_nfa(k, m, lam * shrink, n_tests, sample) + np.log10(len(RADIUS_FRACTIONS))
        if lg < best[0]:
            best = (lg, k, r_fit)
    return best


@pytest.mark.parametrize("seed", range(30))
def test_nfa_over_radii_of_several_chance_levels_equals_the_plain_form(seed):
    from sgloc.acceptance.chance import nfa_over_radii_each

    rng = np.random.default_rng(seed)
    radius = float(rng.choice([1.0, 5.0, 7.5]))
    res2 = (rng.random(int(rng.integers(0, 60))) * 1.3 * radius) ** 2
    if res2.size and seed % 3 == 0:  # residuals exactly at the radii
        res2[: min(3, res2.size)] = [(f * radius) ** 2 for f in (0.25, 0.5, 1.0)][: res2.size]
    lams = tuple(rng.random(3) * 5)
    m, n_tests, sample = res2.size + 5, float(rng.integers(1, 10**6)), int(rng.choice([2, 3]))
    got = nfa_over_radii_each(res2, radius, lams, m, n_tests, sample)
    for lam, g in zip(lams, got, strict=True):
        assert g == _nfa_over_radii_plain(res2, radius, lam, m, n_tests, sample)


@pytest.mark.parametrize("seed", range(20))
def test_compiled_per_object_fits_equal_the_sorted_form(seed):
    """The compiled per-object fits (one pass, no sort) give the sorted numpy form's bits:
    repeated query objects, a subset of rows, residuals exactly at the radii."""
    from sgloc.acceptance.chance import object_nfa_over_radii

    rng = np.random.default_rng(seed)
    radius, m = float(rng.choice([1.0, 5.0])), int(rng.integers(1, 80))
    res2 = (rng.random(m) * 1.3 * radius) ** 2
    if seed % 3 == 0:
        res2[: min(3, m)] = [(f * radius) ** 2 for f in (0.25, 0.5, 1.0)][:m]
    qi = np.sort(rng.integers(0, max(m // (1 + seed % 2), 1), m))  # odd seeds: repeats
    rows = rng.random(m) < (0.6 if seed % 4 else 1.0)
    args = (res2, qi, rows, int(qi.max()) + 1, radius, (0.7, 3.0), m + 5, 1e5, 2)
    got = object_nfa_over_radii(*args)
    assert got == acceptance_reference.object_nfa_over_radii(*args)


@pytest.mark.parametrize("seed", range(10))
def test_compiled_chance_terms_and_axis_equal_numpy(seed):
    """The compiled chance sums (counts equal, sums to rounding), inlier spread along the xy
    axis and the reflection across it (closed form), residuals under a transform equal the
    numpy forms (SVDs)."""
    from sgloc.acceptance import ChanceModel, inlier_spread
    from sgloc.acceptance.assessment import squared_residuals_of
    from sgloc.acceptance.chance import chance_terms
    from sgloc.acceptance.mirror import reflect_across_line
    from sgloc.geometry import random_rigid_transform

    rng = np.random.default_rng(seed)
    tpos = rng.uniform(-50, 50, (150, 3)) * [1, 1, 0.1]
    qpos = tpos[:90] + rng.normal(0, 1.5, (90, 3))
    qlab = rng.integers(0, 4, 90)
    qi = np.sort(rng.integers(0, 90, 120))
    cand = np.stack([qi, np.where(rng.random(120) < 0.5, qi, rng.integers(0, 150, 120))], 1)
    model = ChanceModel(SemanticGraph(tpos, rng.integers(0, 4, 150)), 5.0, 4)
    counts, used = model.near_counts_and_targets(qpos, cand[:, 1])
    inlier = np.sum((qpos[qi] - tpos[cand[:, 1]]) ** 2, axis=1) < 25.0
    tlab = model.labels[cand[:, 1]].astype(np.int64)
    line = tpos[:30] * [1.0, 0.05 * seed, 1.0]  # from a nearly straight line to a blob
    T = random_rigid_transform(rng)
    ref = acceptance_reference
    out = [(chance_terms(qlab, counts, used, qi, tlab, inlier, model),
            inlier_spread(line, 4), reflect_across_line(qpos, line),
            squared_residuals_of(T, qpos, tpos[:90])),
           (ref.chance_terms(qlab, counts, used, qi, tlab, inlier, model),
            ref.inlier_spread(line, 4), ref.reflect_across_line(qpos, line),
            ref.squared_residuals_of(T, qpos, tpos[:90]))]  # fmt: skip
    (got, spread, flipped, res2), (ref, ref_spread, ref_flipped, ref_res2) = out
    np.testing.assert_allclose(res2, ref_res2, rtol=1e-12)
    assert got[0] == ref[0] > 0 and got[3] == ref[3]  # inlier objects, co-located count
    np.testing.assert_allclose(got, ref, rtol=1e-12)
    assert spread == pytest.approx(ref_spread, rel=1e-9)
    np.testing.assert_allclose(flipped, ref_flipped, atol=1e-9)


@pytest.mark.parametrize("n_target", [30, 3000])
def test_one_search_chance_counts_equal_two_searches(n_target):
    from sgloc.acceptance import ChanceModel

    rng = np.random.default_rng(n_target)
    pos = rng.uniform(0, 100, (n_target, 3)) * [1, 1, 0.05]
    target = SemanticGraph(pos, rng.integers(0, 4, n_target))
    moved = pos[rng.integers(0, n_target, 40)] + rng.normal(0, 3, (40, 3))
    targets = rng.integers(0, n_target, 25)
    chance = ChanceModel(target, 6.0, 4)
    counts, used = chance.near_counts_and_targets(moved, targets)
    assert np.array_equal(counts, chance.near_counts(moved)[0])
    assert np.array_equal(used, chance.near_targets(moved, targets)) and used.sum() > 0
