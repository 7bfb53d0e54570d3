"""Dataset loaders on small fixtures written in each format, and their errors."""

from __future__ import annotations

import io
import tarfile
import types

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from sgloc.datasets import DATASETS, make_dataset
from sgloc.datasets.kitti_objects import TR_KITTI_00
from sgloc.errors import DatasetError, UnknownNameError
from sgloc.extraction import ExtractionConfig, build_graph
from sgloc.geometry import make_transform
from sgloc.io.poses import read_kitti_poses, read_tum_poses, write_kitti_poses, write_tum_poses
from sgloc.maps.classes import AIRSIM_COLORS


def _save(path, array):
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)


# -- airsim -----------------------------------------------------------------------------------
W, H, F = 64, 36, 32.0  # fx = fy = 32, cx = 32, cy = 18


def _write_airsim_robot(folder, poses_xyzq, intrinsics=True):
    """A robot folder: frame i sees a class-2 block at 10 m in the image centre."""
    folder.mkdir(parents=True)
    rows = [" ".join(f"{v:.9f}" for v in r) for r in poses_xyzq]
    (folder / "airsim.txt").write_text(f"{len(rows)}\n" + "\n".join(rows) + "\n")
    if intrinsics:
        (folder / "intrinsics.txt").write_text(f"{F} {F} {W / 2} {H / 2} {W} {H}\n")
    for i in range(len(rows)):
        seg = np.zeros((H, W, 3), np.uint8)
        seg[14:23, 28:37] = AIRSIM_COLORS[2]
        seg[0:4, 0:4] = (1, 2, 3)  # a colour of no class
        depth = np.full((H, W), 255, np.uint8)
        depth[14:23, 28:37] = round(10.0 / 100 * 255)  # 10 m (26 -> 10.196 m)
        _save(folder / "depth" / f"depth_{i}.png", depth)
        _save(folder / "segmentation" / f"segmentation_{i}.png", seg)


def test_airsim_loader_axes_intrinsics_and_lazy_frames(tmp_path):
    yaw = Rotation.from_euler("z", 90, degrees=True).as_quat()  # x, y, z, w
    poses = [(0, 0, 0, 1, 0, 0, 0), (5, 0, 0, yaw[3], yaw[0], yaw[1], yaw[2])]
    _write_airsim_robot(tmp_path / "run" / "forwardCar", poses)
    ds = make_dataset("airsim", tmp_path / "run", robot="forwardCar")
    assert len(ds) == 2 and ds.poses.shape == (2, 4, 4)
    np.testing.assert_allclose(ds.K, [[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    # optical z (forward) is body x; optical x (right) is body y; optical y (down) is body z
    np.testing.assert_allclose(ds.poses[0][:3, :3] @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(ds.poses[0][:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(ds.poses[0][:3, :3] @ [0, 1, 0], [0, 0, 1], atol=1e-12)
    frames = ds.frames()
    f0 = next(frames)
    assert f0.semantic.shape == (H, W) and f0.semantic[18, 32] == 2 and f0.semantic[0, 0] == -1
    assert f0.semantic[30, 5] == -1
    np.testing.assert_allclose(f0.depth[18, 32], 26 / 255 * 100)
    # the block is straight ahead: frame 0 puts it 10.2 m along map x, frame 1 (turned left
    # 90 deg at x = 5) 10.2 m along map y
    cfg = ExtractionConfig(min_pixels=1)
    g0 = build_graph([f0], cfg)
    np.testing.assert_allclose(g0.positions[0], [26 / 255 * 100, 0, 0], atol=0.7)
    g1 = build_graph([ds[1]], cfg)
    np.testing.assert_allclose(g1.positions[0], [5, 26 / 255 * 100, 0], atol=0.7)
    # the robot folder itself works too, and a frame range
    ds2 = make_dataset("airsim", tmp_path / "run" / "forwardCar", frames="1-1")
    assert len(ds2) == 1 and ds2[0].index == 1


def test_airsim_default_intrinsics_and_robot_choice(tmp_path):
    _write_airsim_robot(tmp_path / "run" / "a", [(0, 0, 0, 1, 0, 0, 0)], intrinsics=False)
    _write_airsim_robot(tmp_path / "run" / "b", [(0, 0, 0, 1, 0, 0, 0)])
    ds = make_dataset("airsim", tmp_path / "run" / "a")
    np.testing.assert_allclose(ds.K, [[512, 0, 512], [0, 512, 288], [0, 0, 1]])
    with pytest.raises(DatasetError, match="several robots"):
        make_dataset("airsim", tmp_path / "run")


def test_airsim_errors_name_the_file(tmp_path):
    robot = tmp_path / "r"
    _write_airsim_robot(robot, [(0, 0, 0, 1, 0, 0, 0), (1, 0, 0, 1, 0, 0, 0)])
    (robot / "depth" / "depth_1.png").unlink()
    ds = make_dataset("airsim", robot)  # frames are read lazily: no error yet
    ds[0]
    with pytest.raises(DatasetError, match="depth_1.png"):
        ds[1]
    (robot / "airsim.txt").write_text("3\n0 0 0 1 0 0 0\n")
    with pytest.raises(DatasetError, match="airsim.txt.*3 frames"):
        make_dataset("airsim", robot)
    (robot / "airsim.txt").write_text("1\n0 0 0 1 0 0\n")
    with pytest.raises(DatasetError, match="7 values"):
        make_dataset("airsim", robot)
    (robot / "airsim.txt").write_text("1\n0 0 0 1 0 0 0\n")
    (robot / "segmentation" / "segmentation_0.png").write_bytes(b"not a png")
    with pytest.raises(DatasetError, match="segmentation_0.png"):
        make_dataset("airsim", robot)[0]
    with pytest.raises(DatasetError, match="nowhere: no such Airsim run folder"):
        make_dataset("airsim", tmp_path / "nowhere")
    with pytest.raises(DatasetError, match="backwardCar/airsim.txt"):
        make_dataset("airsim", tmp_path, robot="backwardCar")


# -- synthia ----------------------------------------------------------------------------------
def test_synthia_loader_column_major_pose_yz_flip_and_units(tmp_path):
    seq = tmp_path / "SYNTHIA-SEQS-04-SUMMER"
    T_raw = make_transform(Rotation.from_euler("y", 30, degrees=True).as_matrix(), [1, 2, 3])
    for cam in ("Omni_F", "Omni_B"):
        d = seq / "CameraParams" / "Stereo_Left" / cam
        d.mkdir(parents=True)
        for i in range(2):
            T = T_raw.copy()
            T[0, 3] += i
            (d / f"{i:06d}.txt").write_text(" ".join(f"{v:.9f}" for v in T.ravel(order="F")))
            lab = np.zeros((8, 10), np.uint8)
            lab[2:5, 2:6] = 8  # car
            lab[6:8, :] = 15  # beyond the 13 classes
            dep = np.full((8, 10), 2500, np.uint16)  # 25 m in cm
            _save(seq / "GT" / "LABELS" / "Stereo_Left" / cam / f"{i:06d}.png", lab)
            _save(seq / "Depth" / "Stereo_Left" / cam / f"{i:06d}.png", dep)
    (seq / "CameraParams" / "intrinsics.txt").write_text("5.0\n5.0\n4.0\n")
    ds = make_dataset("synthia", seq, camera="Omni_B")
    assert len(ds) == 2
    np.testing.assert_allclose(ds.poses[0], T_raw @ np.diag([1.0, -1, -1, 1]))
    np.testing.assert_allclose(ds.poses[1][:3, 3], [2, 2, 3])
    np.testing.assert_allclose(ds.K, [[5, 0, 5], [0, 5, 4], [0, 0, 1]])
    f = ds[0]
    assert f.semantic[3, 3] == 8 and f.semantic[0, 0] == -1 and f.semantic[7, 0] == -1
    np.testing.assert_allclose(f.depth, 25.0)
    local = make_dataset("synthia", seq, robot="Omni_F", start_frame=True)
    np.testing.assert_allclose(local.poses[0], np.eye(4), atol=1e-9)
    with pytest.raises(DatasetError, match="Omni_L"):
        make_dataset("synthia", seq, camera="Omni_L")
    (seq / "CameraParams" / "Stereo_Left" / "Omni_F" / "000001.txt").write_text("1 2 3")
    with pytest.raises(DatasetError, match="000001.txt.*16 values"):
        make_dataset("synthia", seq)


# -- kitti (images) ---------------------------------------------------------------------------
def test_kitti_loader_camera_offset_and_images(tmp_path):
    seq = tmp_path / "00"
    P = np.stack([make_transform(np.eye(3), [0, 0, z]) for z in (0.0, 1.0, 2.0)])
    write_kitti_poses(seq / "poses_00.txt", P)
    K = np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 1]])
    P2 = np.hstack([K, K @ np.array([[0.06], [0.0], [0.0]])])  # camera 2: 6 cm left of cam 0
    lines = [
        f"P{c}: " + " ".join(map(str, (P2 if c == 2 else np.hstack([K, np.zeros((3, 1))])).ravel()))
        for c in range(4)
    ]
    (seq / "calib.txt").write_text("\n".join(lines) + "\n")
    for i in range(3):
        sem = np.full((6, 8), 255, np.uint8)
        sem[1:3, 1:3] = 4
        dep = np.zeros((6, 8), np.uint16)
        dep[1:3, 1:3] = 12 * 256
        _save(seq / "semantic" / f"{i:06d}.png", sem)
        _save(seq / "depth" / f"{i:06d}.png", dep)
    ds = make_dataset("kitti", seq, frames="1-2")
    assert len(ds) == 2 and ds[0].index == 1
    np.testing.assert_allclose(ds.K, K)
    # T_map_cam2 = P_i @ T_cam0_cam2; camera 2's centre is at x = -0.06 in camera 0
    np.testing.assert_allclose(ds.poses[0][:3, 3], [-0.06, 0, 1.0], atol=1e-12)
    f = ds[1]
    assert f.semantic[1, 1] == 4 and f.semantic[0, 0] == -1
    assert f.depth[1, 1] == 12.0 and np.isnan(f.depth[0, 0])
    (seq / "poses_00.txt").write_text("1 0 0\n")
    with pytest.raises(DatasetError, match="poses_00.txt:1.*12 values"):
        make_dataset("kitti", seq)


# -- kitti objects ----------------------------------------------------------------------------
def _write_objects_archive(folder, scans, packed=True):
    """scans: list of (vehicles (a,3), trunks (b,3), poles (c,3))."""
    files = {"00/bow.txt": "".join(f"{len(v)},{len(t)},{len(p)}\n" for v, t, p in scans)}
    for i, groups in enumerate(scans):
        rows = np.concatenate([np.reshape(g, (-1, 3)) for g in groups])
        files[f"00/centroids/{i:06d}.txt"] = "".join(
            " ".join(f"{x:.6e}" for x in r) + "\n" for r in rows
        )
    folder.mkdir(parents=True, exist_ok=True)
    if packed:
        with tarfile.open(folder / "gosmatch_00_objects.tar.xz", "w:xz") as tf:
            for name, text in files.items():
                data = text.encode()
                info = tarfile.TarInfo(name)
                info.size = len(data)
                tf.addfile(info, io.BytesIO(data))
    else:
        for name, text in files.items():
            (folder / name).parent.mkdir(parents=True, exist_ok=True)
            (folder / name).write_text(text)


@pytest.mark.parametrize("packed", [True, False])
def test_kitti_objects_loader_labels_poses_start_frame(tmp_path, packed):
    P = np.stack(
        [
            make_transform(Rotation.from_euler("y", a, degrees=True).as_matrix(), [0, 0, z])
            for a, z in ((0, 0), (10, 2), (20, 4))
        ]
    )
    P = read_kitti_poses(write_kitti_poses(tmp_path / "poses_00.txt", P))  # as stored
    Tr = np.vstack([TR_KITTI_00, [0, 0, 0, 1]])
    # objects fixed in the sequence frame, seen from each scan's LiDAR frame
    car, car2, tree, pole = (
        np.array(p, float) for p in ([0, 1, 20], [0, 1, 30], [4, 0, 5], [-6, 0, 8])
    )

    def seen(i, *objs):
        return [(np.linalg.inv(P[i] @ Tr) @ np.append(o, 1))[:3] for o in objs]

    scans = [
        (seen(0, car), seen(0, tree), seen(0, pole)),
        (seen(1, car, car2), [], seen(1, pole)),
        ([], seen(2, tree), []),
    ]
    _write_objects_archive(tmp_path, scans, packed)
    ds = make_dataset("kitti_objects", tmp_path)
    assert len(ds) == 3 and ds.class_counts.tolist() == [[1, 1, 1], [2, 0, 1], [0, 1, 0]]
    f1 = ds[1]
    pts, labels = f1.detections
    assert labels.tolist() == [0, 0, 2]
    np.testing.assert_allclose(f1.T_map_sensor, P[1] @ Tr)
    # the same object seen from every scan lands in one place of the sequence frame
    g = build_graph(ds, ExtractionConfig(association_radius=1.0))
    assert sorted(g.labels.tolist()) == [0, 0, 1, 2]
    for obj, label in ((car, 0), (car2, 0), (tree, 1), (pole, 2)):
        d = np.linalg.norm(g.positions - obj, axis=1)
        assert d.min() < 1e-4 and g.labels[np.argmin(d)] == label
    # scan range and start frame: poses relative to the first selected scan's LiDAR frame
    local = make_dataset("kitti_objects", tmp_path, scans=(1, 2), start_frame=True)
    assert [f.index for f in local] == [1, 2]
    np.testing.assert_allclose(local.poses[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(local.poses[1], np.linalg.inv(P[1] @ Tr) @ P[2] @ Tr, atol=1e-12)


def test_kitti_objects_errors(tmp_path):
    with pytest.raises(DatasetError, match="gosmatch_00_objects.tar.xz"):
        make_dataset("kitti_objects", tmp_path)
    _write_objects_archive(tmp_path, [([[1, 2, 3]], [], [])] * 2)
    with pytest.raises(DatasetError, match="poses_00.txt"):
        make_dataset("kitti_objects", tmp_path)
    write_kitti_poses(tmp_path / "poses_00.txt", np.tile(np.eye(4), (3, 1, 1)))
    with pytest.raises(DatasetError, match="3 poses but .* 2 scans"):
        make_dataset("kitti_objects", tmp_path)
    write_kitti_poses(tmp_path / "poses_00.txt", np.tile(np.eye(4), (2, 1, 1)))
    with pytest.raises(DatasetError, match="outside 0-1"):
        make_dataset("kitti_objects", tmp_path, scans="0-5")
    with pytest.raises(DatasetError, match="malformed"):
        make_dataset("kitti_objects", tmp_path, scans="a-b")
    bad = tmp_path / "bad"
    _write_objects_archive(bad, [([[1, 2, 3]], [[1, 1, 1]], [])], packed=False)
    (bad / "00" / "bow.txt").write_text("2,1,0\n")
    write_kitti_poses(bad / "poses_00.txt", np.eye(4)[None])
    with pytest.raises(DatasetError, match="000000.txt.*3 objects"):
        make_dataset("kitti_objects", bad)[0]


# -- factory and pose files -------------------------------------------------------------------
def test_factory_by_name_and_bad_options(tmp_path):
    assert set(DATASETS) == {"airsim", "synthia", "kitti", "kitti_objects"}
    with pytest.raises(UnknownNameError, match="kitti_objects"):
        make_dataset("kitty", tmp_path)
    with pytest.raises(DatasetError, match="bad option"):
        make_dataset("kitti_objects", tmp_path, robot="A")
    assert isinstance(make_dataset, types.FunctionType)


def test_pose_files_round_trip(tmp_path, rng):
    T = np.stack(
        [
            make_transform(Rotation.random(random_state=k).as_matrix(), rng.normal(size=3))
            for k in range(4)
        ]
    )
    np.testing.assert_allclose(
        read_kitti_poses(write_kitti_poses(tmp_path / "k.txt", T)), T, atol=1e-8
    )
    t, T2 = read_tum_poses(write_tum_poses(tmp_path / "t.txt", np.arange(4.0), T))
    np.testing.assert_allclose(T2, T, atol=1e-8)
    np.testing.assert_allclose(t, np.arange(4.0))
    (tmp_path / "bad.txt").write_text("1 2 x\n")
    with pytest.raises(DatasetError, match="bad.txt:1"):
        read_kitti_poses(tmp_path / "bad.txt")
