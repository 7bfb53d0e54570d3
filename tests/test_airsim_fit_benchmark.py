"""benchmarks/airsim_fit.py: its true-pair rule and overlap axes on hand-made maps, and its
report on Guo's Airsim maps."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.maps.graph import SemanticGraph


@pytest.fixture(scope="module")
def af(benchmark_module):
    return benchmark_module("airsim_fit")


def test_true_pairs_are_same_class_mutual_nearest_within_the_radius(af):
    q = SemanticGraph(np.array([[0.0, 0, 0], [10, 0, 0], [20, 0, 0], [30, 0, 0]]), [0, 0, 1, 0])
    t = SemanticGraph(
        np.array([[0.5, 0, 0], [10.2, 0, 0], [10.4, 0, 0], [20.1, 0, 0], [33.5, 0, 0]]),
        [0, 1, 0, 0, 0],
    )
    pairs = af.true_pairs(q, t, 2.0)
    # q1's nearest same-class target is t2 (t1 is closer but of class 1); q2 (class 1) has
    # no class-1 partner within 2 m; q3's nearest (t4) is 3.5 m away.
    assert pairs.tolist() == [[0, 0], [1, 2]]
    assert af.true_pairs(q, t, 4.0).tolist() == [[0, 0], [1, 2], [3, 4]]
    # Not mutual: two query objects near one target object; only the nearer one pairs.
    q2 = SemanticGraph(np.array([[0.0, 0, 0], [0.8, 0, 0], [50, 0, 0]]), [0, 0, 0])
    t2 = SemanticGraph(np.array([[0.7, 0, 0], [60, 0, 0], [70, 0, 0]]), [0, 0, 0])
    assert af.true_pairs(q2, t2, 2.0).tolist() == [[1, 0]]


def test_overlap_axes(af):
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-2, 2, 50), rng.uniform(-100, 100, 50), np.zeros(50)])
    c, s = np.cos(0.3), np.sin(0.3)
    pts = pts @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])
    axes = af.axes_of(pts)
    np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-12)
    assert abs(axes[0] @ [-s, c, 0]) > 0.999 and axes[2].tolist() == [0, 0, 1]


def test_report_on_the_airsim_maps(af, airsim_dir):
    text = af.report(trials=1)
    assert "| r = 2 m | 45 |" in text  # the 45 true pairs within 2 m of Guo's two maps
    for name in af.VARIANTS:
        assert f"| {name} | 1/1 |" in text
