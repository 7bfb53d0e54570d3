"""The acceptance test against repeating layouts (sgloc.acceptance.repetition)."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc import SemanticGraph
from sgloc.acceptance import AcceptanceConfig, assess
from sgloc.acceptance.repetition import log10_rival_weight, self_similar_shifts
from sgloc.geometry import apply, invert, make_transform, random_rigid_transform

PERIOD = 20.0
#: The test with the repetition check on (off by default).
SHIFTS = AcceptanceConfig(repetition_shifts=8)


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
    before = assess(query, target, cand, T_false, 2.0, AcceptanceConfig())  # the default: off
    assert before.accepted and before.confidence > 0.9999  # the chance model alone is fooled
    a = assess(query, target, cand, T_false, 2.0, SHIFTS)
    assert not a.accepted and a.confidence < 0.9
    assert a.reason.startswith("ambiguous: the target map repeats itself")
    assert "repetition_shifts=0" in a.reason
    squared = (a.details["repetition_shift_m"] / PERIOD) ** 2  # a lattice vector: i^2 + j^2
    assert squared >= 1 - 0.1 and abs(squared - round(squared)) < 0.1


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
