"""The hard-case benchmark's pair builder (benchmarks/hard_cases.py) on real KITTI 00 data:
categories hold what their names say, the ground truth aligns the maps, tuning and held-out
pairs are split at scan 3000."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.geometry import apply, make_transform


@pytest.fixture(scope="module")
def hc(data_dir, benchmark_module):
    return benchmark_module("hard_cases")


@pytest.fixture(scope="module")
def sequence(hc):
    from sgloc.evaluation.pairs_kitti import kitti_sequence

    return kitti_sequence(hc.kitti_root())


def _forward_angle_deg(L: np.ndarray, i: int, j: int) -> float:
    """3D angle between the LiDAR forward (x) axes of scans i and j in the sequence frame."""
    c = float(np.clip(L[i, :3, 0] @ L[j, :3, 0], -1.0, 1.0))
    return float(np.degrees(np.arccos(c)))


def test_heading_categories(hc, sequence):
    L, ij, _ = sequence
    for cat, lo, hi in [("reverse", 135, 180), ("same", 0, 45), ("crossing", 45, 135)]:
        specs = hc.category_specs(cat, quick=True)
        assert specs, cat
        for s in specs:
            i, j = ij[s.k][::-1] if s.swap else ij[s.k]
            assert s.a[0] <= i <= s.a[1] and s.b[0] <= j <= s.b[1]
            assert lo - 3 <= _forward_angle_deg(L, i, j) <= hi + 3, (cat, s.label)


def test_negatives_far_apart_and_split(hc, sequence):
    L = sequence[0]
    for heldout in (False, True):
        specs = hc.category_specs("negatives", quick=True, heldout=heldout)
        assert len(specs) == 4 and not any(s.positive for s in specs)
        for s in specs:
            pa, pb = L[s.a[0] : s.a[1] + 1, :3, 3], L[s.b[0] : s.b[1] + 1, :3, 3]
            gap = np.linalg.norm(pa[:, None] - pb[None], axis=2).min()
            assert gap >= 150.0, s.label
            assert (max(*s.a, *s.b) > 3000) == heldout


def test_tuning_pairs_stay_before_scan_3000(hc):
    for cat in ("low_overlap", "scan_to_map"):
        for s in hc.category_specs(cat, quick=True):
            assert max(*s.a, *s.b) <= 3000
        assert any(max(*s.a, *s.b) > 3000 for s in hc.category_specs(cat, True, heldout=True))


@pytest.mark.parametrize("swap", [False, True])
def test_ground_truth_aligns_the_maps(hc, swap):
    specs = [s for s in hc.category_specs("reverse") if s.swap == swap]
    pair = hc.make_pair(min(specs, key=lambda s: s.a[1] - s.a[0]))
    assert not np.allclose(pair.T_moved_own, np.eye(4))  # the target is moved
    within = hc.gt_residuals(pair) < 1.0
    assert within.sum() >= 15 and within.mean() >= 0.2
    assert hc.gt_check(pair)["gt_ok"]
    # The same maps under a GT off by 4 m do not pass.
    off = make_transform(np.eye(3), np.array([4.0, 0.0, 0.0])) @ pair.T_target_query
    bad = type(pair)(pair.query, pair.target, off)
    assert (hc.gt_residuals(bad) < 1.0).sum() < within.sum() / 2
    assert not hc.gt_check(bad)["gt_ok"]
    # A single scan's objects land on the map too.
    scan = hc.make_pair(hc.category_specs("scan_to_map", quick=True)[0])
    q = apply(scan.T_target_query, scan.query.positions)
    assert len(q) >= 3 and (hc.gt_residuals(scan) < 1.0).sum() >= 3


def test_parse_variant(hc):
    name, settings = hc.parse_variant("k3=descriptor=histogram,top_k=3,acceptance=false")
    assert name == "k3"
    assert settings == {"descriptor": "histogram", "top_k": 3, "acceptance": False}
    name, settings = hc.parse_variant("p=base=paper,tau=2")
    assert settings["tau"] == 2 and settings["scoring"] == "count"
