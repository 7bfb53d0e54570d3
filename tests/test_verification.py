"""Verification of a small query against the whole map (sgloc.acceptance.verification)."""

from __future__ import annotations

import numpy as np

import sgloc.acceptance.stage as stage_module
from sgloc import SemanticGraph, localize
from sgloc.acceptance import (
    AcceptanceConfig,
    ChanceModel,
    ClassTree,
    SearchContext,
    Verification,
    self_rival,
    verify_small_query,
)
from sgloc.estimation import ANY_RIGID, GROUND_VEHICLE
from sgloc.geometry import make_transform, transform_error


def _yaw(deg: float, t) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return make_transform(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), np.asarray(t, float))


def _scattered_map(rng, n=400, size=300.0) -> SemanticGraph:
    xy = rng.uniform(0, size, (n, 2))
    pos = np.column_stack([xy, rng.uniform(0, 3, n)])
    return SemanticGraph(pos, rng.integers(0, 3, n))


def _query_of(target: SemanticGraph, centre, radius, T_target_query, rng, noise=0.15):
    """The target objects within `radius` of `centre`, seen in a query frame (positions
    T^-1 p + noise); returns (query graph, their target indices)."""
    keep = np.flatnonzero(np.linalg.norm(target.positions[:, :2] - centre, axis=1) < radius)
    inv = np.linalg.inv(T_target_query)
    p = target.positions[keep] @ inv[:3, :3].T + inv[:3, 3]
    p = p + rng.normal(0, noise, p.shape)
    return SemanticGraph(p, target.labels[keep]), keep


def test_small_query_with_two_right_candidates_is_localized_by_its_geometry(rng):
    target = _scattered_map(rng)
    T = _yaw(70.0, [40.0, -25.0, 1.0])
    query, partner = _query_of(target, np.array([150.0, 150.0]), 28.0, T, rng)
    assert 10 <= len(query) < 30
    # Descriptors: random per target object; each query object copies a *wrong* same-class
    # target's descriptor, except two that copy their partner's: two right top-1 candidates.
    dt = rng.normal(size=(len(target), 32))
    dq = np.empty((len(query), 32))
    right = {int(np.argmin(query.positions[:, 0])), int(np.argmax(query.positions[:, 0]))}
    for i, j in enumerate(partner):
        same = np.flatnonzero((target.labels == target.labels[j]) & (np.arange(len(target)) != j))
        dq[i] = dt[j] if i in right else dt[rng.choice(same)]
    top1 = np.argmax(np.where(target.labels[None, :] == query.labels[:, None], dq @ dt.T, -np.inf),
                     axis=1)  # fmt: skip
    assert (top1 == partner).sum() == 2  # too few for the 5-inlier minimum of RANSAC

    v = verify_small_query(query, target, dq, dt, AcceptanceConfig())
    assert isinstance(v, Verification)
    assert v.accepted, v.reason
    dtr, drot = transform_error(v.transform, T)
    assert dtr < 0.5 and drot < 0.5
    assert v.confidence >= 0.9999
    # The co-located objects are the true partners.
    assert len(v.matches) >= len(query) - 1
    assert np.array_equal(partner[v.matches[:, 0]], v.matches[:, 1])


def _road(length=400.0, spacing=8.0, width=12.0) -> SemanticGraph:
    """Two rows of identical poles along a straight road, and trees halfway between them."""
    x = np.arange(0.0, length, spacing)
    poles = [np.column_stack([x, np.full_like(x, y), np.zeros_like(x)]) for y in (0.0, width)]
    trees = np.column_stack([x + spacing / 2, np.full_like(x, -4.0), np.full_like(x, 1.0)])
    pos = np.concatenate([*poles, trees])
    labels = np.repeat([0, 0, 1], len(x))
    return SemanticGraph(pos, labels)


def test_repetitive_road_is_refused(rng):
    target = _road()
    T = _yaw(-35.0, [100.0, 20.0, 0.0])
    # A stretch of the same road: fits the target everywhere along it, one spacing apart.
    query, _ = _query_of(target, np.array([200.0, 6.0]), 22.0, T, rng, noise=0.05)
    assert 10 <= len(query) < 30
    n_classes = 2
    from sgloc.descriptors import make_descriptor

    desc = make_descriptor("distance_histogram")
    dq = desc(query, n_classes, rng)
    dt = desc(target, n_classes, rng)
    v = verify_small_query(query, target, dq, dt, AcceptanceConfig())
    assert not v.accepted
    assert v.confidence < 0.9
    assert "another place" in v.reason or "few metres" in v.reason
    assert not localize(query, target).accepted


def test_random_small_query_against_unrelated_map_is_refused(rng):
    target = _scattered_map(rng)
    other = _scattered_map(np.random.default_rng(99))
    query, _ = _query_of(other, np.array([150.0, 150.0]), 30.0, np.eye(4), rng)
    dq = rng.normal(size=(len(query), 16))
    dt = rng.normal(size=(len(target), 16))
    v = verify_small_query(query, target, dq, dt, AcceptanceConfig())
    assert not v.accepted and v.reason


def test_localizer_verifies_only_refused_small_queries(monkeypatch, rng):
    calls = []
    real = stage_module.verify_small_query

    def spy(query, *args, **kwargs):
        calls.append(len(query))
        return real(query, *args, **kwargs)

    monkeypatch.setattr(stage_module, "verify_small_query", spy)
    target = _scattered_map(rng)
    other = _scattered_map(np.random.default_rng(5))
    small, _ = _query_of(other, np.array([150.0, 150.0]), 28.0, np.eye(4), rng)
    res = localize(small, target)
    assert not res.accepted and calls == [len(small)]
    assert "verification" in res.timings
    calls.clear()
    assert not localize(small, target, verify_small=False).accepted and calls == []
    assert not localize(small, target, dof=6, max_tilt=None).accepted and calls == []
    big, _ = _query_of(other, np.array([150.0, 150.0]), 60.0, np.eye(4), rng)
    assert len(big) >= 30
    localize(big, target)
    assert calls == []


def test_place_copied_elsewhere_in_the_map_is_refused(rng):
    """A map holding two copies of the query's place: the query fits both, so it must refuse
    (and it accepts when the copy is absent)."""
    from sgloc.descriptors import make_descriptor

    base = _scattered_map(rng, n=500)
    block = np.flatnonzero(np.linalg.norm(base.positions[:, :2] - [80.0, 80.0], axis=1) < 30.0)
    far = np.linalg.norm(base.positions[:, :2] - [220.0, 220.0], axis=1) >= 35.0
    keep = np.flatnonzero(far)  # clear the copy's place
    copy = base.positions[block] + [140.0, 140.0, 0.0]
    twice = SemanticGraph(
        np.concatenate([base.positions[keep], copy]),
        np.concatenate([base.labels[keep], base.labels[block]]),
    )
    once = SemanticGraph(base.positions[keep], base.labels[keep])
    T = _yaw(20.0, [10.0, 5.0, 0.0])
    query, _ = _query_of(once, np.array([80.0, 80.0]), 24.0, T, rng, noise=0.05)
    assert 10 <= len(query) < 30
    desc = make_descriptor("distance_histogram")
    dq = desc(query, 3, rng)
    ok = verify_small_query(query, once, dq, desc(once, 3, rng), AcceptanceConfig())
    assert ok.accepted, ok.reason
    assert transform_error(ok.transform, T)[0] < 1.0
    v = verify_small_query(query, twice, dq, desc(twice, 3, rng), AcceptanceConfig())
    assert not v.accepted
    assert v.confidence < 0.9


def test_self_rival_finds_the_other_copy_of_a_place(rng):
    from sgloc.descriptors import make_descriptor

    base = _scattered_map(rng, n=500)
    block = np.flatnonzero(np.linalg.norm(base.positions[:, :2] - [80.0, 80.0], axis=1) < 24.0)
    keep = np.flatnonzero(np.linalg.norm(base.positions[:, :2] - [220.0, 220.0], axis=1) >= 35)
    n_keep = len(keep)
    pos = np.concatenate([base.positions[keep], base.positions[block] + [140.0, 140.0, 0.0]])
    target = SemanticGraph(pos, np.concatenate([base.labels[keep], base.labels[block]]))
    placed = np.flatnonzero(np.isin(keep, block))  # the original block, inside the target
    dt = make_descriptor("distance_histogram")(target, 3, rng)
    cfg = AcceptanceConfig()
    tree = ClassTree(target, cfg.verification.verify_radius)
    chance = ChanceModel(target, cfg.verification.verify_density_radius, 3)
    context = SearchContext(target.positions, tree, chance, 15.0, cfg.distinct_rotation)
    lg, k = self_rival(target, dt, placed, context, cfg, 0.5, 100)
    assert k >= len(placed) - 1 and lg < -3
    # Without the copy, nothing else in the map fits the block.
    alone = SemanticGraph(target.positions[:n_keep], target.labels[:n_keep])
    tree = ClassTree(alone, cfg.verification.verify_radius)
    chance = ChanceModel(alone, cfg.verification.verify_density_radius, 3)
    context = SearchContext(alone.positions, tree, chance, 15.0, cfg.distinct_rotation)
    dt = make_descriptor("distance_histogram")(alone, 3, rng)
    lg, k = self_rival(alone, dt, placed, context, cfg, 0.5, 100)
    assert k <= 4


def test_accept_takes_the_verified_alignment_through_the_callers_refit(rng):
    """`accept` on a small query estimation could not localize: the whole-map verification
    finds the alignment; the verdict carries the co-located matches the caller's `refit` was
    given, and a refit that fails leaves the query refused with the estimation's reason."""
    from sgloc.acceptance import accept

    target = _scattered_map(rng)
    T = _yaw(30.0, [20.0, -10.0, 0.5])
    query, partner = _query_of(target, np.array([150.0, 150.0]), 28.0, T, rng, noise=0.05)
    assert 10 <= len(query) < 30
    from sgloc.descriptors import make_descriptor

    desc = make_descriptor("distance_histogram")
    dq, dt = desc(query, 3, rng), desc(target, 3, rng)
    empty = np.zeros((0, 2), np.int64)
    given = []

    def refit(matches):
        given.append(matches)
        return np.eye(4)

    kw = {"radius": 5.0, "motion": GROUND_VEHICLE, "rng": np.random.default_rng(0)}
    v = accept(query, target, dq, dt, empty, None, None, empty, "ransac failed", refit=refit, **kw)
    assert v.accepted and v.verified and v.reason == "" and v.assessment is None
    assert np.array_equal(v.transform, np.eye(4))  # the caller's refit is the result
    assert len(given) == 1 and np.array_equal(given[0], v.matches)
    assert np.array_equal(partner[v.matches[:, 0]], v.matches[:, 1])
    assert v.confidence == v.verification.confidence >= 0.9999
    assert set(v.timings) == {"verification"}
    plain = accept(query, target, dq, dt, empty, None, None, empty, "x", **kw)
    assert transform_error(plain.transform, T)[0] < 0.5  # without refit: the verification's own
    failed = accept(query, target, dq, dt, empty, None, None, empty, "x", refit=lambda m: None,
                    **kw)  # fmt: skip
    assert not failed.accepted and failed.transform is None and len(failed.matches) == 0
    assert failed.reason.startswith("only 0 candidate")  # fewer than 3 candidates: said so
    six = accept(query, target, dq, dt, np.zeros((5, 2), np.int64), None, None, empty, "x",
                 **(kw | {"motion": ANY_RIGID}))  # fmt: skip
    assert not six.accepted and six.verification is None and six.reason == "x"


def _no_distinctive_match(query, target, partner, rng):
    """Descriptors where each query object's most similar target is a wrong one of its class
    and its partner comes second: the right pairs are candidates but none is a best match."""
    dt = rng.normal(size=(len(target), 32))
    dq = np.empty((len(query), 32))
    for i, j in enumerate(partner):
        same = np.flatnonzero((target.labels == target.labels[j]) & (np.arange(len(target)) != j))
        dq[i] = dt[rng.choice(same)] + 0.6 * dt[j]
    return dq, dt


def test_one_class_maps_are_decided_by_their_geometry_without_a_distinctive_pair(rng):
    one = _scattered_map(rng, n=300)
    one = SemanticGraph(one.positions, np.zeros(len(one), np.int64))
    two = SemanticGraph(one.positions, np.arange(len(one)) % 2)
    T = _yaw(-40.0, [20.0, 35.0, 0.5])
    centre = np.array([150.0, 150.0])
    for target in (one, two):
        query, partner = _query_of(target, centre, 28.0, T, rng)
        assert 10 <= len(query) < 30
        dq, dt = _no_distinctive_match(query, target, partner, rng)
        v = verify_small_query(query, target, dq, dt, AcceptanceConfig())
        assert v.details["distinct_support"] == 0
        assert len(v.matches) >= len(query) - 1  # the geometry fits either way
        if target is one:  # one class: the chance model and the rivals decide
            assert v.details["classes"] == 1
            assert v.accepted, v.reason
            c = np.append(query.positions.mean(axis=0), 1.0)  # where the query is
            assert np.linalg.norm((v.transform @ c - T @ c)[:3]) < 0.5
        else:  # two classes: a place without a distinctive pair is not recognisable
            assert v.details["classes"] == 2
            assert not v.accepted and "distinctive" in v.reason
