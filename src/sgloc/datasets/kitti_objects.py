"""KITTI odometry LiDAR object detections (GOSMatch layout), e.g. `$SGLOC_DATA/kitti00`.

Folder:
    gosmatch_{seq}_objects.tar.xz   read directly (never unpacked): {seq}/centroids/NNNNNN.txt
                                    (rows `x y z`, LiDAR frame of scan NNNNNN) and {seq}/bow.txt
                                    (per scan: counts of vehicle, trunk, pole; the centroid rows
                                    come in that class order). An unpacked {seq}/ folder works too.
    poses_{seq}.txt                 KITTI ground truth, 12 values a row (camera-0 pose P_i in the
                                    sequence frame).
An object at p_velo in scan i is at P_i @ Tr @ p_velo in the sequence frame; the sensor frame of
a Frame is the LiDAR frame, T_map_sensor = P_i @ Tr (or, with start_frame=True, relative to the
first selected scan: inv(P_s @ Tr) @ P_i @ Tr, the robot-local frame of real use).
"""

from __future__ import annotations

import functools
import re
import tarfile
from pathlib import Path

import numpy as np

from sgloc.datasets.base import Dataset, Frame, parse_range, require_file
from sgloc.errors import DatasetError
from sgloc.io.files import MAX_TEXT_FILE_BYTES, read_regular_file
from sgloc.io.poses import read_kitti_poses
from sgloc.validation import MAX_VERTICES

#: Class ids of the detections (the column order of bow.txt).
CLASS_NAMES = ("vehicle", "trunk", "pole")

#: LiDAR-to-camera-0 calibration of KITTI odometry sequences 00-02 (row-major 3x4).
TR_KITTI_00 = np.array(
    [
        [4.276802385584e-04, -9.999672484946e-01, -8.084491683471e-03, -1.198459927713e-02],
        [-7.210626507497e-03, 8.081198471645e-03, -9.999413164504e-01, -5.403984729748e-02],
        [9.999738645903e-01, 4.859485810390e-04, -7.206933692422e-03, -2.921968648686e-01],
    ]
)

_CENTROID_NAME = re.compile(r"(?:^|/)centroids/(\d+)\.txt$")
#: One bow.txt row: three counts "vehicle,trunk,pole" (digits only).
_BOW_ROW = re.compile(r"[0-9]+,[0-9]+,[0-9]+")


def _read_text_bytes(path: Path, what: str) -> bytes:
    """The bytes of a regular file of bounded size (a FIFO or folder is refused unopened)."""
    require_file(path, what)
    return read_regular_file(path, what, MAX_TEXT_FILE_BYTES, DatasetError)


def _parse_bow(data: bytes, where: str) -> np.ndarray:
    rows = [r for r in data.decode("ascii", "replace").split() if r]
    try:
        if not all(_BOW_ROW.fullmatch(r) for r in rows):
            raise ValueError
        bow = np.array([[int(v) for v in r.split(",")] for r in rows], dtype=np.int64)
    except (ValueError, OverflowError):
        raise DatasetError(f"{where}: rows must be three integer counts `v,t,p`.") from None
    if bow.ndim != 2 or bow.shape[1] != len(CLASS_NAMES) or (bow < 0).any():
        raise DatasetError(f"{where}: rows must be three non-negative counts `vehicle,trunk,pole`.")
    if (bow > MAX_VERTICES).any():
        raise DatasetError(
            f"{where}: a count above {MAX_VERTICES} objects in one scan; the file is damaged."
        )
    return bow


def parse_centroids(data: bytes, where: str) -> np.ndarray:
    """(n,3) float64 centroids (metres, sensor frame) of a centroids file's bytes, rows `x y z`;
    DatasetError naming `where` when a value is not a finite number or a row is short."""
    try:
        vals = np.array(data.split(), dtype=np.float64)
    except ValueError:
        raise DatasetError(f"{where}: non-numeric value in the centroid rows.") from None
    if vals.size % 3:
        raise DatasetError(f"{where}: centroid rows must have 3 values `x y z`.")
    if not np.all(np.isfinite(vals)):
        raise DatasetError(f"{where}: NaN or infinite centroid values; fix or drop those rows.")
    return vals.reshape(-1, 3)


@functools.lru_cache(maxsize=4)
def _read_archive(path: str, mtime: float) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """(bow (N,3), centroids per scan) from the .tar.xz, parsed once per process."""
    bow = None
    texts: dict[int, bytes] = {}
    try:
        with tarfile.open(path, "r:*") as tf:
            for m in tf:
                if not m.isfile():
                    continue
                hit = _CENTROID_NAME.search(m.name)
                if hit:
                    texts[int(hit.group(1))] = tf.extractfile(m).read()
                elif m.name.endswith("bow.txt"):
                    bow = _parse_bow(tf.extractfile(m).read(), f"{path}:{m.name}")
    except (tarfile.TarError, OSError, EOFError) as e:
        raise DatasetError(f"{path}: cannot read the object archive ({e}).") from None
    if bow is None:
        raise DatasetError(f"{path}: the archive holds no bow.txt (per-scan class counts).")
    return bow, _check_scans(bow, texts, path)


def _check_scans(bow: np.ndarray, texts: dict[int, bytes], where: str) -> tuple[np.ndarray, ...]:
    n = len(bow)
    missing = sorted(set(range(n)) - set(texts))
    if missing:
        raise DatasetError(
            f"{where}: bow.txt lists {n} scans but centroids/{missing[0]:06d}.txt is missing."
        )
    out = []
    for i in range(n):
        c = parse_centroids(texts[i], f"{where}: centroids/{i:06d}.txt")
        if len(c) != bow[i].sum():
            raise DatasetError(
                f"{where}: centroids/{i:06d}.txt has {len(c)} rows but bow.txt line {i + 1} "
                f"counts {bow[i].sum()} objects."
            )
        out.append(c)
    return tuple(out)


def find_kitti_objects_files(path: Path, sequence: str) -> tuple[Path, Path]:
    """(objects source: .tar.xz or unpacked {seq}/ folder, poses file) under `path`."""
    path = Path(path)
    if path.is_file():
        return path, path.parent / f"poses_{sequence}.txt"
    if not path.is_dir():
        raise DatasetError(f"{path}: no such KITTI objects folder.")
    for cand in (path / f"gosmatch_{sequence}_objects.tar.xz", path / sequence, path):
        if cand.is_file() or (cand / "bow.txt").is_file():
            poses = path / f"poses_{sequence}.txt"
            if not poses.is_file() and (path / "poses.txt").is_file():
                poses = path / "poses.txt"
            return cand, poses
    raise DatasetError(
        f"{path}: missing gosmatch_{sequence}_objects.tar.xz (or an unpacked {sequence}/ folder "
        "with bow.txt and centroids/)."
    )


class KittiObjectsDataset(Dataset):
    """KITTI LiDAR object detections as detection frames (classes vehicle 0, trunk 1, pole 2).

    Args:
        path: the folder (e.g. $SGLOC_DATA/kitti00) or the .tar.xz itself.
        scans: scan range, (first, last) inclusive or "first-last"; None = all.
        start_frame: express poses in the first selected scan's LiDAR frame (robot-local).
        sequence: KITTI sequence number as in the file names ("00").
        Tr: (3,4) or (4,4) LiDAR-to-camera-0 calibration (default: sequence 00's).
        poses: pose file to use instead of poses_{sequence}.txt.
    """

    name = "kitti_objects"
    n_classes = len(CLASS_NAMES)

    def __init__(
        self,
        path: str | Path,
        scans: tuple[int, int] | str | None = None,
        start_frame: bool = False,
        sequence: str = "00",
        Tr: np.ndarray | None = None,
        poses: str | Path | None = None,
    ) -> None:
        source, poses_path = find_kitti_objects_files(Path(path), sequence)
        self.source = source
        self._folder: Path | None = None
        if source.is_file():
            self._bow, self._centroids = _read_archive(str(source), source.stat().st_mtime)
        else:
            self._folder = source
            self._bow = _parse_bow(
                _read_text_bytes(source / "bow.txt", "per-scan class counts"),
                str(source / "bow.txt"),
            )
            self._centroids = None
        P = read_kitti_poses(Path(poses) if poses is not None else poses_path)
        if len(P) != len(self._bow):
            raise DatasetError(
                f"{poses or poses_path}: {len(P)} poses but the detections have "
                f"{len(self._bow)} scans; use the pose file of the same sequence."
            )
        Tr4 = np.eye(4)
        Tr_arr = TR_KITTI_00 if Tr is None else np.asarray(Tr, dtype=np.float64)
        if Tr_arr.shape not in ((3, 4), (4, 4)):
            raise DatasetError(f"Tr must be a 3x4 or 4x4 matrix, got shape {Tr_arr.shape}.")
        Tr4[:3] = Tr_arr[:3]
        self.Tr = Tr4
        self.indices = parse_range(scans, len(self._bow), "scans")
        T = P[self.indices] @ Tr4
        if start_frame:
            T = np.linalg.inv(T[0]) @ T  # Tr is rigid only to ~1e-7: exact inverse
        self.start_frame = bool(start_frame)
        self.poses = T

    @property
    def class_counts(self) -> np.ndarray:
        """(N,3) detections per selected scan: vehicle, trunk, pole."""
        return self._bow[self.indices].copy()

    def _load(self, i: int) -> Frame:
        k = int(self.indices[i])
        if self._centroids is not None:
            pts = self._centroids[k]
        else:
            p = self._folder / "centroids" / f"{k:06d}.txt"
            pts = parse_centroids(_read_text_bytes(p, "scan centroids"), str(p))
            if len(pts) != self._bow[k].sum():
                raise DatasetError(
                    f"{p}: {len(pts)} rows but bow.txt counts {self._bow[k].sum()} objects."
                )
        labels = np.repeat(np.arange(len(CLASS_NAMES)), self._bow[k])
        return Frame(index=k, T_map_sensor=self.poses[i], detections=(pts.copy(), labels))

    def __repr__(self) -> str:
        return (
            f"KittiObjectsDataset(scans={self.indices[0]}-{self.indices[-1]}, "
            f"start_frame={self.start_frame}, source={self.source})"
        )
