"""The refined KITTI 00 trajectory: a pose graph making the raw poses agree with the refined
revisit transforms while keeping their consecutive motions."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.errors import SglocError
from sgloc.evaluation.kitti_refined import (
    invert_all,
    refine_trajectory,
    refinement_figures,
    rotation_angles_deg,
    step_changes,
)
from sgloc.evaluation.replay_scenarios import kitti_scenario
from sgloc.geometry import make_transform

pytest.importorskip("gtsam")


def _loop(n: int, drift_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(true, drifted) poses (n,4,4) of a circle of radius 50 m driven twice; the drifted one
    turns `drift_deg` more per step (a slow heading drift, as raw poses have)."""
    from scipy.spatial.transform import Rotation

    def track(extra: float) -> np.ndarray:
        yaw = np.cumsum(np.full(n, 4 * np.pi / n + np.radians(extra)))
        step = 4 * np.pi * 50.0 / n
        T = [np.eye(4)]
        for k in range(1, n):
            Rk = Rotation.from_euler("z", yaw[k - 1]).as_matrix()
            T.append(make_transform(Rk, T[-1][:3, 3] + Rk @ np.array([step, 0.0, 0.0])))
        return np.stack(T)

    return track(0.0), track(drift_deg)


def test_refined_loop_agrees_with_exact_revisits_and_keeps_steps() -> None:
    true, drifted = _loop(400, 0.01)
    pairs = np.array([(i, i + 200) for i in range(0, 200, 10)])
    M = np.einsum("nij,njk->nik", invert_all(true[pairs[:, 1]]), true[pairs[:, 0]])

    def revisit_error(T: np.ndarray) -> np.ndarray:
        D = invert_all(T[pairs[:, 1]]) @ T[pairs[:, 0]] @ invert_all(M)
        return np.linalg.norm(D[:, :3, 3], axis=1)

    refined = refine_trajectory(drifted, pairs, M)
    raw_err, ref_err = revisit_error(drifted), revisit_error(refined)
    assert np.median(raw_err) > 1.0  # the drift leaves the passes metres apart
    assert np.median(ref_err) < 0.1 * np.median(raw_err)
    dm, dd = step_changes(drifted, refined)
    assert dm.max() < 0.05 and dd.max() < 0.05  # each step moved by cm, hundredths of a degree
    np.testing.assert_allclose(refined[0], drifted[0], atol=1e-9)
    np.testing.assert_array_equal(refined, refine_trajectory(drifted, pairs, M))


def test_rotation_angles_of_nearly_orthonormal_matrices() -> None:
    R = np.eye(3) + 3e-7  # orthonormal to ~3e-7, as KITTI's raw rotations
    assert rotation_angles_deg(R[None])[0] < 1e-4
    Rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(rotation_angles_deg(Rz[None]), [90.0])


def test_kitti_scenario_names_a_bad_pose_choice() -> None:
    with pytest.raises(SglocError, match="raw' or 'refined"):
        kitti_scenario(4, poses="smoothed")


def test_refined_kitti_trajectory_reduces_revisit_disagreement(kitti_dir) -> None:
    f = refinement_figures(str(kitti_dir))
    # True same-class object pairs at the revisits: the raw poses leave them ~0.9 m apart.
    assert f["object_pairs"] > 5000
    assert f["refined_median_m"] < 0.5 * f["raw_median_m"]
    assert f["refined_p90_m"] < f["raw_p90_m"]
    # Revisits left out of the fit agree better too (not only the factors it was fitted to).
    assert f["held_out_refined_median_m"] < 0.6 * f["held_out_raw_median_m"]
    # Consecutive relative motions barely change: at most 3 cm / 0.03 deg per scan.
    assert f["step_max_m"] < 0.03 and f["step_max_deg"] < 0.03


def test_kitti_scenario_with_refined_poses_uses_them_as_odometry_and_truth(kitti_dir) -> None:
    from sgloc.evaluation.kitti_refined import kitti_refined_poses
    from sgloc.evaluation.pairs_kitti import kitti_sequence

    raw, ref = kitti_sequence(str(kitti_dir))[0], kitti_refined_poses(str(kitti_dir))
    sc = kitti_scenario(2, 1000, 1099, poses="refined")
    np.testing.assert_allclose(sc.T_gt_odom["kitti1"], ref[1050])
    assert np.abs(ref[1050][:3, 3] - raw[1050][:3, 3]).max() > 0.05  # not the raw pose
    log = sc.logs[1]  # odometry: the refined poses relative to the robot's first scan
    np.testing.assert_allclose(log.poses[-1], invert_all(ref[1050:1051])[0] @ ref[1099],
                               atol=1e-6)
    assert "refined poses" in sc.note
