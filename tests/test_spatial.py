"""sgloc.maps.spatial.ClassKDTree: the nearest same-class point, never one of another class."""

from __future__ import annotations

import numpy as np

from sgloc.maps.spatial import ClassKDTree


def _brute(points, labels, tpos, tlab, scale, upper):
    d = np.linalg.norm((points[:, None] - tpos[None]) * scale, axis=2)
    d[labels[:, None] != tlab[None]] = np.inf
    j = d.argmin(axis=1)
    best = d[np.arange(len(points)), j]
    return np.where(best <= upper, best, np.inf), np.where(best <= upper, j, len(tpos))


def test_nearest_same_class_matches_brute_force():
    rng = np.random.default_rng(3)
    tpos, tlab = rng.uniform(-50, 50, (200, 3)), rng.integers(0, 4, 200)
    pts, lab = rng.uniform(-60, 60, (300, 3)), rng.integers(0, 4, 300)
    scale = (1.0, 1.0, 0.25)
    tree = ClassKDTree(tpos, tlab, 8.0, extent=60.0, scale=scale)
    d, j = tree.query(pts, lab, 8.0)
    d_ref, j_ref = _brute(pts, lab, tpos, tlab, np.array(scale), 8.0)
    assert np.array_equal(np.isfinite(d), np.isfinite(d_ref)) and np.isfinite(d).any()
    assert np.allclose(d[np.isfinite(d)], d_ref[np.isfinite(d_ref)])
    assert np.array_equal(j, j_ref)
    # Batched points (..., n, 3) give the same answers row by row.
    d2, _ = tree.query(np.stack([pts, pts]), lab, 8.0)
    assert np.array_equal(d2[1], d)


def test_pairs_stay_within_a_class():
    pos = np.array([[0.0, 0, 0], [0.5, 0, 0], [0.2, 0, 0], [9.0, 0, 0]])
    lab = np.array([0, 1, 0, 0])
    pairs = ClassKDTree(pos, lab, 1.0).pairs(1.0)
    assert sorted(map(tuple, pairs.tolist())) == [(0, 2)]
