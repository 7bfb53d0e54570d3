"""Airsim runs in Guo et al.'s layout (also what `sgloc.sim` writes).

One folder per robot:
    airsim.txt                      first line N, then N rows `x y z qw qx qy qz` = T_map_body
                                    (body axes x forward, y right, z down)
    intrinsics.txt                  optional, one line `fx fy cx cy [width height]`;
                                    absent = Guo's 1024x576, fx = fy = 512, cx = 512, cy = 288
    depth/depth_{i}.png             8-bit planar depth, metres = px / 255 * 100
    segmentation/segmentation_{i}.png   RGB; class k = sgloc.maps.classes.AIRSIM_COLORS[k],
                                    any other colour = no class (-1)
The optical frame (x right, y down, z forward) is the body frame with axes reordered: an
optical point (X, Y, Z) is (Z, X, Y) in the body frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.datasets.base import (
    Dataset,
    Frame,
    intrinsics_matrix,
    parse_range,
    read_image,
)
from sgloc.errors import DatasetError
from sgloc.io.text import read_numbers, read_text_file
from sgloc.maps.classes import AIRSIM_COLORS, colors_to_labels

#: Columns of R_body_optical are the optical axes in body coordinates.
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
GUO_INTRINSICS = (512.0, 512.0, 512.0, 288.0)
#: metres per 8-bit depth step.
DEPTH_SCALE = 100.0 / 255.0


def find_robot_folder(path: Path, robot: str | None) -> Path:
    """The robot folder holding airsim.txt: `path` itself or `path/robot`."""
    path = Path(path)
    if robot is None and (path / "airsim.txt").is_file():
        return path
    if robot is not None:
        if (path / robot / "airsim.txt").is_file():
            return path / robot
        if path.name == robot and (path / "airsim.txt").is_file():
            return path
        raise DatasetError(f"{path / robot / 'airsim.txt'}: missing Airsim pose file.")
    if not path.is_dir():
        raise DatasetError(f"{path}: no such Airsim run folder.")
    robots = sorted(p.name for p in path.iterdir() if (p / "airsim.txt").is_file())
    if len(robots) == 1:
        return path / robots[0]
    if robots:
        raise DatasetError(f"{path} holds several robots {robots}; choose one with --robot NAME "
                           "(Python: robot=NAME).")
    raise DatasetError(f"{path / 'airsim.txt'}: missing Airsim pose file (no robot folder found).")


def read_airsim_poses(path: Path) -> np.ndarray:
    """(N,4,4) T_map_body from an airsim.txt (first line N, rows x y z qw qx qy qz)."""
    text = read_text_file(path, "Airsim pose file (first line N, then rows x y z qw qx qy qz)")
    lines = [s.strip() for s in text.splitlines() if s.strip()]
    try:
        n = int(float(lines[0].split()[0]))
    except (IndexError, ValueError):
        raise DatasetError(f"{path}:1: the first line must be the number of frames N.") from None
    rows = lines[1:]
    if len(rows) < n:
        raise DatasetError(f"{path}: header says {n} frames but only {len(rows)} pose rows follow.")
    try:
        vals = np.array([[float(v) for v in r.split()] for r in rows[:n]])
    except ValueError:
        raise DatasetError(f"{path}: non-numeric value in the pose rows.") from None
    if vals.ndim != 2 or vals.shape[1] != 7:
        raise DatasetError(f"{path}: pose rows must have 7 values `x y z qw qx qy qz`.")
    q = vals[:, 3:7]
    norms = np.linalg.norm(q, axis=1)
    if not np.all(np.isfinite(vals)) or np.any(norms < 1e-9):
        raise DatasetError(f"{path}: NaN values or zero quaternions in the pose rows.")
    from scipy.spatial.transform import Rotation  # deferred: scipy.spatial loads in ~0.2 s

    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.from_quat(q[:, [1, 2, 3, 0]] / norms[:, None]).as_matrix()
    T[:, :3, 3] = vals[:, :3]
    return T


def read_airsim_intrinsics(folder: Path) -> np.ndarray:
    """K from `folder/intrinsics.txt` (`fx fy cx cy [width height]`), else Guo's camera."""
    p = folder / "intrinsics.txt"
    if not p.is_file():
        return intrinsics_matrix(*GUO_INTRINSICS)
    vals = read_numbers(p, "Airsim intrinsics (fx fy cx cy width height)").ravel()
    if vals.size not in (4, 6) or vals[0] <= 0 or vals[1] <= 0:
        raise DatasetError(f"{p}: expected one line `fx fy cx cy width height` with fx, fy > 0.")
    return intrinsics_matrix(*vals[:4])


class AirsimDataset(Dataset):
    """A robot's Airsim run (Guo's layout).

    Args:
        path: the robot folder, or a run folder holding robot folders (then pass `robot`).
        robot: robot folder name, e.g. "forwardCar" or "backwardCar".
        frames: frame range, (first, last) inclusive or "first-last"; None = all.
        colors: (C,3) class colour table (default the 11 Airsim colours).
        depth_scale: metres per depth PNG step (default 100/255).
    """

    name = "airsim"
    n_classes = len(AIRSIM_COLORS)

    def __init__(
        self,
        path: str | Path,
        robot: str | None = None,
        frames: tuple[int, int] | str | None = None,
        colors: np.ndarray = AIRSIM_COLORS,
        depth_scale: float = DEPTH_SCALE,
    ) -> None:
        self.folder = find_robot_folder(Path(path), robot)
        self.robot = self.folder.name
        T_map_body = read_airsim_poses(self.folder / "airsim.txt")
        self.indices = parse_range(frames, len(T_map_body), "frames")
        T_body_optical = np.eye(4)
        T_body_optical[:3, :3] = R_BODY_OPTICAL
        self.poses = T_map_body[self.indices] @ T_body_optical
        self.K = read_airsim_intrinsics(self.folder)
        self.colors = np.asarray(colors)
        self.depth_scale = float(depth_scale)

    def _load(self, i: int) -> Frame:
        k = int(self.indices[i])
        dp = self.folder / "depth" / f"depth_{k}.png"
        sp = self.folder / "segmentation" / f"segmentation_{k}.png"
        depth = read_image(dp, f"depth image of frame {k}")
        seg = read_image(sp, f"segmentation image of frame {k}")
        if depth.ndim == 3:
            depth = depth[..., 0]
        if seg.ndim == 2:
            semantic = seg.astype(np.int64)  # already class ids
        elif seg.ndim == 3 and seg.shape[2] >= 3:
            semantic = colors_to_labels(seg[..., :3], self.colors)
        else:
            raise DatasetError(f"{sp}: segmentation must be an RGB image, got shape {seg.shape}.")
        if semantic.shape != depth.shape:
            raise DatasetError(
                f"frame {k}: segmentation {semantic.shape} and depth {depth.shape} differ in size."
            )
        return Frame(
            index=k,
            T_map_sensor=self.poses[i],
            semantic=semantic,
            depth=depth.astype(np.float64) * self.depth_scale,
            K=self.K,
        )

    def __repr__(self) -> str:
        return f"AirsimDataset(robot={self.robot!r}, frames={len(self)}, folder={self.folder})"
