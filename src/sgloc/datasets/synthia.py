"""SYNTHIA video sequences (e.g. SYNTHIA-SEQS-04-SUMMER), cameras Omni_F / Omni_B as two robots.

Folder (the official layout):
    CameraParams/intrinsics.txt                     focal length, cx, cy (first three numbers);
                                                    absent = 532.740352, 640, 380 (1280x760)
    CameraParams/Stereo_Left/Omni_F/NNNNNN.txt      16 values: the 4x4 world-from-camera pose,
                                                    column-major, camera axes with Y and Z flipped
                                                    against the optical frame (x right, y up,
                                                    z backward)
    Depth/Stereo_Left/Omni_F/NNNNNN.png             depth in centimetres (first channel)
    GT/LABELS/Stereo_Left/Omni_F/NNNNNN.png         class id in the first channel
    RGB/...                                         (not needed)
Class ids 1..12 are kept (13 classes with void 0: sky, building, road, sidewalk, fence,
vegetation, pole, car, sign, pedestrian, bicycle, lane marking); void and ids above 12 become
-1 (no class). Note: Pillow reads 16-bit multi-channel PNGs only as 8 bits; class ids and depth
in the first channel survive when they are below 256 / stored single-channel.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.datasets.base import Dataset, Frame, intrinsics_matrix, parse_range, read_image
from sgloc.errors import DatasetError
from sgloc.geometry import invert
from sgloc.io.text import read_numbers

SYNTHIA_CLASSES = (
    "void",
    "sky",
    "building",
    "road",
    "sidewalk",
    "fence",
    "vegetation",
    "pole",
    "car",
    "sign",
    "pedestrian",
    "bicycle",
    "lanemarking",
)
#: Classes that are not objects (for ExtractionConfig.ignore_classes).
SYNTHIA_STUFF_CLASSES = (1, 3, 4, 12)
SYNTHIA_INTRINSICS = (532.740352, 640.0, 380.0)
#: The optical frame from SYNTHIA's camera frame: flip Y and Z.
FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])


def read_synthia_pose(path: Path) -> np.ndarray:
    """T_world_camera (4x4) from one CameraParams file (16 values, column-major)."""
    vals = read_numbers(path, "SYNTHIA camera pose (16 values, column-major 4x4)").ravel()
    if vals.size != 16:
        raise DatasetError(f"{path}: expected 16 values (a column-major 4x4), got {vals.size}.")
    return vals.reshape(4, 4, order="F")


class SynthiaDataset(Dataset):
    """One SYNTHIA camera as a robot.

    Args:
        path: the sequence folder (holding CameraParams/, Depth/, GT/).
        camera: "Omni_F" (forward, robot A) or "Omni_B" (backward, robot B); also `robot=`.
        stereo: "Stereo_Left" or "Stereo_Right".
        frames: frame range, (first, last) inclusive or "first-last"; None = all.
        start_frame: express poses relative to the first selected frame's camera.
        depth_scale: metres per depth PNG step (default 0.01: centimetres).
        flip_yz: compose the Y/Z flip into the poses (True for the official files).
    """

    name = "synthia"
    n_classes = len(SYNTHIA_CLASSES)

    def __init__(
        self,
        path: str | Path,
        camera: str = "Omni_F",
        stereo: str = "Stereo_Left",
        frames: tuple[int, int] | str | None = None,
        start_frame: bool = False,
        depth_scale: float = 0.01,
        flip_yz: bool = True,
        robot: str | None = None,
    ) -> None:
        self.folder = Path(path)
        self.camera = robot or camera
        if not self.folder.is_dir():
            raise DatasetError(f"{self.folder}: no such SYNTHIA sequence folder.")
        pose_dir = self.folder / "CameraParams" / stereo / self.camera
        files = sorted(pose_dir.glob("*.txt")) if pose_dir.is_dir() else []
        if not files:
            raise DatasetError(f"{pose_dir}: missing SYNTHIA camera poses (NNNNNN.txt files).")
        numbers = [int(f.stem) for f in files if f.stem.isdigit()]
        if numbers != list(range(len(numbers))) or len(numbers) != len(files):
            raise DatasetError(
                f"{pose_dir}: pose files must be 000000.txt .. numbered without gaps."
            )
        self.indices = parse_range(frames, len(files), "frames")
        T = np.stack([read_synthia_pose(files[k]) for k in self.indices])
        if flip_yz:
            T = T @ FLIP_YZ
        if start_frame:
            T = invert(T[0]) @ T
        self.poses = T
        intr = self.folder / "CameraParams" / "intrinsics.txt"
        f, cx, cy = SYNTHIA_INTRINSICS
        if intr.is_file():
            vals = read_numbers(intr, "SYNTHIA intrinsics (focal cx cy)").ravel()
            if vals.size < 3 or vals[0] <= 0:
                raise DatasetError(f"{intr}: expected `focal cx cy` with focal > 0.")
            f, cx, cy = vals[:3]
        self.K = intrinsics_matrix(f, f, cx, cy)
        self.depth_dir = self.folder / "Depth" / stereo / self.camera
        self.label_dir = self.folder / "GT" / "LABELS" / stereo / self.camera
        self.depth_scale = float(depth_scale)

    def _load(self, i: int) -> Frame:
        k = int(self.indices[i])
        lab = read_image(self.label_dir / f"{k:06d}.png", f"SYNTHIA label image of frame {k}")
        dep = read_image(self.depth_dir / f"{k:06d}.png", f"SYNTHIA depth image of frame {k}")
        lab = lab[..., 0] if lab.ndim == 3 else lab
        dep = dep[..., 0] if dep.ndim == 3 else dep
        if lab.shape != dep.shape:
            raise DatasetError(f"frame {k}: labels {lab.shape} and depth {dep.shape} differ.")
        semantic = lab.astype(np.int64)
        semantic[(semantic <= 0) | (semantic >= len(SYNTHIA_CLASSES))] = -1
        depth = dep.astype(np.float64) * self.depth_scale
        depth[dep == 0] = np.nan
        return Frame(index=k, T_map_sensor=self.poses[i], semantic=semantic, depth=depth, K=self.K)
