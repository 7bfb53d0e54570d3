"""KITTI odometry with precomputed semantic and depth images (from networks of your choice).

Folder:
    poses_{seq}.txt or poses.txt    12 values a row: camera-0 pose P_i in the sequence frame
    calib.txt                       KITTI odometry calibration: lines `P0: ...` .. `P3: ...`
                                    (3x4 projections), `Tr: ...` (LiDAR to camera 0)
    semantic/NNNNNN.png             class ids, single channel 8- or 16-bit (`ignore_value` =
                                    no class); or colour images with a `colors` table
    depth/NNNNNN.png                16-bit planar depth, metres = px / 256 (KITTI depth
                                    benchmark convention), 0 = no depth
Images are of camera `camera` (default 2, the left colour camera). KITTI camera frames are
already optical (x right, y down, z forward): T_map_sensor = P_i @ T_cam0_camX.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.datasets.base import Dataset, Frame, parse_range, read_image
from sgloc.errors import DatasetError
from sgloc.geometry import invert
from sgloc.io.poses import read_kitti_poses
from sgloc.io.text import read_text_file
from sgloc.maps.classes import colors_to_labels


def read_kitti_calib(path: Path) -> dict[str, np.ndarray]:
    """{key: (3,4) matrix} from a KITTI odometry calib.txt (`P0: 12 values` lines)."""
    text = read_text_file(path, "KITTI calibration (lines `P0: ...`, `P2: ...`, `Tr: ...`)")
    out: dict[str, np.ndarray] = {}
    for lineno, line in enumerate(text.splitlines(), 1):
        if ":" not in line:
            continue
        key, rest = line.split(":", 1)
        try:
            vals = np.array([float(v) for v in rest.split()])
        except ValueError:
            raise DatasetError(f"{path}:{lineno}: non-numeric value in {key}.") from None
        if not np.all(np.isfinite(vals)):
            raise DatasetError(f"{path}:{lineno}: NaN or infinite value in {key}.")
        if vals.size != 12:
            raise DatasetError(f"{path}:{lineno}: {key} must have 12 values, got {vals.size}.")
        out[key.strip()] = vals.reshape(3, 4)
    return out


def camera_offset(P: np.ndarray) -> np.ndarray:
    """T_camX_cam0 (4x4) of a rectified KITTI camera with projection P = K [I | t]."""
    T = np.eye(4)
    T[:3, 3] = np.linalg.solve(P[:3, :3], P[:3, 3])
    return T


class KittiDataset(Dataset):
    """KITTI odometry image frames (semantic + depth precomputed).

    Args:
        path: the sequence folder (see the module docstring).
        camera: which rectified camera the images belong to (0-3, default 2).
        frames: frame range, (first, last) inclusive or "first-last"; None = all.
        start_frame: express poses relative to the first selected frame's camera.
        sequence: sequence number for the pose file name poses_{sequence}.txt.
        poses: pose file to use instead.
        semantic_dir, depth_dir: image folder names.
        depth_scale: metres per depth PNG step (default 1/256).
        ignore_value: semantic id meaning "no class" (default 255).
        colors: (C,3) colour table when the semantic images are colour-coded.
    """

    name = "kitti"

    def __init__(
        self,
        path: str | Path,
        camera: int = 2,
        frames: tuple[int, int] | str | None = None,
        start_frame: bool = False,
        sequence: str = "00",
        poses: str | Path | None = None,
        semantic_dir: str = "semantic",
        depth_dir: str = "depth",
        depth_scale: float = 1.0 / 256.0,
        ignore_value: int | None = 255,
        colors: np.ndarray | None = None,
    ) -> None:
        self.folder = Path(path)
        if not self.folder.is_dir():
            raise DatasetError(f"{self.folder}: no such KITTI sequence folder.")
        if poses is None:
            poses = self.folder / f"poses_{sequence}.txt"
            if not poses.is_file() and (self.folder / "poses.txt").is_file():
                poses = self.folder / "poses.txt"
        P = read_kitti_poses(Path(poses))
        calib = read_kitti_calib(self.folder / "calib.txt")
        key = f"P{int(camera)}"
        if key not in calib:
            raise DatasetError(f"{self.folder / 'calib.txt'}: no {key} line for camera {camera}.")
        self.K = calib[key][:3, :3].copy()
        self.indices = parse_range(frames, len(P), "frames")
        T = P[self.indices] @ invert(camera_offset(calib[key]))
        if start_frame:
            T = invert(T[0]) @ T
        self.poses = T
        self.semantic_dir = self.folder / semantic_dir
        self.depth_dir = self.folder / depth_dir
        self.depth_scale = float(depth_scale)
        self.ignore_value = ignore_value
        self.colors = None if colors is None else np.asarray(colors)

    def _load(self, i: int) -> Frame:
        k = int(self.indices[i])
        sem = read_image(self.semantic_dir / f"{k:06d}.png", f"semantic image of frame {k}")
        dep = read_image(self.depth_dir / f"{k:06d}.png", f"depth image of frame {k}")
        if sem.ndim == 3:
            if self.colors is None:
                raise DatasetError(
                    f"{self.semantic_dir / f'{k:06d}.png'}: colour semantic image; pass colors= "
                    "(the class colour table) or write single-channel class ids."
                )
            semantic = colors_to_labels(sem[..., :3], self.colors)
        else:
            semantic = sem.astype(np.int64)
            if self.ignore_value is not None:
                semantic[semantic == self.ignore_value] = -1
        if dep.ndim == 3:
            dep = dep[..., 0]
        if dep.shape != semantic.shape:
            raise DatasetError(
                f"frame {k}: semantic {semantic.shape} and depth {dep.shape} differ."
            )
        depth = dep.astype(np.float64) * self.depth_scale
        depth[dep == 0] = np.nan
        return Frame(index=k, T_map_sensor=self.poses[i], semantic=semantic, depth=depth, K=self.K)
