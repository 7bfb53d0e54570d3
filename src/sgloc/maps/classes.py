"""Semantic class tables: the Airsim colour table of Guo et al. and packed-RGB helpers."""

from __future__ import annotations

import numpy as np

#: The 11 Airsim class colours (RGB) of Guo et al.; class k is the k-th colour.
AIRSIM_COLORS: np.ndarray = np.array(
    [
        (175, 6, 140),
        (65, 54, 217),
        (156, 198, 23),
        (184, 145, 182),
        (211, 80, 208),
        (232, 250, 80),
        (234, 20, 250),
        (99, 242, 104),
        (142, 1, 246),
        (81, 13, 36),
        (112, 105, 191),
    ],
    dtype=np.uint8,
)


#: 11 distinct class colours (hex) of every picture, class k -> CLASS_PALETTE[k % 11] (chosen in
#: sgloc.io.pictures's docstring).
CLASS_PALETTE: tuple[str, ...] = (
    "#0072B2", "#F38400", "#2CA02C", "#D62728", "#6A3D9A", "#654522",
    "#E68FAC", "#F0E442", "#000000", "#17BECF", "#C2B280",
)  # fmt: skip


def class_colours(labels: np.ndarray) -> list[str]:
    """A palette colour (hex) for each class id."""
    return [CLASS_PALETTE[int(c) % len(CLASS_PALETTE)] for c in np.asarray(labels)]


def pack_rgb(colors: np.ndarray) -> np.ndarray:
    """Pack (n,3) uint8 RGB into PCL's 24-bit integer `rgb` field (r << 16 | g << 8 | b)."""
    c = np.asarray(colors, dtype=np.uint32)
    return (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]


def unpack_rgb(packed: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pack_rgb`: (n,) integers -> (n,3) uint8 RGB."""
    p = np.asarray(packed, dtype=np.uint32)
    return np.stack([(p >> 16) & 255, (p >> 8) & 255, p & 255], axis=1).astype(np.uint8)


def colors_to_labels(colors: np.ndarray, table: np.ndarray = AIRSIM_COLORS) -> np.ndarray:
    """Map (..., 3) RGB colours to class ids via `table`; unknown colours give -1."""
    c = np.asarray(colors, dtype=np.int64)
    keys = (c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2]
    table_keys = pack_rgb(table).astype(np.int64)
    order = np.argsort(table_keys)
    pos = np.searchsorted(table_keys[order], keys)
    pos = np.clip(pos, 0, len(table_keys) - 1)
    found = table_keys[order][pos] == keys
    return np.where(found, order[pos], -1)


def label_colors(labels: np.ndarray, table: np.ndarray = AIRSIM_COLORS) -> np.ndarray:
    """Class ids -> (n,3) uint8 colours; ids beyond the table wrap around."""
    return table[np.asarray(labels) % len(table)]
