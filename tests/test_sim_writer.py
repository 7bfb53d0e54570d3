"""A synthetic run written in the Airsim layout reads back through the `airsim` loader."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.datasets import make_dataset
from sgloc.errors import DatasetError
from sgloc.sim import QUERY, ROBOT_NAMES, TARGET, make_synthetic_run, read_ground_truth
from sgloc.sim.airsim_writer import depth_to_png, png_to_depth, semantic_to_rgb

STEP_M = 100.0 / 255.0  # one 8-bit depth step


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    run = make_synthetic_run(seed=11, overlap=0.5, width=64, height=36, length=24.0, step=3.0)
    run_dir = run.write(tmp_path_factory.mktemp("run"))
    return run, run_dir


def test_layout_and_files(written):
    run, run_dir = written
    assert (run_dir / "ground_truth.txt").is_file() and (run_dir / "run.json").is_file()
    for robot in ROBOT_NAMES:
        d = run_dir / robot
        n = run.n_frames(robot)
        assert int((d / "airsim.txt").read_text().split()[0]) == n
        assert len(list((d / "depth").glob("depth_*.png"))) == n
        assert len(list((d / "segmentation").glob("segmentation_*.png"))) == n
        assert (d / "intrinsics.txt").read_text().split() == ["32", "32", "32", "18", "64", "36"]
        first_pose = (d / "airsim.txt").read_text().splitlines()[1].split()
        np.testing.assert_allclose([float(v) for v in first_pose], [0, 0, 0, 1, 0, 0, 0])


@pytest.mark.parametrize("robot", ROBOT_NAMES)
def test_round_trip_through_the_airsim_loader(written, robot):
    run, run_dir = written
    ds = make_dataset("airsim", run_dir, robot=robot)
    rendered = list(run.frames(robot))
    loaded = list(ds.frames())
    assert len(loaded) == len(rendered) == run.n_frames(robot)
    for a, b in zip(rendered, loaded, strict=True):
        np.testing.assert_allclose(b.T_map_sensor, a.T_map_sensor, atol=1e-5)
        np.testing.assert_allclose(b.K, a.K)
        np.testing.assert_array_equal(b.semantic, a.semantic)
        near = np.isfinite(a.depth) & (a.depth < 99.0)
        assert near.any()
        np.testing.assert_allclose(b.depth[near], a.depth[near], atol=STEP_M / 2 + 1e-9)
        assert np.all(b.depth[~np.isfinite(a.depth)] == pytest.approx(100.0))
    np.testing.assert_allclose(ds.poses, np.stack([f.T_map_sensor for f in rendered]), atol=1e-5)


def test_ground_truth_file(written):
    run, run_dir = written
    np.testing.assert_allclose(read_ground_truth(run_dir), run.ground_truth, atol=1e-8)
    # it maps B's start frame into A's: consistent with the world poses of both starts
    T_wa = run.routes.start_pose(TARGET)
    T_wb = run.routes.start_pose(QUERY)
    np.testing.assert_allclose(T_wa @ read_ground_truth(run_dir), T_wb, atol=1e-6)


def test_missing_ground_truth_is_a_clear_error(tmp_path):
    with pytest.raises(DatasetError, match="ground_truth.txt"):
        read_ground_truth(tmp_path)
    (tmp_path / "ground_truth.txt").write_text("1 2 3\n")
    with pytest.raises(DatasetError, match="4 rows of 4"):
        read_ground_truth(tmp_path)


def test_depth_and_colour_encodings():
    d = np.array([[0.0, 50.0, 99.9], [np.inf, 150.0, np.nan]])
    px = depth_to_png(d)
    assert px.dtype == np.uint8
    np.testing.assert_array_equal(px, [[0, 128, 255], [255, 255, 255]])
    np.testing.assert_allclose(png_to_depth(px[0, :2]), [0.0, 128 / 255 * 100])
    rgb = semantic_to_rgb(np.array([[-1, 0, 10]]))
    np.testing.assert_array_equal(rgb[0, 0], [0, 0, 0])
    np.testing.assert_array_equal(rgb[0, 1], [175, 6, 140])
    np.testing.assert_array_equal(rgb[0, 2], [112, 105, 191])
    with pytest.raises(DatasetError):
        semantic_to_rgb(np.array([[11]]))
