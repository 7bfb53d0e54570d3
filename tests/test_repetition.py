"""The acceptance test against repeating layouts (sgloc.acceptance.repetition)."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc import SemanticGraph
from sgloc.acceptance import AcceptanceConfig, assess
from sgloc.acceptance.repetition import (
    log10_binomial_sum_tail,
    log10_rival_weight,
    self_similar_shifts,
)
from sgloc.geometry import apply, invert, make_transform, random_rigid_transform

PERIOD = 20.0
#: The test with the rival-shift check on (off by default).
SHIFTS = AcceptanceConfig(repetition_shifts=8)
#: The test without any repetition check (the default).
PLAIN = AcceptanceConfig()
#: The test with the layout's own chance on (off by default).
LAYOUT = AcceptanceConfig(layout_shifts=8)


def _lattice(rng: np.random.Generator, blocks: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """A block of 8 objects of 4 classes repeated on a square lattice of PERIOD metres."""
    block = np.column_stack([rng.uniform(0, PERIOD, (8, 2)), rng.uniform(0, 3, 8)])
    lab = rng.integers(0, 4, 8)
    ij = np.stack(np.meshgrid(np.arange(blocks), np.arange(blocks)), -1).reshape(-1, 2)
    pos = (block[None] + np.column_stack([ij * PERIOD, np.zeros(len(ij))])[:, None]).reshape(-1, 3)
    return pos + rng.normal(0, 0.05, pos.shape), np.tile(lab, len(ij))


def _crop(pos, lab, lo, hi, rng, noise=0.05):
    """The objects inside the xy box [lo, hi), with noise."""
    keep = np.all((pos[:, :2] >= lo) & (pos[:, :2] < hi), axis=1)
    return pos[keep] + rng.normal(0, noise, (int(keep.sum()), 3)), lab[keep], np.flatnonzero(keep)


def _lattice_offset_pair(rng):
    """Target: the lattice. Query: a crop of it (3 x 3 periods) under a random motion; its
    candidates match every object to the same object one period further along x: one
    consistent, lattice-offset false match (T_false), and the true alignment T_true."""
    pos, lab = _lattice(rng)
    q, ql, idx = _crop(pos, lab, (2 * PERIOD, 2 * PERIOD), (5 * PERIOD, 5 * PERIOD), rng)
    M = random_rigid_transform(rng, 100.0, 0.0)
    query = SemanticGraph(apply(M, q), ql)
    target = SemanticGraph(pos, lab)
    # each object's candidate: the same object of the next block along x (8 objects a block)
    cand = np.column_stack([np.arange(len(idx)), idx + 8])
    T_true = invert(M)
    T_false = make_transform(np.eye(3), np.array([PERIOD, 0.0, 0.0])) @ T_true
    return query, target, cand, T_true, T_false


def test_lattice_offset_false_match_is_refused_as_ambiguous(rng):
    query, target, cand, T_true, T_false = _lattice_offset_pair(rng)
    before = assess(query, target, cand, T_false, 2.0, PLAIN)
    assert before.accepted and before.confidence > 0.9999  # the chance model alone is fooled
    a = assess(query, target, cand, T_false, 2.0, SHIFTS)
    assert not a.accepted and a.confidence < 0.9
    assert a.reason.startswith("ambiguous: the target map repeats itself")
    assert "repetition_shifts=0" in a.reason
    squared = (a.details["repetition_shift_m"] / PERIOD) ** 2  # a lattice vector: i^2 + j^2
    assert squared >= 1 - 0.1 and abs(squared - round(squared)) < 0.1


def _street_grid(rng: np.random.Generator, blocks: int = 7):
    """A street grid of blocks STREET metres wide: the same 10 pieces of street furniture
    (classes 0-1) in every block, and 10 objects (classes 2-4) at random places of each
    block (buildings, trees: what the layout does not repeat). Returns positions, labels."""
    furniture = np.column_stack([rng.uniform(0, STREET, (10, 2)), rng.uniform(0, 3, 10)])
    furniture_labels = rng.integers(0, 2, 10)
    pos, lab = [], []
    for i in range(blocks):
        for j in range(blocks):
            corner = np.array([i * STREET, j * STREET, 0.0])
            own = np.column_stack([rng.uniform(0, STREET, (10, 2)), rng.uniform(0, 3, 10)])
            pos += [furniture + corner, own + corner]
            lab += [furniture_labels, rng.integers(2, 5, 10)]
    return np.concatenate(pos), np.concatenate(lab)


STREET = 40.0


def _street_grid_pair(rng):
    """Target: the street grid. Query: 3 x 3 of its blocks (5 cm noise) under a random motion.
    Returns query, target, the true candidates (every object to itself) with T_true, and the
    lattice-offset false match: every piece of furniture to its copy one block further
    along x, with T_false (the true alignment moved by that block)."""
    pos, lab = _street_grid(rng)
    q, ql, idx = _crop(pos, lab, (2 * STREET, 2 * STREET), (5 * STREET, 5 * STREET), rng)
    M = random_rigid_transform(rng, 100.0, 0.0)
    query, target = SemanticGraph(apply(M, q), ql), SemanticGraph(pos, lab)
    true = np.column_stack([np.arange(len(idx)), idx])
    # blocks are listed along y first, 20 objects each (10 furniture, then 10 of its own)
    furniture = np.flatnonzero(idx % 20 < 10)
    false = np.column_stack([furniture, idx[furniture] + 20 * 7])
    assert np.allclose(pos[false[:, 1]] - pos[idx[furniture]], [STREET, 0, 0])
    T_true = invert(M)
    T_false = make_transform(np.eye(3), np.array([STREET, 0.0, 0.0])) @ T_true
    return query, target, (true, T_true), (false, T_false)


def test_lattice_offset_on_a_street_grid_is_refused_as_ambiguous(rng):
    """The street furniture of a grid matched one block off: every piece lands, so the chance
    model alone (the default) accepts it with confidence ~1; the layout's own chance knows
    that a copy of the grid lands its furniture too, and nothing else: ambiguous."""
    assert PLAIN.layout_shifts == 0
    query, target, _, (cand, T_false) = _street_grid_pair(rng)
    plain = assess(query, target, cand, T_false, 2.0, PLAIN)
    assert plain.accepted and plain.confidence > 0.9999
    a = assess(query, target, cand, T_false, 2.0, LAYOUT)
    assert not a.accepted and a.confidence < 0.5
    assert a.reason.startswith("ambiguous: the maps repeat themselves"), a.reason
    assert "layout_shifts=0" in a.reason
    assert a.details["layout_shifts_measured"] > 0 and a.details["layout_log10_nfa"] > 0


def test_true_match_on_the_street_grid_is_accepted(rng):
    """The same grid's true alignment lands the objects the layout does not repeat too."""
    query, target, (cand, T_true), _ = _street_grid_pair(rng)
    a = assess(query, target, cand, T_true, 2.0, LAYOUT)
    assert a.accepted and a.confidence > 0.9999, a.reason
    assert a.details["layout_shifts_measured"] > 0 and a.details["layout_log10_nfa"] < -10
    assert a.details["layout_expected_landed"] < 0.8 * a.details["agreement_landed"]


def test_layout_chance_changes_nothing_without_repetition(rng):
    """On a layout that does not repeat no self-similar shift is found: the same verdict."""
    pos = np.column_stack([rng.uniform(0, 140, (280, 2)), rng.uniform(0, 3, 280)])
    lab = rng.integers(0, 4, 280)
    q, ql, idx = _crop(pos, lab, (40, 40), (100, 100), rng)
    M = random_rigid_transform(rng, 100.0, 0.0)
    query, target = SemanticGraph(apply(M, q), ql), SemanticGraph(pos, lab)
    cand = np.column_stack([np.arange(len(idx)), idx])
    a = assess(query, target, cand, invert(M), 2.0, LAYOUT)
    b = assess(query, target, cand, invert(M), 2.0, PLAIN)
    assert a.accepted and b.accepted and a.confidence == pytest.approx(b.confidence)
    assert a.details["layout_shifts_measured"] == 0


def test_layout_shifts_setting():
    """Off by default; a count of shifts per map; a bad value is refused by name."""
    from sgloc.pipeline.config import LocalizerConfig

    assert LocalizerConfig().acceptance.layout_shifts == 0
    assert LocalizerConfig().with_overrides(layout_shifts=8).acceptance.layout_shifts == 8
    with pytest.raises(ValueError, match="layout_shifts"):
        AcceptanceConfig(layout_shifts=-1)


def test_binomial_sum_tail():
    """The tail of a sum of binomials: exact against a direct sum, 0 (log) at or below 0
    landed, -inf above the objects counted."""
    from scipy.stats import binom

    n, p = np.array([3, 0, 5]), np.array([0.5, 0.9, 0.2])
    full = np.convolve(binom.pmf(np.arange(4), 3, 0.5), binom.pmf(np.arange(6), 5, 0.2))
    for k in range(1, 9):
        assert 10 ** log10_binomial_sum_tail(k, n, p) == pytest.approx(full[k:].sum())
    assert log10_binomial_sum_tail(0, n, p) == 0.0
    assert log10_binomial_sum_tail(9, n, p) == -np.inf


def test_true_alignment_on_the_lattice_is_as_ambiguous(rng):
    """Nothing tells the true place of a crop of a lattice from the next block: refused too."""
    query, target, cand, T_true, _ = _lattice_offset_pair(rng)
    cand = np.column_stack([cand[:, 0], cand[:, 1] - 8])
    a = assess(query, target, cand, T_true, 2.0, SHIFTS)
    assert not a.accepted and "ambiguous" in a.reason


def test_true_match_on_a_non_repetitive_layout_passes(rng):
    pos = np.column_stack([rng.uniform(0, 140, (280, 2)), rng.uniform(0, 3, 280)])
    lab = rng.integers(0, 4, 280)
    q, ql, idx = _crop(pos, lab, (40, 40), (100, 100), rng)
    M = random_rigid_transform(rng, 100.0, 0.0)
    cand = np.column_stack([np.arange(len(idx)), idx])
    a = assess(SemanticGraph(apply(M, q), ql), SemanticGraph(pos, lab), cand, invert(M), 2.0,
               SHIFTS)  # fmt: skip
    assert a.accepted and a.confidence > 0.9999, a.reason
    assert a.details["agreement_landed"] >= 0.9 * a.details["agreement_covered"]
    assert a.details["repetition_log10_p"] < -10


def _forest(rng, width: float, height: float, density: float) -> np.ndarray:
    """Trunks of one class: a Poisson process of `density` per m^2 on [0, width) x [0, height)."""
    n = rng.poisson(density * width * height)
    return np.column_stack([rng.uniform(0, width, n), rng.uniform(0, height, n), np.zeros(n)])


def _seen(world: np.ndarray, lo: float, hi: float, rng, noise: float = 0.3):
    """The trunks with x in [lo, hi), 90 % of them, with `noise` m of position noise."""
    keep = (world[:, 0] >= lo) & (world[:, 0] < hi) & (rng.random(len(world)) < 0.9)
    idx = np.flatnonzero(keep)
    return world[idx] + rng.normal(0, noise, (len(idx), 3)), idx


@pytest.mark.parametrize("density", [0.02, 0.05, 0.1])
def test_one_class_forest_crop_passes_and_another_forest_is_refused(rng, density):
    world = _forest(rng, 120.0, 100.0, density)
    tpos, tidx = _seen(world, 0.0, 100.0, rng)
    qpos, qidx = _seen(world, 20.0, 120.0, rng)  # 80 % of the query's strip overlaps
    target = SemanticGraph(tpos, np.zeros(len(tpos), np.int64))
    M = random_rigid_transform(rng, 100.0, 0.0)
    query = SemanticGraph(apply(M, qpos), np.zeros(len(qpos), np.int64))
    # Candidates: the true partner for 40 % of the query objects, a random trunk for the rest.
    partner = {int(w): k for k, w in enumerate(tidx)}
    true = [(i, partner[int(w)]) for i, w in enumerate(qidx) if int(w) in partner]
    true = [p for p in true if rng.random() < 0.4]
    wrong = [(i, int(rng.integers(len(tpos)))) for i in range(len(qpos)) if rng.random() < 0.6]
    cand = np.array(sorted(true + wrong), np.int64)
    for cfg in (AcceptanceConfig(), SHIFTS, AcceptanceConfig(min_agreement=0.75)):
        a = assess(query, target, cand, invert(M), 2.0, cfg)
        assert a.accepted, a.reason
    # A crop of a different random forest with the same candidates' structure: refused.
    other = _forest(rng, 120.0, 100.0, density)
    opos, _ = _seen(other, 20.0, 120.0, rng)
    oq = SemanticGraph(apply(M, opos), np.zeros(len(opos), np.int64))
    ocand = np.column_stack([np.arange(len(opos)), rng.integers(0, len(tpos), len(opos))])
    b = assess(oq, target, ocand, invert(M), 2.0, SHIFTS)
    assert not b.accepted


def test_self_similar_shifts_find_the_lattice_period(rng):
    pos, lab = _lattice(rng)
    g = SemanticGraph(pos, lab)
    anchors = np.flatnonzero((pos[:, 0] > 60) & (pos[:, 0] < 80) & (pos[:, 1] > 60)
                             & (pos[:, 1] < 80))  # fmt: skip
    d = self_similar_shifts(g, anchors, 0.5, 10.0, 30.0, 4)
    assert len(d) == 4
    steps = d[:, :2] / PERIOD  # lattice vectors: whole numbers of periods along x and y
    assert np.all(np.abs(steps - np.round(steps)) < 0.05) and np.all(np.abs(steps).sum(1) >= 1)
    trunks = _forest(rng, 100.0, 100.0, 0.05)
    forest = SemanticGraph(trunks, np.zeros(len(trunks), np.int64))
    assert len(self_similar_shifts(forest, np.arange(40), 0.5, 10.0, 30.0, 4)) <= 4


def test_rival_weight():
    """A tie weighs 1, a rival that lands more too (at most 1); an estimate that lands objects
    no shift lands weighs the rivals down, the more the rarer such landings are."""
    lg = log10_rival_weight(np.array([5, 0, 12]), np.array([5, 3, 0]))
    assert lg[0] == 0.0 and lg[1] == 0.0 and lg[2] < -4
    mu = 9.0 / 4.0  # (5 + 3 + 0 + 1) / (3 + 1)
    from scipy.stats import poisson

    assert lg[2] == pytest.approx(np.log10(poisson.sf(11, mu)), rel=1e-9)
    assert log10_rival_weight(np.array([6]), np.array([6]))[0] == 0.0


def test_agreement_refuses_an_overlap_that_mostly_disagrees(rng):
    """Half of the query's objects match a look-alike copy, the rest land next to target
    objects of other classes: refused when min_agreement asks for 75 %, with the rule and its
    setting named (the default, 0, does not check)."""
    pos = np.column_stack([rng.uniform(0, 100, (200, 2)), np.zeros(200)])
    lab = rng.integers(0, 4, 200)
    qlab = lab.copy()
    qlab[100:] = (lab[100:] + 1) % 4  # the other half: same places, other classes
    cand = np.column_stack([np.arange(100), np.arange(100)])
    query = SemanticGraph(pos + rng.normal(0, 0.05, pos.shape), qlab)
    cfg = AcceptanceConfig(min_agreement=0.75)
    a = assess(query, SemanticGraph(pos, lab), cand, np.eye(4), 2.0, cfg)
    assert not a.accepted
    assert "min_agreement" in a.reason and "repeating layout" in a.reason
    assert assess(query, SemanticGraph(pos, lab), cand, np.eye(4), 2.0).accepted  # the default



def _room(rng):
    """A 12 m x 8 m room of 35 objects of 4 classes; the query: 85 % of them, 5 cm noise,
    under a random rigid motion (a crop of the room)."""
    pos = np.column_stack([rng.uniform(0, 12, 35), rng.uniform(0, 8, 35), rng.uniform(0, 2, 35)])
    lab = rng.integers(0, 4, 35)
    idx = np.sort(rng.choice(35, 30, replace=False))
    M = random_rigid_transform(rng, 10.0, 0.0)
    q = SemanticGraph(apply(M, pos[idx] + rng.normal(0, 0.05, (30, 3))), lab[idx])
    return q, SemanticGraph(pos, lab), np.column_stack([np.arange(30), idx]), invert(M)


def test_room_passes_when_the_lengths_follow_the_scene_scale(rng):
    query, target, cand, T = _room(rng)
    street = assess(query, target, cand, T, 0.5, AcceptanceConfig())
    assert not street.accepted and "spread" in street.reason  # street lengths: 10 m spread
    for cfg in (AcceptanceConfig(), SHIFTS, AcceptanceConfig(min_agreement=0.75)):
        room = assess(query, target, cand, T, 0.5, cfg.scaled(0.1))
        assert room.accepted, room.reason


def test_scaled_multiplies_every_length_and_nothing_else():
    base = AcceptanceConfig(radius=2.0, agreement_radius=0.5)
    half = base.scaled(0.5)
    for group, names in AcceptanceConfig.LENGTHS.items():
        for name in names:
            b = getattr(getattr(base, group) if group else base, name)
            h = getattr(getattr(half, group) if group else half, name)
            assert h == (None if b is None else 0.5 * b)
    assert half.distinct_rotation == base.distinct_rotation
    assert half.min_confidence == base.min_confidence
    assert half.cover_radius is None  # follows agreement_radius
    with pytest.raises(ValueError, match="scale factor"):
        base.scaled(0.0)


def test_city_objects_preset_keeps_a_big_street_grid_fleet_right():
    """The 12x12-block city (2,000 m routes, a tuning seed) cut into 8 robots and replayed:
    with the `city` preset some attempts are accepted at another copy of the street grid
    (hundreds of metres off); with `city-objects` (the agreement check) none is, and every
    overlapping robot still joins, none placed wrong."""
    from sgloc.evaluation.fleet_cases import Case, case_scenario
    from sgloc.evaluation.fleet_runs import run_fleet
    from sgloc.online import OnlineConfig
    from sgloc.pipeline.presets import localizer_preset

    case = Case("t", "big city", "t", "city", 8, 0.0, 1, 2000.0, 12)
    assert case.preset == "city-objects"
    scenario = case_scenario(case)
    runs = {p: run_fleet(scenario, localizer_preset(p), OnlineConfig(), oracle=False)
            for p in ("city", "city-objects")}
    assert runs["city"]["wrong_accepted"] > 0  # the chance model alone is fooled
    right = runs["city-objects"]
    assert right["wrong_accepted"] == 0 and right["wrong_joins"] == []
    assert right["joined"] == right["overlapping"] == 7
