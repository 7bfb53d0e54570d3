"""The rendered city written in SYNTHIA's layout reads back through the `synthia` loader and
runs as a pair source (column-major poses, the Y/Z flip, centimetre depth, SYNTHIA class ids)."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.datasets import make_dataset
from sgloc.datasets.synthia import SYNTHIA_CLASSES
from sgloc.evaluation.pairs import SynthiaPairs, make_pair_source
from sgloc.sim.run import QUERY, TARGET, make_synthetic_run
from sgloc.sim.synthia_writer import (
    city_to_synthia_ids,
    pose_values,
    synthia_depth_image,
    write_synthia_run,
)


@pytest.fixture(scope="module")
def synthia_run(tmp_path_factory):
    run = make_synthetic_run(seed=1, overlap=0.8, width=96, height=54, length=80.0)
    return run, write_synthia_run(run, tmp_path_factory.mktemp("synthia"))


def test_pose_file_is_column_major_with_y_and_z_flipped():
    T = np.eye(4)
    T[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = [1.0, 2.0, 3.0]
    v = pose_values(T)
    # column-major: the translation is the 4th column, values 12..14
    assert np.allclose(v[12:15], [1.0, 2.0, 3.0])
    # camera Y and Z axes are the optical ones negated
    F = v.reshape(4, 4, order="F")
    assert np.allclose(F[:3, 0], T[:3, 0])
    assert np.allclose(F[:3, 1], -T[:3, 1]) and np.allclose(F[:3, 2], -T[:3, 2])


def test_class_table_and_depth_encoding():
    ids = city_to_synthia_ids()
    names = [SYNTHIA_CLASSES[k] for k in ids]
    assert names[:4] == ["building", "vegetation", "pole", "car"]
    assert names[-1] == "void"  # bus stop: no SYNTHIA class
    d = synthia_depth_image(np.array([[1.234, np.inf, np.nan, 0.0]]))
    assert d.dtype == np.uint16 and d.tolist() == [[123, 0, 0, 0]]


def test_loader_reads_back_the_written_poses_and_images(synthia_run):
    run, seq = synthia_run
    for robot, camera in ((TARGET, "Omni_F"), (QUERY, "Omni_B")):
        ds = make_dataset("synthia", seq, camera=camera)
        frames = list(run.frames(robot))
        assert len(ds) == len(frames)
        T_world_map = run.routes.start_pose(robot)
        k = len(frames) // 2
        assert np.allclose(ds.poses[k], T_world_map @ frames[k].T_map_sensor, atol=1e-6)
        f = ds[k]
        want = frames[k].depth
        hit = np.isfinite(want) & (want < 600)
        assert np.allclose(f.depth[hit], want[hit], atol=0.006)
        assert np.all(np.isnan(f.depth[~np.isfinite(want)]))


def test_synthia_pair_source_ground_truth_aligns_the_two_maps(synthia_run):
    _, seq = synthia_run
    src = make_pair_source(str(seq))
    assert isinstance(src, SynthiaPairs)
    p = src(0)
    assert len(p.query) > 10 and len(p.target) > 10
    moved = p.query.positions @ p.T_target_query[:3, :3].T + p.T_target_query[:3, 3]
    d = np.linalg.norm(moved[:, None] - p.target.positions[None], axis=2)
    d[p.query.labels[:, None] != p.target.labels[None]] = np.inf
    near_gt = int((d.min(axis=1) < 3.0).sum())
    d0 = np.linalg.norm(p.query.positions[:, None] - p.target.positions[None], axis=2)
    d0[p.query.labels[:, None] != p.target.labels[None]] = np.inf
    assert near_gt >= 10 and near_gt > 3 * max(1, int((d0.min(axis=1) < 3.0).sum()))


def test_synthia_overlap_windows(synthia_run):
    _, seq = synthia_run
    src = SynthiaPairs(root=str(seq), overlap=0.5, length=20)
    a, b, ov = src.windows()
    assert a == (0, 19) and b[1] - b[0] == 19
    assert 0.0 <= ov <= 1.0
