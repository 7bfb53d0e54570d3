"""The odometry noise the links show (`OnlineConfig.odometry_scale`): the maximum-likelihood
scale follows the drift the loops carry, stays within [MIN_SCALE, 1], needs MIN_LOOPS loops;
the scaled model keeps its floors; the graph's odometry factors follow it; a saved session
keeps it."""

import numpy as np

from sgloc import lie
from sgloc.online import OnlineConfig
from sgloc.online.config import OdometryNoise
from sgloc.online.keyframes.graph import ODOMETRY, KeyframeGraph
from sgloc.online.keyframes.noise import MIN_LOOPS, MIN_SCALE, fit_scale
from sgloc.online.keyframes.state import KeyframeState


def _loops(true_scale, n=200, seed=0):
    rng = np.random.default_rng(seed)
    var_link = np.full(n, np.radians(0.3) ** 2)
    var_odo = np.radians(rng.uniform(0.05, 2.0, n)) ** 2
    e = rng.standard_normal(n) * np.sqrt(var_link + true_scale * var_odo)
    return e, var_link, var_odo


def test_the_fit_follows_the_drift_the_loops_carry():
    for true in (0.02, 0.1, 0.5):
        s = fit_scale(*_loops(true))
        assert true / 2.5 <= s <= true * 2.5, (true, s)
    assert fit_scale(*_loops(0.0)) <= 5 * MIN_SCALE  # exact odometry: held nearly rigid
    assert fit_scale(*_loops(4.0)) == 1.0  # never looser than the model as given


def test_too_few_loops_keep_the_model():
    e, a, b = _loops(0.01)
    assert fit_scale(e[:MIN_LOOPS - 1], a[:MIN_LOOPS - 1], b[:MIN_LOOPS - 1]) == 1.0


def test_the_scaled_model_keeps_its_floors_and_the_graph_follows():
    noise = OdometryNoise()
    half = noise.scaled(0.25)
    assert half.translation_per_metre == noise.translation_per_metre * 0.5
    assert half.translation_floor == noise.translation_floor
    assert noise.scaled(1.0) == noise
    g = KeyframeGraph(noise, "scipy")
    for k in range(4):
        g.add_keyframe(0, lie.se3_exp([0, 0, 0, 10.0 * k, 0, 0]))
    g.set_noise(half)
    odo = [f for f in g.factors().values() if f.kind == ODOMETRY]
    assert len(odo) == 3
    assert np.allclose(odo[0].covariance, half.covariance(odo[0].T_a_b))


def test_a_saved_backend_keeps_its_scale():
    b = KeyframeState(OnlineConfig(solver="scipy"))
    b.graph.add_keyframe(0, np.eye(4))
    b.odometry_scale = 0.1
    meta, arrays = b.state()
    again = KeyframeState.from_state(b.online, meta, arrays)
    assert again.odometry_scale == 0.1
    assert again.graph.noise == b.online.odometry.scaled(0.1)
    saved = OnlineConfig().to_dict()
    del saved["odometry_scale"]
    assert OnlineConfig.from_dict(saved).odometry_scale is False
