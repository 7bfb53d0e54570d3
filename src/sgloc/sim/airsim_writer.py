"""Write a rendered two-robot run in Guo's Airsim layout (read back by the `airsim` loader),
with the ground-truth transform between the two robots' start frames.

Layout (see /work/notes/sim_extraction_contract.md and docs):
```
run_dir/run.json, run_dir/ground_truth.txt (T_forwardCar_backwardCar, 4 rows)
run_dir/<robot>/airsim.txt            N, then rows `x y z qw qx qy qz` (T_start_body)
run_dir/<robot>/intrinsics.txt        `fx fy cx cy width height`
run_dir/<robot>/depth/depth_{i}.png   8-bit planar depth, metres = px / 255 * 100
run_dir/<robot>/segmentation/segmentation_{i}.png   RGB, class k = AIRSIM_COLORS[k]
```
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from sgloc.datasets.base import Frame
from sgloc.errors import DatasetError
from sgloc.maps.classes import AIRSIM_COLORS
from sgloc.sim.render import T_BODY_OPTICAL

#: Metres per 8-bit depth step range: metres = px / 255 * DEPTH_SCALE (Guo's Airsim data).
DEPTH_SCALE = 100.0
GROUND_TRUTH_FILE = "ground_truth.txt"

Progress = Callable[[int], None]


def depth_to_png(depth: np.ndarray) -> np.ndarray:
    """Planar depth (metres; inf = no hit) -> uint8 px = round(depth / 100 * 255), capped at
    255."""
    d = np.nan_to_num(np.asarray(depth, dtype=np.float64), nan=DEPTH_SCALE, posinf=DEPTH_SCALE)
    return np.clip(np.rint(d / DEPTH_SCALE * 255.0), 0, 255).astype(np.uint8)


def png_to_depth(px: np.ndarray) -> np.ndarray:
    """Inverse of `depth_to_png` (metres)."""
    return np.asarray(px, dtype=np.float64) / 255.0 * DEPTH_SCALE


def semantic_to_rgb(semantic: np.ndarray, table: np.ndarray = AIRSIM_COLORS) -> np.ndarray:
    """(H,W) class ids (-1 = none) -> (H,W,3) uint8 colours; no class is black."""
    sem = np.asarray(semantic)
    rgb = np.zeros((*sem.shape, 3), np.uint8)
    m = sem >= 0
    if np.any(sem[m] >= len(table)):
        raise DatasetError(f"class id {sem.max()} has no Airsim colour (only {len(table)}).")
    rgb[m] = table[sem[m]]
    return rgb


def pose_rows(T_map_body: np.ndarray) -> np.ndarray:
    """(N,4,4) poses -> (N,7) rows `x y z qw qx qy qz`."""
    T = np.asarray(T_map_body, dtype=np.float64)
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # x y z w
    q = np.where(q[:, 3:4] < 0, -q, q)  # unique sign: qw >= 0
    return np.concatenate([T[:, :3, 3], q[:, 3:4], q[:, :3]], axis=1)


def write_robot(
    folder: str | Path,
    frames: Iterable[Frame],
    progress: Progress | None = None,
    compress_level: int = 1,
) -> int:
    """Write one robot's rendered `frames` (optical poses in its map frame) in the Airsim
    layout under `folder`; returns the number of frames written."""
    folder = Path(folder)
    (folder / "depth").mkdir(parents=True, exist_ok=True)
    (folder / "segmentation").mkdir(parents=True, exist_ok=True)
    body_from_optical_inv = np.linalg.inv(T_BODY_OPTICAL)
    poses, K, shape = [], None, None
    for i, f in enumerate(frames):
        if f.semantic is None or f.depth is None or f.K is None:
            raise DatasetError(f"frame {i} has no semantic image, depth or K; cannot write it.")
        Image.fromarray(depth_to_png(f.depth), mode="L").save(
            folder / "depth" / f"depth_{i}.png", compress_level=compress_level
        )
        Image.fromarray(semantic_to_rgb(f.semantic), mode="RGB").save(
            folder / "segmentation" / f"segmentation_{i}.png", compress_level=compress_level
        )
        poses.append(f.T_map_sensor @ body_from_optical_inv)  # T_map_body
        K, shape = f.K, f.semantic.shape
        if progress is not None:
            progress(1)
    if not poses:
        raise DatasetError(f"{folder}: no frames to write.")
    rows = pose_rows(np.stack(poses))
    with open(folder / "airsim.txt", "w") as fh:
        fh.write(f"{len(rows)}\n")
        np.savetxt(fh, rows, fmt="%.6f")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    (folder / "intrinsics.txt").write_text(f"{fx:g} {fy:g} {cx:g} {cy:g} {shape[1]} {shape[0]}\n")
    return len(rows)


def write_ground_truth(run_dir: str | Path, T_target_query: np.ndarray, target: str, query: str):
    """Write `ground_truth.txt`: T_target_query (4 rows), with a comment naming the robots."""
    path = Path(run_dir) / GROUND_TRUTH_FILE
    with open(path, "w") as fh:
        fh.write(f"# T_{target}_{query}: maps points of {query}'s start frame into {target}'s\n")
        np.savetxt(fh, np.asarray(T_target_query, dtype=np.float64), fmt="%.9f")
    return path


def read_ground_truth(run_dir: str | Path) -> np.ndarray:
    """Read T_forwardCar_backwardCar (4x4) from a run written by `write_airsim_run`."""
    path = Path(run_dir) / GROUND_TRUTH_FILE
    if not path.is_file():
        raise DatasetError(
            f"{path}: missing ground-truth file; write the run with sgloc.sim.write_airsim_run."
        )
    try:
        T = np.loadtxt(path, comments="#")
    except ValueError as e:
        raise DatasetError(f"{path}: malformed ground truth ({e}).") from None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DatasetError(f"{path}: expected 4 rows of 4 numbers, got shape {T.shape}.")
    return T


def write_run_metadata(run_dir: str | Path, meta: dict) -> Path:
    path = Path(run_dir) / "run.json"
    path.write_text(json.dumps(meta, indent=2, default=_jsonable))
    return path


def _jsonable(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")
