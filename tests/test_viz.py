"""Pictures: one top-down convention, a palette whose classes are told apart."""

from __future__ import annotations

import itertools

import numpy as np
from matplotlib.colors import to_rgb

from sgloc.io.pictures import CLASS_PALETTE, plot_aligned_maps
from sgloc.maps.classes import AIRSIM_COLORS


def _lab(rgb: np.ndarray) -> np.ndarray:
    """sRGB 0-255 -> CIELAB (D65)."""
    c = np.asarray(rgb, float) / 255
    c = np.where(c > 0.04045, ((c + 0.055) / 1.055) ** 2.4, c / 12.92)
    m = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    xyz = c @ m.T / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > 0.008856, np.cbrt(xyz), 7.787 * xyz + 16 / 116)
    return np.stack([116 * f[:, 1] - 16, 500 * (f[:, 0] - f[:, 1]), 200 * (f[:, 1] - f[:, 2])], 1)


def _closest(rgb: np.ndarray) -> float:
    lab = _lab(rgb)
    return min(np.linalg.norm(a - b) for a, b in itertools.combinations(lab, 2))


def test_eleven_class_colours_are_far_apart():
    ours = np.array([to_rgb(c) for c in CLASS_PALETTE]) * 255
    assert len(CLASS_PALETTE) == 11
    assert _closest(ours) > 40 > 25 > _closest(AIRSIM_COLORS)
    white = _lab(np.array([[255, 255, 255]]))[0]
    assert all(np.linalg.norm(c - white) > 25 for c in _lab(ours))  # visible on white


def test_aligned_maps_picture_is_written(tmp_path, airsim_graphs):
    c1, c2 = airsim_graphs
    m = np.stack([np.arange(10), np.arange(10)], axis=1)
    p = plot_aligned_maps(c2, c1, np.eye(4), m, tmp_path / "a" / "maps.png", "title")
    assert p.read_bytes()[:4] == b"\x89PNG" and p.stat().st_size > 10_000
