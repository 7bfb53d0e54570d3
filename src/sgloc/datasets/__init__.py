"""Dataset loaders, one per file, and a factory by name (as KISS-ICP does).

from sgloc.datasets.downloads import dataset_dir
ds = make_dataset("kitti_objects", dataset_dir("kitti00"), scans="0-800", start_frame=True)
for frame in ds:  # frames are read lazily
    ...
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

from sgloc.datasets.airsim import AirsimDataset
from sgloc.datasets.base import Dataset, Frame
from sgloc.datasets.kitti import KittiDataset
from sgloc.datasets.kitti_objects import KittiObjectsDataset
from sgloc.datasets.synthia import SynthiaDataset
from sgloc.errors import DatasetError
from sgloc.registry import Registry

#: Loader classes by name.
DATASETS: Registry[type[Dataset]] = Registry(
    "dataset",
    {
        "airsim": AirsimDataset,
        "synthia": SynthiaDataset,
        "kitti": KittiDataset,
        "kitti_objects": KittiObjectsDataset,
    },
)


def make_dataset(name: str, path: str | Path, **options: Any) -> Dataset:
    """The loader `name` (see DATASETS) on `path`, with its own options (e.g. robot=, scans=)."""
    cls = DATASETS.lookup(name)
    try:
        inspect.signature(cls).bind(path, **options)
    except TypeError as e:
        raise DatasetError(
            f"dataset {name!r}: bad option ({e}); see help({cls.__name__})."
        ) from None
    return cls(path, **options)


__all__ = [
    "DATASETS",
    "AirsimDataset",
    "Dataset",
    "DatasetError",
    "Frame",
    "KittiDataset",
    "KittiObjectsDataset",
    "SynthiaDataset",
    "make_dataset",
]
