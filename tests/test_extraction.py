"""Extraction: segmentation, back-projection, association, build_graph."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from sgloc.datasets import Frame
from sgloc.errors import DatasetError, SglocError
from sgloc.extraction import (
    ExtractionConfig,
    GraphBuilder,
    build_graph,
    region_positions,
    segment,
)
from sgloc.geometry import make_transform


def _regions(seg):
    """The partition as a set of frozensets of flat pixel indices."""
    rm = seg.region_map.ravel()
    return {frozenset(np.flatnonzero(rm == r).tolist()) for r in range(len(seg))}


def _flood_fill_oracle(sem, dep, max_depth, jump, min_pixels):
    """Plain 4-connected seed fill (the paper's rule), as a reference partition."""
    H, W = sem.shape
    valid = (sem >= 0) & np.isfinite(dep) & (dep > 0) & (dep <= max_depth)
    seen = np.zeros_like(valid)
    out = set()
    for y in range(H):
        for x in range(W):
            if not valid[y, x] or seen[y, x]:
                continue
            region, q = [], deque([(y, x)])
            seen[y, x] = True
            while q:
                cy, cx = q.popleft()
                region.append(cy * W + cx)
                for ny, nx in ((cy + 1, cx), (cy - 1, cx), (cy, cx + 1), (cy, cx - 1)):
                    if (
                        0 <= ny < H
                        and 0 <= nx < W
                        and valid[ny, nx]
                        and not seen[ny, nx]
                        and sem[ny, nx] == sem[cy, cx]
                        and abs(dep[ny, nx] - dep[cy, cx]) < jump
                    ):
                        seen[ny, nx] = True
                        q.append((ny, nx))
            if len(region) >= min_pixels:
                out.add(frozenset(region))
    return out


# -- segmentation -----------------------------------------------------------------------------
def test_touching_objects_of_one_class_at_different_depths_split():
    sem = np.full((10, 20), -1)
    sem[2:8, 2:18] = 3  # one class, one connected blob in the image
    dep = np.full((10, 20), 50.0)
    dep[:, :10] = 5.0  # left object at 5 m
    dep[:, 10:] = 8.0  # right object at 8 m, touching it
    seg = segment(sem, dep, max_depth=30, depth_jump=1.0)
    assert len(seg) == 2
    assert set(seg.classes.tolist()) == {3}
    assert sorted(seg.sizes.tolist()) == [48, 48]
    assert seg.region_map[4, 5] != seg.region_map[4, 14]
    # the same blob with a depth step below 1 m stays one object
    dep[:, 10:] = 5.6
    assert len(segment(sem, dep, max_depth=30, depth_jump=1.0)) == 1


def test_depth_rule_is_between_neighbours_not_to_the_seed():
    sem = np.zeros((4, 30), dtype=int)
    dep = np.tile(5.0 + 0.5 * np.arange(30), (4, 1))  # a wall receding 0.5 m per column
    seg = segment(sem, dep, max_depth=100, depth_jump=1.0)
    assert len(seg) == 1 and seg.sizes[0] == 120


def test_different_classes_and_diagonal_contact_are_separate_regions():
    sem = np.full((6, 6), -1)
    sem[0:3, 0:3] = 1
    sem[3:6, 3:6] = 1  # touches the first block only at a corner
    sem[0:3, 3:6] = 2  # same depth, other class
    dep = np.full((6, 6), 4.0)
    seg = segment(sem, dep)
    assert len(seg) == 3
    assert sorted(seg.classes.tolist()) == [1, 1, 2]


def test_tiny_regions_dropped_and_max_depth_and_invalid_depth_ignored():
    sem = np.full((12, 12), -1)
    sem[0:2, 0:2] = 0  # 4 px
    sem[5:10, 5:10] = 1  # 25 px
    sem[0:4, 8:12] = 2  # 16 px, too deep
    dep = np.full((12, 12), 10.0)
    dep[0:4, 8:12] = 40.0
    dep[9, 5:10] = np.inf  # sky-like pixels inside region 1 are no depth
    seg = segment(sem, dep, max_depth=30, min_pixels=5)
    assert seg.classes.tolist() == [1]
    assert seg.sizes.tolist() == [20]
    assert (seg.region_map[9, 5:10] == -1).all()
    assert len(segment(sem, dep, max_depth=30, min_pixels=4)) == 2
    assert len(segment(sem, dep, max_depth=50, min_pixels=4)) == 3


def test_segmentation_equals_a_flood_fill_on_random_images(rng):
    for _ in range(5):
        H, W = 24, 31
        sem = rng.integers(-1, 3, size=(H // 3, W))
        sem = np.repeat(sem, 3, axis=0)[:H]  # blobby rows
        dep = rng.choice(
            [2.0, 2.5, 4.0, 9.0, 35.0, np.nan], size=(H, W), p=[0.3, 0.2, 0.2, 0.2, 0.05, 0.05]
        )
        got = _regions(segment(sem, dep, max_depth=30, depth_jump=1.0, min_pixels=3))
        assert got == _flood_fill_oracle(sem, dep, 30, 1.0, 3)


def test_min_pixels_scales_with_resolution():
    cfg = ExtractionConfig()
    assert cfg.min_pixels_for(576, 1024) == 5000
    assert cfg.min_pixels_for(180, 320) == round(5000 * 320 * 180 / (1024 * 576))
    assert cfg.min_pixels_for(1, 1) == 1


def test_bad_images_raise():
    with pytest.raises(SglocError, match="same size"):
        segment(np.zeros((3, 4), int), np.zeros((4, 3)))
    with pytest.raises(SglocError, match="integer class ids"):
        segment(np.zeros((3, 3)), np.ones((3, 3)))
    with pytest.raises(SglocError, match="association_radius"):
        ExtractionConfig(association_radius=-1)


# -- back-projection --------------------------------------------------------------------------
K = np.array([[100.0, 0, 50], [0, 200.0, 40], [0, 0, 1]])


def test_backprojection_against_a_hand_computed_point():
    sem = np.full((60, 100), -1)
    dep = np.full((60, 100), np.nan)
    sem[20, 70] = sem[20, 71] = 4
    dep[20, 70], dep[20, 71] = 10.0, 10.0
    seg = segment(sem, dep, min_pixels=1)
    # pixel (u=70, v=20) at 10 m: x = (70-50)/100*10 = 2, y = (20-40)/200*10 = -1, z = 10;
    # pixel (71, 20): x = 2.1. Mean: (2.05, -1, 10).
    p = region_positions(seg, dep, K, "mean")
    np.testing.assert_allclose(p, [[2.05, -1.0, 10.0]])
    # into the map: camera rotated 90 deg about the map's z axis and moved by (1, 2, 3)
    T = make_transform(np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), [1.0, 2.0, 3.0])
    frame = Frame(0, T, semantic=sem, depth=dep, K=K)
    g = build_graph([frame], ExtractionConfig(min_pixels=1, max_depth=30))
    np.testing.assert_allclose(g.positions, [[1.0 + 1.0, 2.0 + 2.05, 3.0 + 10.0]])
    assert g.labels.tolist() == [4]


def test_centre_position_uses_2d_centroid_and_median_depth():
    sem = np.full((60, 100), -1)
    dep = np.full((60, 100), np.nan)
    sem[10:13, 60] = 1  # v = 10, 11, 12 at u = 60
    dep[10:13, 60] = [8.0, 8.5, 8.8]
    seg = segment(sem, dep, min_pixels=1)
    p = region_positions(seg, dep, K, "centre")
    np.testing.assert_allclose(p, [[(60 - 50) / 100 * 8.5, (11 - 40) / 200 * 8.5, 8.5]])
    mean = region_positions(seg, dep, K, "mean")
    assert not np.allclose(mean, p)


# -- association ------------------------------------------------------------------------------
def test_association_merges_repeats_with_running_mean_and_keeps_objects_apart(rng):
    cfg = ExtractionConfig(association_radius=5.0)
    b = GraphBuilder(cfg)
    pole = np.array([10.0, 0.0, 0.0])
    noise = rng.normal(scale=0.3, size=(6, 3))
    for k in range(6):
        # a pole seen with noise; a same-class pole 8 m away; a car on top of the first pole
        b.add_observations(
            np.stack([pole + noise[k], pole + [8.0, 0, 0], pole]), np.array([2, 2, 3])
        )
    g = b.graph()
    assert len(g) == 3
    assert sorted(b.counts.tolist()) == [6, 6, 6]
    i = int(np.flatnonzero((g.labels == 2) & (g.positions[:, 0] < 14))[0])
    np.testing.assert_allclose(g.positions[i], pole + noise.mean(axis=0))


def test_same_frame_observations_never_merge_and_nearest_same_class_wins():
    b = GraphBuilder(ExtractionConfig(association_radius=5.0))
    b.add_observations([[0, 0, 0], [2, 0, 0]], [1, 1])  # two objects 2 m apart, one frame
    assert len(b.graph()) == 2
    ids = b.add_observations([[1.8, 0, 0], [0.1, 0, 0]], [1, 1])
    assert ids.tolist() == [1, 0]
    assert b.counts.tolist() == [2, 2]


def test_min_observations_and_ignored_classes():
    b = GraphBuilder(ExtractionConfig(min_observations=2, ignore_classes=(7,)))
    b.add_observations([[0, 0, 0], [50, 0, 0], [0, 50, 0]], [1, 1, 7])
    b.add_observations([[0.5, 0, 0]], [1])
    g = b.graph()
    assert len(g) == 1 and g.labels.tolist() == [1]
    np.testing.assert_allclose(g.positions, [[0.25, 0, 0]])


def test_build_graph_from_detection_frames_uses_poses_and_max_range():
    T0 = np.eye(4)
    T1 = make_transform(np.eye(3), [3.0, 0, 0])  # the sensor moved 3 m forward
    f0 = Frame(0, T0, detections=(np.array([[10.0, 0, 0], [60.0, 0, 0]]), np.array([0, 1])))
    f1 = Frame(1, T1, detections=(np.array([[7.2, 0, 0]]), np.array([0])))
    g = build_graph([f0, f1], ExtractionConfig(max_range=50.0, association_radius=1.0))
    assert len(g) == 1
    np.testing.assert_allclose(g.positions, [[10.1, 0, 0]])
    with pytest.raises(DatasetError, match="neither detections nor"):
        build_graph([Frame(3, T0)])


def test_build_graph_edges_and_distances_come_from_the_graph():
    T = np.eye(4)
    det = (np.array([[0.0, 0, 0], [10, 0, 0], [40, 0, 0]]), np.array([0, 1, 2]))
    calls = []
    g = build_graph(
        [Frame(0, T, detections=det)], ExtractionConfig(edge_radius=20), progress=calls.append
    )
    assert len(calls) == 1
    assert g.n_edges == 1
    np.testing.assert_allclose(g.distances[0, 2], 40.0)
