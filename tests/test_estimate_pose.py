"""sgloc.estimation's shape: one estimate_pose for localize and register, the MotionModel handed
to every stage, one random stream per stage, compiled kernels that import nothing of sgloc."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

import sgloc
import sgloc.estimation.pose as pose_module
from sgloc.estimation import (
    ANY_RIGID,
    GROUND_VEHICLE,
    FinalFit,
    MotionModel,
    RansacConfig,
    estimate_pose,
    rot_z,
)
from sgloc.geometry import make_transform
from sgloc.maps.graph import SemanticGraph
from sgloc.pipeline.localizer import RANDOM_STAGES, localize, stage_streams
from sgloc.rejection import make_rejector
from sgloc.sim.correspondences import make_correspondences
from sgloc.validation import InvalidSettingError


def test_motion_model_is_frozen_and_checked():
    assert MotionModel() == GROUND_VEHICLE == RansacConfig().motion
    assert RansacConfig(dof=6, max_tilt=None).motion == ANY_RIGID
    assert MotionModel(4, 10).max_tilt == 10.0 and isinstance(MotionModel(4, 10).max_tilt, float)
    with pytest.raises(AttributeError):
        GROUND_VEHICLE.dof = 6  # type: ignore[misc]
    for bad in ({"dof": 5}, {"dof": True}, {"max_tilt": 0.0}, {"max_tilt": 200.0}):
        with pytest.raises(InvalidSettingError, match="setting (dof|max_tilt)"):
            MotionModel(**bad)


@pytest.mark.parametrize("refine", ["irls", "kabsch", "none"])
def test_register_is_estimate_pose(refine):
    """register = estimate_pose with the rejector and RANSAC settings it derives."""
    cs = make_correspondences(200, 0.7, np.random.default_rng(4), noise=0.3)
    got = sgloc.register(cs.src, cs.dst, noise_bound=1.0, seed=5, refine=refine)
    pose = estimate_pose(
        cs.src, cs.dst, make_rejector("neighbor", tau=2.0),
        RansacConfig(threshold=2.0, dof=6, max_tilt=None), np.random.default_rng(5),
        fit=FinalFit(refine=refine),
    )  # fmt: skip
    assert pose.transform is not None and got.success
    assert np.array_equal(got.transform, pose.transform)
    assert np.array_equal(got.inliers, pose.inliers)
    assert np.array_equal(got.survivors, pose.survivors)
    assert set(got.timings) == {"rejection", "ransac", "refine", "total"}


def test_register_takes_a_motion_model():
    """The motion model reaches RANSAC and the final fit: a ground vehicle's model gives a
    rotation about z only, like the flat settings dof=4, max_tilt=None."""
    yaw = make_transform(rot_z(np.array([0.8]))[0], np.array([10.0, -4.0, 1.0]))
    cs = make_correspondences(120, 0.3, np.random.default_rng(2), noise=0.2, T_dst_src=yaw)
    flat = sgloc.register(cs.src, cs.dst, noise_bound=1.0, dof=4, max_tilt=None)
    typed = sgloc.register(cs.src, cs.dst, noise_bound=1.0, motion=MotionModel(4, None))
    # (flat and typed settings build the same configuration: equal to 1e-9)
    assert np.abs(flat.transform - typed.transform).max() < 1e-9
    R = typed.transform[:3, :3]
    assert R[2, 2] == 1.0 and np.all(R[2, :2] == 0.0) and np.all(R[:2, 2] == 0.0)
    assert np.abs(typed.transform - yaw).max() < 0.5


def test_final_fit_refuses_a_tilt_the_matches_demand():
    """With dof=4 and max_tilt, matches that fit much better tilted than upright are refused
    (an upside-down map), with the reason naming max_tilt."""
    rng = np.random.default_rng(0)
    src = rng.uniform(-30, 30, (30, 3))
    flip = make_transform(np.diag([1.0, -1.0, -1.0]), np.zeros(3))
    dst = src @ flip[:3, :3].T
    T, reason = pose_module.final_fit(src, dst, GROUND_VEHICLE, threshold=5.0)
    assert T is None and "max_tilt" in reason
    T, reason = pose_module.final_fit(src, dst, ANY_RIGID, threshold=5.0)
    assert T is not None and np.allclose(T, flip) and not reason


def test_stage_streams_are_independent_and_reproducible():
    a, b = stage_streams(7), stage_streams(7)
    assert tuple(a) == RANDOM_STAGES
    draws = {k: g.integers(0, 2**62, 4).tolist() for k, g in a.items()}
    assert draws == {k: g.integers(0, 2**62, 4).tolist() for k, g in b.items()}
    assert len({tuple(v) for v in draws.values()}) == len(RANDOM_STAGES)
    g1, g2 = stage_streams(np.random.default_rng(7)), stage_streams(np.random.default_rng(7))
    assert g1["ransac"].random() == g2["ransac"].random()


def test_descriptor_draws_leave_ransac_samples_alone(monkeypatch):
    """Changing the random walks (n_walks) does not change the generator RANSAC draws from."""
    seen = []

    def spy(src, dst, config, rng, weights=None):
        seen.append(rng.bit_generator.state["state"]["state"])
        return real(src, dst, config, rng, weights)

    real = pose_module.ransac
    monkeypatch.setattr(pose_module, "ransac", spy)
    rng = np.random.default_rng(1)
    g = SemanticGraph(rng.uniform(0, 60, (40, 3)), rng.integers(0, 3, 40))
    for n_walks in (20, 40):
        localize(g, g, descriptor="random_walk", n_walks=n_walks, seed=3)
    assert len(seen) == 2 and seen[0] == seen[1]


def test_kernels_import_nothing_of_sgloc_but_kernels():
    """A kernel module holds compiled functions only: no import of another sgloc module than the
    kernels' runtime (`sgloc.kernels`) and other kernel modules."""
    from importlib.util import find_spec

    from sgloc import kernels

    for module in kernels.MODULES:
        path = Path(find_spec(module).origin)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                inside = name.startswith("sgloc.kernels") or name in kernels.MODULES
                assert inside or not name.startswith("sgloc"), f"{module} imports {name}"


def test_the_config_holds_the_motion_model_as_flat_settings(tmp_path):
    """dof= and max_tilt= stay the settings users write (flat, presets, config files); the
    config hands them on as one MotionModel."""
    from sgloc.pipeline.config import LocalizerConfig

    assert LocalizerConfig().motion == GROUND_VEHICLE
    flat = LocalizerConfig().with_overrides(dof=6, max_tilt=None)
    assert flat.motion == ANY_RIGID
    path = tmp_path / "c.yaml"
    path.write_text("ransac:\n  dof: 6\n  max_tilt: 5\n")
    assert LocalizerConfig.load(path).motion == MotionModel(6, 5.0)
    flat.save(tmp_path / "c.json")
    assert LocalizerConfig.load(tmp_path / "c.json").motion == ANY_RIGID
