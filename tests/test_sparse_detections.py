"""A sparse one-class detector's view of a run (`sgloc.sim.detector.sparse_detections`): one
class within range, about the asked number per keyframe, depth error growing with range."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.errors import SglocError
from sgloc.io.keyframes import make_robot_log
from sgloc.sim.detector import sparse_detections


def _log(n_keyframes: int = 400, per_keyframe: int = 20, seed: int = 0):
    rng = np.random.default_rng(seed)
    m = n_keyframes * per_keyframe
    xyz = np.c_[np.arange(n_keyframes, dtype=float), np.zeros((n_keyframes, 2))]
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (n_keyframes, 1))
    kf = np.repeat(np.arange(n_keyframes), per_keyframe)
    pos = rng.uniform(-60, 60, (m, 3))
    lab = rng.integers(0, 3, m)
    return make_robot_log("r", np.arange(n_keyframes) * 10**8, xyz, quat, kf, pos, lab)


def test_one_class_within_range_about_three_per_keyframe():
    log = _log(per_keyframe=100)  # about 5 of class 1 within 40 m per keyframe
    out = sparse_detections(log, 1, np.random.default_rng(1))
    assert set(np.unique(out.labels)) == {1}
    assert len(out.labels) / len(log) == pytest.approx(3.0, rel=0.1)
    assert np.linalg.norm(out.positions, axis=1).max() < 40.0 * 1.1  # moved by <= ~4 sigma
    assert len(out) == len(log) and np.array_equal(out.xyz, log.xyz)


def test_the_depth_error_is_along_the_line_of_sight_and_grows_with_range():
    log = _log()
    out = sparse_detections(log, 1, np.random.default_rng(2), per_keyframe=100.0,
                            range_noise=0.02)
    near = (log.labels == 1) & (np.linalg.norm(log.positions, axis=1) < 40.0)
    before = log.positions[near]
    assert len(before) == len(out.positions)  # all kept: fewer than asked per keyframe
    r = np.linalg.norm(before, axis=1)
    moved = out.positions - before
    ray = before / r[:, None]
    along = np.einsum("ij,ij->i", moved, ray)
    np.testing.assert_allclose(moved, along[:, None] * ray, atol=1e-9)  # only along the ray
    assert np.std(along / r) == pytest.approx(0.02, rel=0.1)


def test_bad_settings_are_refused():
    with pytest.raises(SglocError, match="per_keyframe"):
        sparse_detections(_log(10, 2), 0, np.random.default_rng(0), per_keyframe=0)
