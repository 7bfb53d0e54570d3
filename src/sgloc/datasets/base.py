"""Frame (one sensor reading with its pose) and the Dataset base class every loader follows."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from sgloc.errors import DatasetError
from sgloc.io.text import require_file


@dataclass
class Frame:
    """One frame of a robot run.

    index: the frame's number in its dataset (e.g. the KITTI scan number).
    T_map_sensor: (4,4) pose of the sensor in the robot's map frame. For cameras the sensor
        frame is the OPTICAL frame (x right, y down, z forward); each loader composes its
        dataset's own axis convention into this.
    semantic: (H,W) int class ids (-1 = no class) or None.
    depth: (H,W) float planar depth (metres along the optical axis) or None.
    K: (3,3) pinhole intrinsics or None.
    detections: (positions (k,3) metres in the sensor frame, labels (k,) int) or None.
    """

    index: int
    T_map_sensor: np.ndarray
    semantic: np.ndarray | None = None
    depth: np.ndarray | None = None
    K: np.ndarray | None = None
    detections: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def is_image(self) -> bool:
        return self.semantic is not None and self.depth is not None and self.K is not None


class Dataset(ABC):
    """A robot run: frames given lazily, in order, with their ground-truth poses.

    Subclasses set `poses` ((N,4,4) T_map_sensor per frame, same order as the frames),
    `indices` ((N,) frame numbers) and implement `_load(i)` for the i-th frame of the run.
    """

    name: ClassVar[str] = "dataset"
    #: Number of semantic classes (ids 0..n_classes-1), or None when unknown.
    n_classes: ClassVar[int | None] = None

    poses: np.ndarray
    indices: np.ndarray

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> Frame:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"{self.name}: frame {i} out of range (run has {n} frames)")
        return self._load(i % n)

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def frames(self) -> Iterator[Frame]:
        """The frames one by one, each read from disk only when reached."""
        for i in range(len(self)):
            yield self._load(i)

    @abstractmethod
    def _load(self, i: int) -> Frame: ...

    def __repr__(self) -> str:
        return f"{type(self).__name__}(frames={len(self)})"


_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def read_image(path: Path, what: str) -> np.ndarray:
    """Read a PNG (or any Pillow format) as a numpy array, DatasetError if missing/unreadable."""
    from PIL import Image, UnidentifiedImageError

    require_file(path, what)
    if path.suffix.lower() == ".png":
        with open(path, "rb") as f:  # a PNG ends with its IEND chunk; else it was cut short
            f.seek(max(0, path.stat().st_size - 12))
            if f.read() != _PNG_END:
                raise DatasetError(f"{path}: truncated PNG ({what}); re-export the image.")
    try:
        with Image.open(path) as im:
            return np.asarray(im)
    except (
        UnidentifiedImageError,
        OSError,
        ValueError,
        SyntaxError,
        Image.DecompressionBombError,
    ) as e:
        raise DatasetError(f"{path}: cannot read {what} ({e}); re-export the image.") from None


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The 3x3 pinhole matrix K."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def parse_range(value: tuple[int, int] | str | None, n: int, what: str = "scans") -> np.ndarray:
    """Frame numbers selected by `value`: None = all of 0..n-1; (first, last) or "first-last"
    inclusive; "first:stop" exclusive as in Python."""
    if value is None:
        return np.arange(n)
    if isinstance(value, str):
        s = value.strip()
        try:
            if ":" in s:
                a, b = s.split(":")
                first, last = int(a or 0), int(b or n) - 1
            elif "-" in s[1:]:
                a, b = s.split("-", 1)
                first, last = int(a), int(b)
            else:
                first = last = int(s)
        except ValueError:
            raise DatasetError(
                f"{what} range {value!r} is malformed; write FIRST-LAST (inclusive), e.g. 0-800."
            ) from None
    else:
        try:
            first, last = (int(v) for v in value)
        except (TypeError, ValueError):
            raise DatasetError(
                f"{what} range {value!r} is malformed; give (first, last) inclusive."
            ) from None
    if not (0 <= first <= last < n):
        raise DatasetError(
            f"{what} range {first}-{last} is outside 0-{n - 1} (the run has {n} {what})."
        )
    return np.arange(first, last + 1)
