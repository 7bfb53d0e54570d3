"""sgloc.lie against gtsam's Pose3 (the convention it promises) and its own identities."""

import numpy as np
import pytest

from sgloc import lie


def _random_xi(rng, n, scale=1.0):
    xi = rng.normal(size=(n, 6)) * scale
    xi[:, :3] = xi[:, :3] / np.maximum(1.0, np.linalg.norm(xi[:, :3], axis=1, keepdims=True))
    return xi


def test_exp_log_round_trip_batched_and_single():
    rng = np.random.default_rng(0)
    xi = np.vstack([_random_xi(rng, 50), np.zeros((1, 6)), [[1e-9, 0, 0, 1, 2, 3]]])
    T = lie.se3_exp(xi)
    assert T.shape == (52, 4, 4)
    np.testing.assert_allclose(lie.se3_log(T), xi, atol=1e-9)
    np.testing.assert_allclose(lie.se3_exp(xi[3]), T[3], atol=1e-12)
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-12)


def test_adjoint_moves_a_perturbation_across():
    rng = np.random.default_rng(1)
    T = lie.se3_exp(_random_xi(rng, 1, 3.0)[0])
    xi = _random_xi(rng, 1, 0.3)[0]
    np.testing.assert_allclose(T @ lie.se3_exp(xi), lie.se3_exp(lie.adjoint(T) @ xi) @ T,
                               atol=1e-12)


def test_skew_is_the_cross_product_and_between_is_the_relative_pose():
    rng = np.random.default_rng(2)
    v, u = rng.normal(size=(2, 3))
    np.testing.assert_allclose(lie.skew(v) @ u, np.cross(v, u))
    A, B = lie.se3_exp(_random_xi(rng, 2, 2.0))
    np.testing.assert_allclose(lie.between(A, B), np.linalg.inv(A) @ B, atol=1e-12)
    np.testing.assert_allclose(lie.compose(A, B, A), A @ B @ A)
    d = _random_xi(rng, 1, 1e-4)[0]
    np.testing.assert_allclose(lie.retract(A, d), A @ lie.se3_exp(d), atol=1e-12)


def test_matches_gtsam_pose3():
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(3)
    for xi in _random_xi(rng, 10, 2.0):
        np.testing.assert_allclose(lie.se3_exp(xi), gtsam.Pose3.Expmap(xi).matrix(), atol=1e-10)
        T = lie.se3_exp(xi)
        np.testing.assert_allclose(lie.se3_log(T), gtsam.Pose3.Logmap(gtsam.Pose3(T)), atol=1e-9)
        np.testing.assert_allclose(lie.adjoint(T), gtsam.Pose3(T).AdjointMap(), atol=1e-10)
        d = _random_xi(rng, 1, 0.5)[0]
        np.testing.assert_allclose(lie.retract(T, d), gtsam.Pose3(T).retract(d).matrix(),
                                   atol=1e-10)


def test_right_jacobian_inverse_is_the_derivative_of_log():
    rng = np.random.default_rng(3)
    xi = _random_xi(rng, 1, 0.3)[0]
    J = lie.se3_right_jacobian_inv(xi)
    eps = 1e-6
    num = np.stack([(lie.se3_log(lie.se3_exp(xi) @ lie.se3_exp(eps * e))
                     - lie.se3_log(lie.se3_exp(xi) @ lie.se3_exp(-eps * e))) / (2 * eps)
                    for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(J, num, atol=1e-6)
    np.testing.assert_allclose(lie.se3_ad(xi) @ xi, np.zeros(6), atol=1e-15)


def test_product_chart_keeps_rotation_and_translation_apart():
    rng = np.random.default_rng(4)
    d = _random_xi(rng, 20, 2.0)
    T = lie.product_exp(d)
    assert T.shape == (20, 4, 4)
    np.testing.assert_allclose(T[:, :3, :3], lie.so3_exp(d[:, :3]), atol=0)
    np.testing.assert_array_equal(T[:, :3, 3], d[:, 3:])
    np.testing.assert_allclose(lie.product_log(T), d, atol=1e-9)
    np.testing.assert_array_equal(lie.product_exp(d[5]), T[5])


def test_axis_rotation_is_exp_of_the_scaled_axis():
    rng = np.random.default_rng(5)
    axis = rng.normal(size=3)
    angle = np.concatenate([[0.0], rng.uniform(-3, 3, size=30)])
    R = lie.axis_rotation(2.0 * axis, angle)
    omega = angle[:, None] * axis / np.linalg.norm(axis)
    np.testing.assert_allclose(R, lie.so3_exp(omega), atol=1e-12)
    np.testing.assert_array_equal(R[0], np.eye(3))  # angle 0: the identity, bit for bit
