"""The paper's metrics on hand-made cases with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sgloc.evaluation.metrics import (
    correct_matches,
    is_failure,
    match_stats,
    pose_errors,
    recall_precision,
)
from sgloc.geometry import apply, make_transform

R30 = Rotation.from_euler("z", 30, degrees=True).as_matrix()
T_GT = make_transform(R30, np.array([100.0, -50.0, 2.0]))


def _maps() -> tuple[np.ndarray, np.ndarray]:
    """Six query objects; the target holds them under T_GT, plus offsets chosen per object:
    objects 0-3 exact, object 4 moved 9.5 m (still correct at T_p = 10), object 5 moved 10.5 m."""
    q = np.array([[0, 0, 0], [30, 0, 0], [0, 40, 0], [50, 50, 1], [80, 10, 0], [10, 90, 0.0]])
    t = apply(T_GT, q)
    t[4] += [9.5, 0, 0]
    t[5] += [0, 10.5, 0]
    return q, t


def test_correct_matches_uses_the_ground_truth_and_T_p():
    q, t = _maps()
    m = np.array([[0, 0], [1, 1], [4, 4], [5, 5], [0, 1], [2, 3]])
    ok = correct_matches(q, t, m, T_GT, tol=10.0)
    assert ok.tolist() == [True, True, True, False, False, False]
    # a tighter T_p drops the 9.5 m match; the identity as "ground truth" makes all wrong
    assert correct_matches(q, t, m, T_GT, tol=5.0).tolist() == [1, 1, 0, 0, 0, 0]
    assert not correct_matches(q, t, m, np.eye(4)).any()
    assert correct_matches(q, t, np.zeros((0, 2), int), T_GT).shape == (0,)


def test_recall_and_precision_of_a_known_match_set():
    q, t = _maps()
    candidates = np.array([[0, 0], [1, 1], [2, 2], [3, 3], [0, 1], [2, 3], [5, 5]])  # 4 correct
    survivors = np.array([[0, 0], [1, 1], [2, 2], [0, 1], [5, 5]])  # 3 correct of 5
    final = np.array([[0, 0], [1, 1], [0, 1]])  # 2 correct of 3
    st = match_stats(q, t, candidates, survivors, final, T_GT, tol=10.0)
    assert (st["n_candidates"], st["n_correct_candidates"]) == (7, 4)
    assert (st["n_survivors"], st["n_correct_survivors"]) == (5, 3)
    assert (st["n_final"], st["n_correct_final"]) == (3, 2)
    assert st["recall"] == pytest.approx(2 / 4)
    assert st["precision"] == pytest.approx(2 / 3)


def test_recall_precision_empty_sets_are_nan_not_zero_division():
    assert recall_precision(3, 4, 6) == pytest.approx((0.5, 0.75))
    r, p = recall_precision(0, 0, 5)
    assert r == 0.0 and math.isnan(p)
    r, p = recall_precision(0, 2, 0)
    assert math.isnan(r) and p == 0.0


def test_pose_errors_are_measured_in_the_target_frame():
    # An extra 3 m shift applied after the ground truth (in the target frame) -> 3 m, 0 deg.
    T_est = make_transform(np.eye(3), [0.0, 3.0, 0.0]) @ T_GT
    te, re = pose_errors(T_est, T_GT)
    assert te == pytest.approx(3.0) and re == pytest.approx(0.0, abs=1e-6)
    # A 10 deg rotation about the target origin: rotation error 10 deg, no translation error,
    # although the translation vectors of T_est and T_GT differ by ~19.5 m.
    Rz = make_transform(Rotation.from_euler("z", 10, degrees=True).as_matrix(), np.zeros(3))
    T_est = Rz @ T_GT
    te, re = pose_errors(T_est, T_GT)
    assert re == pytest.approx(10.0) and te == pytest.approx(0.0, abs=1e-9)
    assert np.linalg.norm(T_est[:3, 3] - T_GT[:3, 3]) > 19
    assert all(math.isnan(x) for x in pose_errors(None, T_GT))


def test_failure_is_error_above_20_m_or_not_localized():
    assert not is_failure(0.0)
    assert not is_failure(19.99)
    assert not is_failure(20.0)
    assert is_failure(20.01)
    assert is_failure(float("nan"))
    assert is_failure(5.0, failure_m=4.0)
