"""The sub-quadratic candidate search (sgloc.matching.index): exact where it probes the whole
class, a measured recall on a realistic map otherwise, the auto rule, and a prepared map's
index kept right by add / save / load."""

from __future__ import annotations

import numpy as np
import pytest

import sgloc
from sgloc import LocalizerConfig, PreparedMap, SemanticGraph, localize
from sgloc.errors import SglocError
from sgloc.matching import index as mi
from sgloc.matching.candidates import MatchingConfig, match_flagged
from sgloc.pipeline.presets import localizer_preset
from sgloc.sim.object_world import make_two_robot_scene


def descriptors(rng: np.random.Generator, n: int, d: int = 48, classes: int = 3):
    """Sparse non-negative histogram-like rows (some all zero) and labels."""
    D = rng.random((n, d)) * (rng.random((n, d)) < 0.3)
    D[rng.random(n) < 0.02] = 0.0
    D[::97] = D[1::97][: len(D[::97])]  # exact duplicates: ties broken by the lower index
    return D, rng.integers(0, classes, n)


def same(a, b) -> None:
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x, y)  # bit for bit


@pytest.mark.parametrize("k,max_ratio,flag", [(1, None, None), (3, 0.9, 0.8), (2, None, 0.7)])
def test_probing_every_list_is_the_exact_search(k, max_ratio, flag):
    rng = np.random.default_rng(k)
    Dq, lq = descriptors(rng, 700)
    Dt, lt = descriptors(rng, 2500)
    exact = MatchingConfig(top_k=k, max_ratio=max_ratio, search="exact", min_similarity=0.3)
    whole = MatchingConfig(top_k=k, max_ratio=max_ratio, search="index", probes=10**6,
                           min_similarity=0.3)  # fmt: skip
    a = match_flagged(Dq, Dt, lq, lt, exact, flag)
    b = match_flagged(Dq, Dt, lq, lt, whole, flag)
    assert len(a[0]) > 100
    same(a, b)
    few = match_flagged(Dq, Dt, lq, lt, MatchingConfig(top_k=k, max_ratio=max_ratio,
                        search="index", probes=2, min_similarity=0.3), flag)  # fmt: skip
    assert not np.array_equal(a[0], few[0])  # two lists of ~30 miss some best matches


def test_index_is_deterministic():
    rng = np.random.default_rng(5)
    D, lab = descriptors(rng, 3000)
    rows = np.flatnonzero(lab == 1)
    a, b = mi.build_class_index(D, rows), mi.build_class_index(D, rows)
    for x, y in zip((a.centres, a.blocks, a.list_start, a.members),
                    (b.centres, b.blocks, b.list_start, b.members), strict=True):  # fmt: skip
        assert np.array_equal(x, y)
    assert a.n_lists == mi.n_lists(len(rows))
    assert np.array_equal(np.sort(a.members), rows)  # every row in exactly one list


def test_auto_rule():
    assert not mi.uses_index("exact", 10**6)
    assert mi.uses_index("index", 1)
    assert not mi.uses_index("auto", mi.INDEX_MIN_CLASS)  # class too small
    assert mi.uses_index("auto", mi.INDEX_MIN_CLASS + 1)


def test_index_is_kept_by_the_callers_store():
    rng = np.random.default_rng(4)
    D, lab = descriptors(rng, 2000)
    D.flags.writeable = False
    assert mi.class_index(D, lab, 1) is not mi.class_index(D, lab, 1)  # nothing kept itself
    kept: dict = {}
    a = mi.class_index(D, lab, 1, kept)
    assert mi.class_index(D, lab, 1, kept) is a and list(kept) == [1]  # built once
    other = lab.copy()
    other[np.flatnonzero(lab == 1)[:5]] = 0
    assert mi.class_index(D, other, 1, kept) is not a  # another class table: built anew


def test_auto_is_exact_below_the_rule_and_the_index_above(monkeypatch):
    rng = np.random.default_rng(9)
    Dq, lq = descriptors(rng, 900)
    Dt, lt = descriptors(rng, 3000)
    auto, exact = MatchingConfig(search="auto"), MatchingConfig(search="exact")
    index = MatchingConfig(search="index")
    same(match_flagged(Dq, Dt, lq, lt, auto), match_flagged(Dq, Dt, lq, lt, exact))
    monkeypatch.setattr(mi, "INDEX_MIN_CLASS", 500)
    a = match_flagged(Dq, Dt, lq, lt, auto)
    same(a, match_flagged(Dq, Dt, lq, lt, index))
    assert not np.array_equal(a[0], match_flagged(Dq, Dt, lq, lt, exact)[0])


def test_settings_are_checked():
    with pytest.raises(SglocError, match="search"):
        MatchingConfig(search="fast")
    with pytest.raises(SglocError, match="probes"):
        MatchingConfig(probes=0)
    assert localizer_preset("paper").matching.search == "exact"


@pytest.fixture(scope="module")
def city():
    """Two generated maps of about 10,000 objects each (50 % overlap) and their descriptors."""
    scene = make_two_robot_scene(seed=0, overlap=0.5, stretch=10_000 / 0.47, view_radius=130.0)
    L = int(max(scene.query.labels.max(), scene.target.labels.max())) + 1
    desc = LocalizerConfig().descriptor_config
    rng = np.random.default_rng(0)
    return scene, desc(scene.query, L, rng), desc(scene.target, L, rng)


def test_recall_on_a_city_map(city):
    """Default probes find >= 85 % of the exact best matches, >= 90 % of the correct ones."""
    scene, Dq, Dt = city
    lq, lt = scene.query.labels, scene.target.labels
    exact = match_flagged(Dq, Dt, lq, lt, MatchingConfig(search="exact"))[0]
    found = match_flagged(Dq, Dt, lq, lt, MatchingConfig(search="index"))[0]
    hit = {tuple(p) for p in found}
    recall = np.mean([tuple(p) in hit for p in exact])
    T = scene.T_target_query
    moved = scene.query.positions[exact[:, 0]] @ T[:3, :3].T + T[:3, 3]
    correct = np.linalg.norm(moved - scene.target.positions[exact[:, 1]], axis=1) < 1.0
    recall_correct = np.mean([tuple(p) in hit for p in exact[correct]])
    assert correct.sum() > 500
    assert recall >= 0.85 and recall_correct >= 0.90, (recall, recall_correct)
    assert recall < 1.0  # the index did run


def test_index_localizes_a_city_map(city):
    scene = city[0]
    config = LocalizerConfig().with_overrides(search="index")
    res = localize(scene.query, scene.target, config=config, seed=0)
    assert res.accepted
    from sgloc.geometry import transform_error

    assert transform_error(res.transform, scene.T_target_query)[0] < 1.0


@pytest.fixture
def small_rule(monkeypatch):
    """The auto rule scaled down so a 4,000-object map's classes use the index."""
    monkeypatch.setattr(mi, "INDEX_MIN_CLASS", 200)


@pytest.fixture(scope="module")
def street() -> SemanticGraph:
    return make_two_robot_scene(seed=3, stretch=4000 / 0.47, view_radius=130.0).target


def scans(g: SemanticGraph, rng: np.random.Generator, n: int, radius: float = 60.0):
    out = []
    for c in rng.choice(len(g), n, replace=False):
        near = np.linalg.norm(g.positions - g.positions[c], axis=1) < radius
        pos = g.positions[near] + rng.normal(0, 0.2, (int(near.sum()), 3)) + [5, -3, 0]
        out.append(SemanticGraph(pos, g.labels[near], name=f"scan{c}"))
    return out


def same_index(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b) and a
    for c in a:
        for name in ("centres", "blocks", "list_start", "members"):
            assert np.array_equal(getattr(a[c], name), getattr(b[c], name)), (c, name)


def test_prepared_map_keeps_the_index(small_rule, street, tmp_path):
    prepared = sgloc.prepare(street)
    assert prepared.blocks.index  # built once, for the classes the rule sends to it
    assert not sgloc.prepare(street, localizer_preset("paper")).blocks.index
    fresh = SemanticGraph(street.positions, street.labels, street.edge_radius, street.name)
    for seed, query in enumerate(scans(street, np.random.default_rng(1), 3)):
        a, b = localize(query, fresh, seed=seed), localize(query, prepared, seed=seed)
        assert np.array_equal(a.candidates, b.candidates) and a.accepted == b.accepted
        if a.transform is not None:
            assert np.array_equal(a.transform, b.transform)
    grown = sgloc.prepare(SemanticGraph(street.positions[:-40], street.labels[:-40]))
    grown.add(street.positions[-40:], street.labels[-40:])
    same_index(grown.blocks.index, prepared.blocks.index)
    loaded = PreparedMap.load(prepared.save(tmp_path / "map.npz"))
    same_index(loaded.blocks.index, prepared.blocks.index)


def test_prepared_blocks_leave_out_indexed_classes(small_rule, street):
    """The exhaustive blocks of a prepared map hold only the classes not searched by the index
    (one copy of the descriptors less); a localizer searching exactly against that map still
    gets the exact search's candidates, bit for bit."""
    prepared = sgloc.prepare(street)
    blocks = prepared.blocks
    indexed = np.array(sorted(blocks.index))
    assert indexed.size and len(blocks.order) < len(street)
    assert not np.isin(blocks.block_class, indexed).any()
    assert len(blocks.order) == np.count_nonzero(~np.isin(prepared.target.labels, indexed))
    exact = LocalizerConfig(matching=MatchingConfig(search="exact"))
    fresh = SemanticGraph(street.positions, street.labels, street.edge_radius, street.name)
    prepared_exact = sgloc.prepare(fresh, exact)
    assert not prepared_exact.blocks.index and len(prepared_exact.blocks.order) == len(street)
    for seed, query in enumerate(scans(street, np.random.default_rng(2), 3)):
        a = localize(query, prepared_exact, config=exact, seed=seed)
        b = localize(query, prepared, config=exact, seed=seed)
        assert np.array_equal(a.candidates, b.candidates) and a.accepted == b.accepted
        assert np.array_equal(a.scores, b.scores)
