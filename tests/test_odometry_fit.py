"""The odometry's noise fitted to the loops of the links (`OdometryNoise.fit`,
`sgloc.online.odometry_fit`): exact odometry gets the smallest factor, drifting odometry a
factor that grows with its drift; in a session the fit is an event, kept by save and resume,
and keeps exact odometry straighter than the model as given."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc import lie
from sgloc.evaluation.fleet_metrics import odometry_bend
from sgloc.online import Link, OdometryNoise, OnlineConfig, OnlineSession
from sgloc.online.keyframe_consistency import Chains
from sgloc.online.keyframe_solve import gtsam_available
from sgloc.online.odometry_fit import FACTORS, scaled, variance_factor
from sgloc.sim.drift import drift_poses


def _line(n: int, y: float, step: float = 4.0) -> np.ndarray:
    P = np.repeat(np.eye(4)[None], n, 0)
    P[:, 0, 3], P[:, 1, 3] = step * np.arange(n), y
    return P


def _fitted(level: float, seed: int, n: int = 100, every: int = 5) -> float:
    """The factor fitted to links every `every` keyframes between two robots driving side by
    side for 4 n metres, robot b's odometry drifting at `level`, the links' errors drawn from
    their covariance (0.1 m, 0.6 deg)."""
    rng = np.random.default_rng(seed)
    truth = {0: _line(n, 0.0), 1: _line(n, 5.0)}
    odom = {0: truth[0], 1: drift_poses(truth[1], level, rng)}
    cov = np.diag([1e-4] * 3 + [1e-2] * 3)
    links = [Link("a", "b", lie.between(truth[0][k], truth[1][k])
                  @ lie.se3_exp(rng.multivariate_normal(np.zeros(6), cov)), cov, 0.99, float(k),
                  n_matches=10, keyframe_a=k, keyframe_b=k) for k in range(0, n, every)]
    travelled = {r: np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(P[:, :3, 3], axis=0), axis=1))]
                 for r, P in odom.items()}
    chains = Chains({"a": 0, "b": 1}, odom, travelled, OdometryNoise())
    return variance_factor(links, list(range(len(links))), chains)


def test_exact_odometry_gets_the_smallest_factors_and_drift_a_growing_one():
    fits = {lv: [_fitted(lv, seed) for seed in range(4)] for lv in (0.0, 1.0, 4.0)}
    assert max(fits[0.0]) <= FACTORS[2]  # 1/64 of the drift variances as given, or less
    assert min(fits[1.0]) > max(fits[0.0])
    # level 4 drifts four times as much as level 1: about 16 times the variance
    assert min(fits[4.0]) >= 4 * max(fits[1.0])
    assert 0.25 <= np.median(fits[4.0]) <= 4.0  # level 4 is about the model as given


def test_no_loop_keeps_the_model_as_given():
    chains = Chains({"a": 0}, {0: _line(5, 0.0)}, {0: np.arange(5) * 4.0}, OdometryNoise())
    assert variance_factor([], [], chains) == 1.0
    noise = OdometryNoise()
    assert scaled(noise, 1.0) == noise
    s = scaled(noise, 0.25)
    assert s.translation_per_metre == pytest.approx(0.5 * noise.translation_per_metre)
    assert s.translation_floor == noise.translation_floor


@pytest.mark.skipif(not gtsam_available(), reason="gtsam not installed")
def test_a_session_fits_its_odometry_emits_it_and_resumes_with_it(tmp_path):
    from test_keyframe_session import _drive

    a, _ = _drive(7, (0.0, 300.0), 0.0)  # exact odometry, one street driven twice
    rng = np.random.default_rng(8)
    b = [(t, T, p + rng.normal(0.0, 0.2, p.shape), lab) for t, T, p, lab in a]
    bends = {}
    for fit in (False, True):
        s = OnlineSession(online=OnlineConfig(min_observations=1, growth_objects=3,
                                              odometry=OdometryNoise(fit=fit)))
        for fa, fb in zip(a, b, strict=True):
            s.add_keyframe("a", *fa)
            s.add_keyframe("b", *fb)
        s.finish("a")
        s.finish("b")
        fitted = [e for e in s.events if e.kind == "odometry_fitted"]
        assert bool(fitted) == fit
        bends[fit] = max(odometry_bend(s.trajectory(r)[1], np.array([f[1] for f in frames])
                                       ).max() for r, frames in (("a", a), ("b", b)))
    assert s._kf.noise_factor < 1.0
    resumed = OnlineSession.load(s.save(tmp_path / "s.npz"))
    assert resumed._kf.noise_factor == s._kf.noise_factor
    assert resumed._kf.graph.noise == s._kf.graph.noise
    assert bends[True] < min(0.05, 0.5 * bends[False])  # exact odometry kept straight
