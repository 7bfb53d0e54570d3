"""Weighted Kabsch, RANSAC and ICP."""

import numpy as np
import pytest

from sgloc.errors import DegenerateGeometryError
from sgloc.estimation import (
    RansacConfig,
    anisotropic_fit,
    class_scales,
    draw_triplets,
    icp_refine,
    irls_refine,
    ransac,
    rigid_from_triplets,
    squared_residuals,
    tilt_deg,
    weighted_kabsch,
    yaw_fit,
)
from sgloc.geometry import apply, invert, make_transform, random_rigid_transform, transform_error


def test_kabsch_recovers_exact_transform(rng):
    T = random_rigid_transform(rng)
    src = rng.uniform(-50, 50, (10, 3))
    est = weighted_kabsch(src, apply(T, src))
    np.testing.assert_allclose(est, T, atol=1e-9)


def test_kabsch_never_returns_a_reflection(rng):
    # Planar points mirrored through their plane: the best orthogonal fit is a reflection;
    # the guard must return a proper rotation.
    src = np.column_stack([rng.uniform(-10, 10, (8, 2)), np.zeros(8)])
    dst = src * np.array([1.0, 1.0, -1.0]) + rng.normal(0, 0.01, (8, 3))
    src[:, 2] += rng.normal(0, 0.5, 8)
    R = weighted_kabsch(src, dst)[:3, :3]
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)


def test_weights_pull_the_fit(rng):
    src = rng.uniform(-20, 20, (6, 3))
    dst = src.copy()
    dst[0] += [3.0, 0, 0]  # one pair disagrees by 3 m
    light = weighted_kabsch(src, dst)
    heavy = weighted_kabsch(src, dst, weights=np.array([100.0, 1, 1, 1, 1, 1]))
    res_light = np.linalg.norm(apply(light, src[:1]) - dst[:1])
    res_heavy = np.linalg.norm(apply(heavy, src[:1]) - dst[:1])
    assert res_heavy < 0.2 * res_light


def test_kabsch_degenerate_inputs():
    with pytest.raises(DegenerateGeometryError, match="at least 3"):
        weighted_kabsch(np.zeros((2, 3)), np.zeros((2, 3)))
    line = np.outer(np.arange(6.0), [1.0, 2.0, 0.5])
    with pytest.raises(DegenerateGeometryError, match="collinear"):
        weighted_kabsch(line, line + 1.0)


def test_triplet_hypotheses_and_residuals(rng):
    T = random_rigid_transform(rng)
    s = rng.normal(0, 10, (50, 3, 3))
    R, t = rigid_from_triplets(s, s @ T[:3, :3].T + T[:3, 3])
    np.testing.assert_allclose(R, np.broadcast_to(T[:3, :3], R.shape), atol=1e-9)
    src = rng.normal(0, 20, (30, 3))
    dst = rng.normal(0, 20, (30, 3))
    ref = np.sum((np.einsum("bij,mj->bmi", R, src) + t[:, None] - dst) ** 2, axis=2)
    np.testing.assert_allclose(squared_residuals(R, t, src, dst), ref, rtol=1e-9, atol=1e-8)


def test_triplets_are_distinct(rng):
    tr = draw_triplets(4, 5000, rng)
    assert np.all((tr[:, 0] != tr[:, 1]) & (tr[:, 1] != tr[:, 2]) & (tr[:, 0] != tr[:, 2]))
    assert tr.min() == 0 and tr.max() == 3


@pytest.mark.parametrize("scoring", ["count", "msac"])
def test_ransac_with_outliers(rng, scoring):
    T = random_rigid_transform(rng)
    src = rng.uniform(-100, 100, (200, 3))
    dst = apply(T, src) + rng.normal(0, 0.5, src.shape)
    out = rng.choice(200, 140, replace=False)  # 70 % outliers
    dst[out] = rng.uniform(-300, 300, (140, 3))
    res = ransac(src, dst, RansacConfig(threshold=3.0, scoring=scoring), rng)
    te, re = transform_error(res.transform, T)
    assert te < 1.0 and re < 0.5
    inl = np.setdiff1d(np.arange(200), out)
    assert len(np.intersect1d(res.inliers, inl)) >= 0.95 * len(inl)


def test_ransac_acceptance_rule(rng):
    T = random_rigid_transform(rng)
    src = rng.uniform(-100, 100, (4, 3))
    res = ransac(src, apply(T, src), RansacConfig(), rng)  # 4 inliers < 5
    assert res.transform is None and "at least 5" in res.reason
    res = ransac(src[:2], src[:2], RansacConfig(), rng)
    assert res.transform is None and "at least 3" in res.reason


def test_ransac_collinear_matches(rng):
    line = np.outer(np.linspace(0, 100, 20), [1.0, 0.5, 0.0])
    res = ransac(line, line + 5.0, RansacConfig(dof=6), rng)
    assert res.transform is None and "collinear" in res.reason
    # With gravity fixing roll and pitch (dof=4) a horizontal line fixes the yaw...
    res = ransac(line, line + 5.0, RansacConfig(dof=4), rng)
    np.testing.assert_allclose(res.transform, make_transform(np.eye(3), np.full(3, 5.0)), atol=1e-9)
    # ...a vertical one does not.
    pole = np.outer(np.linspace(0, 30, 20), [0.0, 0.0, 1.0])
    assert ransac(pole, pole + 5.0, RansacConfig(dof=4), rng).transform is None


def test_icp_refines_a_perturbed_estimate(rng):
    src = rng.uniform(-80, 80, (150, 3))
    labels = rng.integers(0, 4, 150)
    T = random_rigid_transform(rng)
    dst = apply(T, src) + rng.normal(0, 0.1, src.shape)
    perturb = random_rigid_transform(rng, max_translation=1.5, max_roll_pitch_deg=0.5)
    perturb[:3, :3] = np.eye(3)
    start = perturb @ T
    refined = icp_refine(src, labels, dst, labels, start, max_distance=5.0)
    assert transform_error(refined, T)[0] < 0.1 < transform_error(start, T)[0]
    assert np.allclose(invert(refined) @ refined, np.eye(4))


def _yaw_motion(yaw_deg: float, t=(30.0, -12.0, 1.5)) -> np.ndarray:
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return make_transform(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.array(t))


def test_yaw_fit_and_dof4_ransac_recover_an_exact_yaw_motion(rng):
    src = rng.uniform(-60, 60, (40, 3)) * [1, 1, 0.1]
    T = _yaw_motion(137.0)
    np.testing.assert_allclose(yaw_fit(src, apply(T, src)), T, atol=1e-9)
    dst = apply(T, src)
    dst[:15] = rng.uniform(-60, 60, (15, 3))  # outliers
    res = ransac(src, dst, RansacConfig(dof=4, max_tilt=None), rng)
    np.testing.assert_allclose(res.transform, T, atol=1e-9)
    assert set(range(15, 40)) <= set(res.inliers.tolist())
    assert tilt_deg(res.transform[:3, :3]) == 0.0


def test_tilt_gate_refuses_upside_down_hypotheses(rng):
    src = rng.uniform(-60, 60, (30, 3)) * [1, 1, 0.2]
    flip = make_transform(np.diag([1.0, -1.0, -1.0]), np.zeros(3))  # upside down
    dst = apply(flip, src)
    assert tilt_deg(flip[:3, :3]) == 180.0
    free = ransac(src, dst, RansacConfig(dof=6, max_tilt=None), rng)
    np.testing.assert_allclose(free.transform, flip, atol=1e-9)
    gated = ransac(src, dst, RansacConfig(dof=6, max_tilt=15.0), rng)
    assert gated.transform is None and "max_tilt" in gated.reason


def test_class_scales_and_anisotropic_fit(rng):
    """Class 0 has precise heights, class 1 heights off by metres (a building's centre moves
    with the viewpoint): with per-class, per-axis scales the tilt comes from class 0."""
    n = 60
    src = rng.uniform(-80, 80, (n, 3)) * [1, 1, 0.05]
    classes = np.repeat([0, 1], n // 2)
    T = _yaw_motion(40.0)
    dst = apply(T, src)
    dst[:, :2] += rng.normal(0, 1.0, (n, 2))
    dst[:, 2] += np.where(classes == 0, rng.normal(0, 0.02, n), rng.normal(0, 3.0, n))
    d = apply(T, src) - dst
    s_xy, s_z = class_scales(d, classes, 1.4826 * np.median(np.linalg.norm(d, axis=1)))
    assert np.all(s_z[classes == 1] > 20 * s_z[classes == 0])
    assert np.allclose(s_xy[classes == 0], s_xy[classes == 0][0])  # one scale per class
    # Exact data: the Gauss-Newton fit returns the exact transform from a perturbed start.
    start = T @ _yaw_motion(2.0, (1.0, -1.0, 0.3))
    exact = anisotropic_fit(src, apply(T, src), start, np.ones(n), np.ones(n))
    np.testing.assert_allclose(exact, T, atol=1e-8)
    plain = irls_refine(src, dst, weighted_kabsch(src, dst))
    per_class = irls_refine(src, dst, weighted_kabsch(src, dst), classes=classes)
    assert tilt_deg((per_class @ invert(T))[:3, :3]) < 0.5 * tilt_deg((plain @ invert(T))[:3, :3])


def _tilted(T: np.ndarray, roll_deg: float) -> np.ndarray:
    """T followed by a roll about x of `roll_deg` degrees."""
    a = np.radians(roll_deg)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    return make_transform(Rx, np.zeros(3)) @ T


def test_anisotropic_fit_under_the_ground_vehicle_model(rng):
    """dof=4 with a tilt tolerance fits roll and pitch too, as `fit_rigid` does (the maps may
    disagree about gravity by up to max_tilt); without one it keeps T's tilt; a step beyond
    the tolerance is not taken."""
    src = rng.uniform(-80, 80, (40, 3)) * [1, 1, 0.05]
    T = _tilted(_yaw_motion(25.0), 2.0)
    dst, ones = apply(T, src), np.ones(len(src))
    start = _yaw_motion(24.0, (29.0, -11.0, 1.0))
    tol = anisotropic_fit(src, dst, start, ones, ones, dof=4, max_tilt=15.0, steps=10)
    np.testing.assert_allclose(tol, T, atol=1e-8)
    yaw_only = anisotropic_fit(src, dst, start, ones, ones, dof=4, max_tilt=None, steps=10)
    assert tilt_deg(yaw_only[:3, :3]) == pytest.approx(0.0, abs=1e-9)
    gated = anisotropic_fit(src, dst, start, ones, ones, dof=4, max_tilt=1.0, steps=10)
    assert tilt_deg(gated[:3, :3]) <= 1.0


def test_height_class_scales_share_one_horizontal_scale(rng):
    d = rng.normal(0, 1.0, (40, 3)) * np.repeat([[1, 1, 0.05], [3, 3, 2.0]], 20, axis=0)
    classes = np.repeat([0, 1], 20)
    sigma = 1.4826 * np.median(np.linalg.norm(d, axis=1))
    full_xy, full_z = class_scales(d, classes, sigma, "full")
    h_xy, h_z = class_scales(d, classes, sigma, "height")
    np.testing.assert_array_equal(h_z, full_z)
    assert np.ptp(h_xy) == 0.0 and full_xy[-1] > 2 * full_xy[0]
    all_xy = 1.4826 * np.median(np.linalg.norm(d[:, :2], axis=1) / np.sqrt(2.0))
    assert h_xy[0] == pytest.approx(all_xy)
    with pytest.raises(ValueError, match="axes"):
        class_scales(d, classes, sigma, "xy")


@pytest.mark.parametrize("axes", ["height", "full"])
def test_class_scaled_refit_takes_the_tilt_from_precise_heights(rng, axes):
    """Maps that disagree about gravity by 3 deg (within max_tilt): heights of class 1 off by
    metres (tall objects), class 0's precise. The gravity-bound refit with per-class scales
    takes the tilt from class 0; the isotropic one is pulled by class 1."""
    n = 80
    src = rng.uniform(-80, 80, (n, 3)) * [1, 1, 0.05]
    classes = np.repeat([0, 1], n // 2)
    T = _tilted(_yaw_motion(40.0), 3.0)
    dst = apply(T, src)
    dst[:, :2] += rng.normal(0, 1.0, (n, 2))
    dst[:, 2] += np.where(classes == 0, rng.normal(0, 0.02, n), rng.normal(0, 3.0, n))
    start = weighted_kabsch(src, dst)
    kw = {"dof": 4, "max_tilt": 15.0}
    plain = irls_refine(src, dst, start, **kw)
    scaled = irls_refine(src, dst, start, classes=classes, class_axes=axes, **kw)
    err = [transform_error(E, T)[1] for E in (plain, scaled)]
    assert err[1] < 0.5 * err[0]
