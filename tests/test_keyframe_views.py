"""The keyframe back-end's viewpoint correction (objects seen from one side lie closer to the
sensor than their centres) and its odometry noise for densely spaced keyframes."""

import numpy as np
import pytest

from sgloc import lie
from sgloc.online import OdometryNoise, OnlineConfig
from sgloc.online.keyframes.colocation import colocation_factors
from sgloc.online.keyframes.views import view_corrected, view_offset
from sgloc.online.robot_map import RobotMap
from sgloc.pipeline.config import LocalizerConfig

#: Objects on both sides of a street along x (every 3 m from x = 20 to 41), class by side.
OBJECTS = np.array([[x, y, 1.0] for x in range(20, 42, 3) for y in (-5.0, 5.0)])
LABELS = (OBJECTS[:, 1] > 0).astype(np.int64)


def _drive(name: str, xs: np.ndarray, offset: float, reach: float = 20.0,
           scale: float = 0.0) -> RobotMap:
    """A robot driving along x through `xs` (its odometry frame = the world, its odometry's
    travel too long by the fraction `scale`), seeing every object within `reach` metres at
    `offset` metres short of its centre along the ray."""
    m = RobotMap(name, 1.5, 2, 20.0)
    for k, x in enumerate(xs):
        T = np.eye(4)
        T[0, 3] = x
        rel = OBJECTS - T[:3, 3]
        dist = np.linalg.norm(rel, axis=1)
        seen = dist < reach
        p = rel[seen] * (1.0 - offset / dist[seen, None])
        T[0, 3] = xs[0] + (1.0 + scale) * (x - xs[0])
        m.add(float(k), T, p, LABELS[seen])
    return m


def test_the_view_offset_is_measured_on_the_maps_and_corrected_away():
    """Sightings `offset` short of the centre: the offset comes back from the scatter of each
    object's sightings along their rays, and the corrected objects are the true centres."""
    m = _drive("a", np.arange(0.0, 60.0, 1.0), 0.3)
    assert view_offset([m]) == pytest.approx(0.3, abs=1e-9)
    keep = m.builder.counts >= m.min_observations
    seen_from_behind = np.linalg.norm(m.builder.positions[keep] - OBJECTS, axis=1)
    assert seen_from_behind.max() > 0.1  # the map's own objects are off
    np.testing.assert_allclose(view_corrected(m, view_offset([m]))[keep], OBJECTS, atol=1e-9)
    exact = _drive("b", np.arange(0.0, 60.0, 1.0), 0.0)
    assert view_offset([exact]) == pytest.approx(0.0, abs=1e-9)
    assert view_offset([_drive("c", np.arange(0.0, 60.0, 1.0), -0.2)]) == 0.0  # never < 0


def test_the_view_offset_is_not_confused_with_an_odometry_scale_error():
    """Odometry 2 % too long moves an object's sightings from ahead against those from behind
    along the street, as an offset would: the offset is measured across it, and stays."""
    for offset in (0.0, 0.3):
        m = _drive("a", np.arange(0.0, 60.0, 1.0), offset, scale=0.02)
        assert view_offset([m]) == pytest.approx(offset, abs=0.02)


def test_robots_that_saw_the_objects_from_opposite_sides_are_not_pulled_apart():
    """One robot arrives where the other set off: it saw the objects ahead, the other saw
    them behind. The co-location factor between them, fitted on the map's objects, is off
    along the street by about twice the offset; corrected for it, it is right."""
    a = _drive("a", np.arange(-10.0, 31.0, 1.0), 0.4)
    b = _drive("b", np.arange(30.0, 71.0, 1.0), 0.4)
    motion = LocalizerConfig().motion
    errors = {}
    for corrected in (False, True):
        factors = colocation_factors([a, b], {0: np.eye(4), 1: np.eye(4)}, motion, 1.0, 25.0,
                                     corrected)
        assert factors
        errors[corrected] = max(
            np.linalg.norm(lie.between(f.T_a_b, lie.between(a.anchors()[f.k_a],
                                                            b.anchors()[f.k_b]))[:3, 3])
            for f in factors)
    assert errors[False] > 0.3
    assert errors[True] < 0.05


def test_dense_odometry_steps_add_up_to_the_per_metre_error_of_a_stretch():
    """Per-metre errors are systematic: steps over correlation_length metres add up to the
    per-metre error there whatever the keyframe spacing; with correlation_length 0 each step
    stands alone and denser keyframes make a stiffer chain."""
    n = OdometryNoise(translation_per_metre=0.01, rotation_per_metre=0.01,
                      rotation_per_sqrt_metre=0.0, translation_floor=1e-9, rotation_floor=1e-9,
                      correlation_length=100.0)
    for step in (0.5, 2.0, 10.0, 100.0):
        C = n.covariance(np.stack([lie.se3_exp([0, 0, 0, step, 0, 0])] * int(100 / step)))
        assert np.sqrt(C[:, 3, 3].sum()) == pytest.approx(1.0, rel=1e-6)  # 1 % of 100 m
        assert np.sqrt(C[:, 2, 2].sum()) == pytest.approx(np.radians(1.0), rel=1e-6)
    C = n.covariance(lie.se3_exp([0, 0, 0, 300.0, 0, 0]))  # a step beyond it: 1 % of it
    assert np.sqrt(C[3, 3]) == pytest.approx(3.0, rel=1e-6)
    alone = OdometryNoise(translation_per_metre=0.01, translation_floor=1e-9,
                          correlation_length=0.0)
    C = alone.covariance(np.stack([lie.se3_exp([0, 0, 0, 1.0, 0, 0])] * 100))
    assert np.sqrt(C[:, 3, 3].sum()) == pytest.approx(0.1, rel=1e-6)  # 1 / sqrt(100) of it


def test_settings_saved_before_the_view_correction_keep_their_behaviour():
    saved = OnlineConfig(backend="keyframes").to_dict()
    del saved["view_correction"]
    del saved["odometry"]["correlation_length"]
    old = OnlineConfig.from_dict(saved)
    assert old.view_correction is False and old.odometry.correlation_length == 0.0
    new = OnlineConfig.from_dict(OnlineConfig(backend="keyframes").to_dict())
    assert new == OnlineConfig(backend="keyframes")
    assert new.view_correction and new.odometry.correlation_length == 100.0
