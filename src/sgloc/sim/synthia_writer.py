"""Write a rendered two-robot run in the SYNTHIA video-sequence layout (read back by the
`synthia` loader): robot A (the target) as camera Omni_F, robot B (the query) as Omni_B.

Layout (the official one, as `sgloc.datasets.synthia` reads it):
```
seq_dir/CameraParams/intrinsics.txt                  `focal cx cy`
seq_dir/CameraParams/Stereo_Left/<cam>/NNNNNN.txt    16 values: T_world_camera, column-major,
                                                     camera axes with Y and Z flipped against
                                                     the optical frame
seq_dir/Depth/Stereo_Left/<cam>/NNNNNN.png           16-bit depth in centimetres (0 = none)
seq_dir/GT/LABELS/Stereo_Left/<cam>/NNNNNN.png       class id (SYNTHIA's 13 classes, 0 = void)
``` Unlike the Airsim layout, both cameras share one world frame (as SYNTHIA's cameras do: they sit
on one car), so the ground truth between the two maps in the world frame is the identity.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
from PIL import Image

from sgloc.datasets.base import Frame
from sgloc.datasets.synthia import FLIP_YZ, SYNTHIA_CLASSES
from sgloc.errors import DatasetError
from sgloc.sim.city import CITY_CLASSES

#: SYNTHIA camera of each robot: the forward camera is robot A, the backward one robot B.
SYNTHIA_CAMERAS = ("Omni_F", "Omni_B")
STEREO = "Stereo_Left"
#: Centimetres per depth step, as in SYNTHIA; 16 bits hold up to 655 m.
DEPTH_UNITS_PER_M = 100.0

#: City class -> SYNTHIA class. SYNTHIA has no bench, traffic light, bin or bus stop (void),
#: and one vegetation class for trees and bushes.
CITY_TO_SYNTHIA: dict[str, str] = {
    "building": "building",
    "tree": "vegetation",
    "pole": "pole",
    "car": "car",
    "sign": "sign",
    "fence": "fence",
    "bush": "vegetation",
}


def city_to_synthia_ids() -> np.ndarray:
    """(len(CITY_CLASSES),) SYNTHIA class id of each city class (0 = void)."""
    ids = {name: k for k, name in enumerate(SYNTHIA_CLASSES)}
    return np.array([ids[CITY_TO_SYNTHIA[c]] if c in CITY_TO_SYNTHIA else 0 for c in CITY_CLASSES])


def synthia_label_image(semantic: np.ndarray) -> np.ndarray:
    """(H,W) city class ids (-1 = none) -> (H,W) uint8 SYNTHIA class ids (0 = void)."""
    table = city_to_synthia_ids()
    sem = np.asarray(semantic)
    out = np.zeros(sem.shape, np.uint8)
    known = (sem >= 0) & (sem < len(table))
    out[known] = table[sem[known]]
    return out


def synthia_depth_image(depth: np.ndarray) -> np.ndarray:
    """Planar depth (metres; inf/NaN = no hit) -> uint16 centimetres, 0 where there is none."""
    d = np.asarray(depth, dtype=np.float64) * DEPTH_UNITS_PER_M
    ok = np.isfinite(d) & (d > 0) & (d < 65535)
    return np.where(ok, np.rint(np.where(ok, d, 0.0)), 0).astype(np.uint16)


def pose_values(T_world_optical: np.ndarray) -> np.ndarray:
    """The 16 values of a SYNTHIA pose file (column-major T_world_camera, Y/Z flipped)."""
    return (np.asarray(T_world_optical, dtype=np.float64) @ FLIP_YZ).ravel(order="F")


def write_synthia_camera(
    seq_dir: str | Path, camera: str, frames: Iterable[Frame], T_world_map: np.ndarray
) -> int:
    """Write one camera's rendered `frames` (poses in the robot's map frame, which sits at
    `T_world_map` in the world) into `seq_dir`; returns the number of frames written."""
    seq = Path(seq_dir)
    dirs = [
        seq / "CameraParams" / STEREO / camera,
        seq / "Depth" / STEREO / camera,
        seq / "GT" / "LABELS" / STEREO / camera,
    ]
    for d in dirs:
        d.mkdir(parents=True, exist_ok=True)
    n, K = 0, None
    for k, f in enumerate(frames):
        if f.semantic is None or f.depth is None or f.K is None:
            raise DatasetError(f"frame {k} has no semantic image, depth or K; cannot write it.")
        name = f"{k:06d}"
        np.savetxt(dirs[0] / f"{name}.txt", pose_values(T_world_map @ f.T_map_sensor)[None])
        Image.fromarray(synthia_depth_image(f.depth)).save(dirs[1] / f"{name}.png")
        Image.fromarray(synthia_label_image(f.semantic)).save(dirs[2] / f"{name}.png")
        n, K = n + 1, f.K
    if n == 0:
        raise DatasetError(f"{seq}: no frames to write for camera {camera}.")
    if not np.isclose(K[0, 0], K[1, 1]):
        raise DatasetError("the SYNTHIA layout holds one focal length; fx and fy differ.")
    (seq / "CameraParams" / "intrinsics.txt").write_text(f"{K[0, 0]:.6f} {K[0, 2]:g} {K[1, 2]:g}\n")
    return n


def write_synthia_run(run, seq_dir: str | Path) -> Path:
    """Render a `sgloc.sim.SyntheticRun` into `seq_dir` in the SYNTHIA layout: its target robot
    as Omni_F, its query robot as Omni_B, both in the city's world frame."""
    from sgloc.sim.run import QUERY, TARGET

    for robot, camera in zip((TARGET, QUERY), SYNTHIA_CAMERAS, strict=True):
        write_synthia_camera(seq_dir, camera, run.frames(robot), run.routes.start_pose(robot))
    return Path(seq_dir)
