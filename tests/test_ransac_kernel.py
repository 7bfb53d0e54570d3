"""The compiled 4-dof RANSAC (sgloc.estimation.ransac_compiled) against the numpy reference:
same samples from the same generator, same inliers, same transform."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.estimation import RansacConfig, ransac_compiled, ransac_reference
from sgloc.geometry import make_transform


def ground_matches(m: int, outliers: float, seed: int, tilt_deg: float = 0.0):
    """(src, dst, T, good): m matches of the yaw-and-shift motion T (optionally tilted), a share
    of them wrong (good: which are right)."""
    rng = np.random.default_rng(seed)
    src = rng.uniform([-80, -80, 0], [80, 80, 10], (m, 3))
    yaw = rng.uniform(-np.pi, np.pi)
    c, s = np.cos(yaw), np.sin(yaw)
    T = make_transform(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), rng.uniform(-30, 30, 3))
    if tilt_deg:
        a = np.radians(tilt_deg)
        Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        T[:3, :3] = T[:3, :3] @ Rx
    dst = src @ T[:3, :3].T + T[:3, 3] + rng.normal(0, 0.3, (m, 3))
    bad = rng.random(m) < outliers
    dst[bad] = rng.uniform([-100, -100, 0], [100, 100, 10], (int(bad.sum()), 3))
    return src, dst, T, ~bad


def same(a, b) -> None:
    assert a.reason == b.reason
    assert np.array_equal(a.inliers, b.inliers)
    assert (a.transform is None) == (b.transform is None)
    if a.transform is not None:
        assert np.abs(a.transform - b.transform).max() < 1e-9


@pytest.mark.parametrize("outliers", [0.0, 0.5, 0.9])
@pytest.mark.parametrize("scoring", ["msac", "count"])
@pytest.mark.parametrize("max_tilt", [15.0, None])
def test_dof4_equals_numpy(outliers, scoring, max_tilt):
    cfg = RansacConfig(threshold=3.0, scoring=scoring, dof=4, max_tilt=max_tilt)
    for seed in range(6):
        tilt = 3.0 * (seed % 2)
        src, dst, T, good = ground_matches(150, outliers, seed, tilt_deg=tilt)
        w = np.random.default_rng(seed).uniform(0.5, 2.0, len(src)) if seed % 3 == 0 else None
        a = ransac_reference(src, dst, cfg, np.random.default_rng(seed), w)
        b = ransac_compiled(src, dst, cfg, np.random.default_rng(seed), w)
        same(a, b)
        _near_the_truth(b, T, good, tilt if max_tilt is None else 0.0)


def _near_the_truth(res, T, good, unmodelled_tilt: float) -> None:
    """The model found is the true motion: within 0.35 m / 0.25 deg (measured: at most 0.28 m
    / 0.21 deg, at 90 % outliers) with at most one wrong match among its inliers and no right
    one missed; a tilt the model cannot take (yaw only, no max_tilt) stays in the rotation
    error, and a third of the right matches then fall outside (measured 2.11 m / 3.00 deg)."""
    from sgloc.geometry import transform_error

    assert res.transform is not None
    te, re = transform_error(res.transform, T)
    inliers = np.zeros(len(good), bool)
    inliers[res.inliers] = True
    assert (inliers & ~good).sum() <= 1
    if unmodelled_tilt:
        assert te < 2.3 and abs(re - unmodelled_tilt) < 0.05, (te, re)
        assert (good & ~inliers).sum() < 0.35 * good.sum()
    else:
        assert te < 0.35 and re < 0.25, (te, re)
        assert (good & ~inliers).sum() == 0


def test_dof4_fixed_count_and_small_batches_equal_numpy():
    cfg = RansacConfig(dof=4, confidence=None, iterations=250, batch=7)
    src, dst, _, _ = ground_matches(40, 0.6, 3)
    same(ransac_reference(src, dst, cfg, np.random.default_rng(1)),
         ransac_compiled(src, dst, cfg, np.random.default_rng(1)))  # fmt: skip


def test_dof4_degenerate_inputs_as_numpy():
    cfg = RansacConfig(dof=4)
    stacked = np.zeros((6, 3))
    stacked[:, 2] = np.arange(6.0)  # one vertical line: no pair fixes a yaw
    line = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
    for src in (stacked, line, line[:2]):
        same(ransac_reference(src, src, cfg), ransac_compiled(src, src, cfg))


def test_gravity_gated_rigid_model_is_refused():
    src, dst, _, _ = ground_matches(20, 0.0, 0)
    with pytest.raises(ValueError, match="ransac_reference"):
        ransac_compiled(src, dst, RansacConfig(dof=6, max_tilt=15.0))


@pytest.mark.parametrize("max_tilt", [15.0, 2.0, None])
def test_compiled_ground_fits_equal_numpy(max_tilt):
    from sgloc.estimation import fit_kernels as fit
    from sgloc.estimation import fit_rigid, irls_refine

    for seed in range(8):
        src, dst, _, _ = ground_matches(60, 0.2, seed, tilt_deg=[0.0, 4.0][seed % 2])
        w = np.random.default_rng(seed).uniform(0.5, 2.0, len(src))
        mt = float(max_tilt or 0.0)
        ref = fit_rigid(src, dst, w, 4, max_tilt)
        assert np.abs(fit.fit_model(src, dst, w, 4, mt) - ref).max() < 1e-9
        ref_irls = irls_refine(src, dst, ref, w, dof=4, max_tilt=max_tilt)
        assert np.abs(fit.irls_model(src, dst, ref, w, 15, 4, mt) - ref_irls).max() < 1e-9
    line = np.column_stack([np.arange(10.0), 2 * np.arange(10.0), np.zeros(10)])
    assert fit.collinear(line, 1e-3) and not fit.collinear(src, 1e-3)
    assert np.abs(fit.fit_model(line, line + 1.0, np.ones(10), 4, 15.0)
                  - fit_rigid(line, line + 1.0, None, 4, 15.0)).max() < 1e-9  # fmt: skip
