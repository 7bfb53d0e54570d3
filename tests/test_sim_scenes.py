"""The synthetic forests and rooms of `sgloc.sim`: densities, noise, overlaps, repeated rooms,
determinism by seed."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from sgloc.geometry import apply, rotation_angle_deg
from sgloc.sim.forest import (
    ForestConfig,
    forest_negative,
    forest_pair,
    forest_scan,
    make_forest,
)
from sgloc.sim.rooms import (
    FURNITURE_CLASSES,
    MIN_GAP,
    RoomConfig,
    floor_pair,
    make_floor,
    make_room,
    repeated_room_pair,
    room_pair,
)


def true_residuals(pair) -> np.ndarray:
    """Distances (m) between the two maps' copies of each shared object under the GT."""
    where = {int(t): i for i, t in enumerate(pair.target_truth) if t >= 0}
    qi = [i for i, t in enumerate(pair.query_truth) if t >= 0 and int(t) in where]
    ti = [where[int(pair.query_truth[i])] for i in qi]
    moved = apply(pair.T_target_query, pair.query.positions[qi])
    return np.linalg.norm(moved - pair.target.positions[ti], axis=1)


@pytest.mark.parametrize("density", [0.02, 0.05, 0.1])
def test_forest_density_and_no_lattice(density):
    cfg = ForestConfig(density=density, size=200.0)
    trunks = make_forest(np.random.default_rng(1), cfg)
    assert len(trunks) == pytest.approx(density * 200.0**2, rel=0.1)
    d, _ = cKDTree(trunks[:, :2]).query(trunks[:, :2], k=2)
    nn = d[:, 1]
    # Poisson: mean nearest-neighbour distance 0.5 / sqrt(density), coefficient of variation
    # ~0.52; a lattice would have all distances equal.
    assert nn.mean() == pytest.approx(0.5 / np.sqrt(density), rel=0.15)
    assert nn.std() / nn.mean() > 0.3


def test_clumped_forest_is_more_variable_than_poisson():
    def quadrat_dispersion(clustering: float) -> float:
        t = make_forest(np.random.default_rng(2), ForestConfig(clustering=clustering, size=200.0))
        counts = np.histogram2d(t[:, 0], t[:, 1], bins=20, range=[[0, 200], [0, 200]])[0]
        return counts.var() / counts.mean()

    assert quadrat_dispersion(0.0) == pytest.approx(1.0, abs=0.35)  # Poisson: var = mean
    assert quadrat_dispersion(0.8) > 2.0


def test_forest_pair_truth_noise_drift_and_one_class():
    cfg = ForestConfig()
    pair = forest_pair(np.random.default_rng(3), cfg)
    assert set(np.unique(pair.query.labels)) == {0} and set(np.unique(pair.target.labels)) == {0}
    assert pair.shared > 10 and pair.shared < min(len(pair.query), len(pair.target))
    r = true_residuals(pair)
    # two noisy copies (0.3 m per axis each) plus a little drift
    assert 0.3 < np.median(r) < 1.2
    assert rotation_angle_deg(pair.T_target_query[:3, :3]) > 5.0  # the robots' frames differ
    spurious = (pair.query_truth < 0).mean()
    assert 0.0 < spurious < 0.15


def test_forest_generators_are_deterministic_by_seed():
    a, b = (forest_pair(np.random.default_rng(5)) for _ in range(2))
    c = forest_pair(np.random.default_rng(6))
    assert np.array_equal(a.query.positions, b.query.positions)
    assert np.array_equal(a.T_target_query, b.T_target_query)
    assert not np.array_equal(a.query.positions[:5], c.query.positions[:5])
    s1, s2 = (forest_scan(np.random.default_rng(7)) for _ in range(2))
    assert np.array_equal(s1.target.positions, s2.target.positions)


def test_forest_scan_is_a_local_view_with_its_truth():
    cfg = ForestConfig()
    scan = forest_scan(np.random.default_rng(8), cfg, scan_radius=20.0)
    assert np.linalg.norm(scan.query.positions[:, :2], axis=1).max() < 20.0 + 4 * cfg.noise
    assert scan.shared >= 0.5 * (scan.query_truth >= 0).sum()
    assert np.median(true_residuals(scan)) < 1.2


def test_forest_negative_shares_nothing():
    neg = forest_negative(np.random.default_rng(9))
    assert neg.shared == 0 and len(neg.query) > 50 and len(neg.target) > 50


def test_room_layout_counts_gaps_and_classes():
    rng = np.random.default_rng(10)
    for n in (20, 40, 60):
        pos, lab = make_room(rng, 10.0, 8.0, n)
        assert len(pos) == n
        assert np.all((pos[:, 0] > 0) & (pos[:, 0] < 10) & (pos[:, 1] > 0) & (pos[:, 1] < 8))
        d, _ = cKDTree(pos[:, :2]).query(pos[:, :2], k=2)
        assert d[:, 1].min() >= MIN_GAP - 1e-9
        assert len(np.unique(lab)) >= 4 and lab.max() < len(FURNITURE_CLASSES)


def test_room_pair_overlap_and_noise():
    cfg = RoomConfig()
    for seed in range(5):
        pair = room_pair(np.random.default_rng(seed), cfg)
        assert 0 < pair.shared <= min(len(pair.query), len(pair.target))
        assert np.median(true_residuals(pair)) < 4 * cfg.noise
        assert cfg.objects[0] * 0.3 <= len(pair.query) <= cfg.objects[1] * 1.2


def test_floor_rooms_and_repeated_offices():
    floor = make_floor(np.random.default_rng(11), n_rooms=6, repeated=3)
    assert set(np.unique(floor.room)) == {-1, 0, 1, 2, 3, 4, 5}
    local = [floor.positions[floor.room == r, :2] - floor.origins[r] for r in range(6)]
    assert np.allclose(local[0], local[1]) and np.allclose(local[0], local[2])  # identical
    assert len(local[3]) != len(local[0]) or not np.allclose(local[3], local[0])


def test_floor_pair_shares_one_column_of_rooms():
    pair = floor_pair(np.random.default_rng(12), n_rooms=8)
    assert 10 < pair.shared < min(len(pair.query), len(pair.target))
    assert np.median(true_residuals(pair)) < 0.2
    with pytest.raises(ValueError, match="n_rooms"):
        floor_pair(np.random.default_rng(0), n_rooms=4)


def test_repeated_room_negative_is_one_office_of_identical_ones():
    pair = repeated_room_pair(np.random.default_rng(13), n_rooms=6)
    assert pair.info["ambiguous"]
    # the query holds (at most) one office: its objects span one room, not the floor
    extent = np.ptp(pair.query.positions[:, :2], axis=0).max()
    assert extent < 16.0 and len(pair.target) > 4 * len(pair.query)
