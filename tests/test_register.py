"""sgloc.register: the correspondence-level API, against the plain numpy pipeline."""

from __future__ import annotations

import numpy as np
import pytest
from references.consistency import consistency_bool
from references.rejection import prune_by_support

import sgloc
from sgloc.errors import SglocError, UnknownNameError
from sgloc.estimation import (
    RansacConfig,
    irls_refine,
    ransac,
    ransac_compiled,
    ransac_reference,
    weighted_kabsch,
)
from sgloc.estimation import fit_kernels as fit
from sgloc.geometry import transform_error
from sgloc.sim.correspondences import make_correspondences


def numpy_pipeline(src, dst, tau, threshold, seed):
    """Rejection by the numpy references (tests/references), then RANSAC and the refit."""
    kept = prune_by_support(consistency_bool(src, dst, tau, "distance"), 0.5)
    rs = ransac(src[kept], dst[kept], RansacConfig(threshold=threshold, dof=6, max_tilt=None),
                np.random.default_rng(seed))  # fmt: skip
    if rs.transform is None:
        return None, kept[rs.inliers]
    s, d = src[kept][rs.inliers], dst[kept][rs.inliers]
    return irls_refine(s, d, weighted_kabsch(s, d)), kept[rs.inliers]


@pytest.mark.parametrize("m, ratio", [(50, 0.5), (300, 0.8), (2000, 0.9)])
@pytest.mark.parametrize("kind", ["random", "structured"])
def test_same_transform_as_numpy_pipeline(m, ratio, kind):
    for seed in range(3):
        cs = make_correspondences(m, ratio, np.random.default_rng([m, seed]), kind)
        T_ref, inl_ref = numpy_pipeline(cs.src, cs.dst, 5.0, 5.0, seed)
        res = sgloc.register(cs.src, cs.dst, "neighbor", noise_bound=2.5, seed=seed)
        assert res.success and T_ref is not None
        assert np.abs(res.transform - T_ref).max() < 1e-9
        assert np.array_equal(res.inliers, inl_ref)
        te, re = transform_error(res.transform, cs.T_dst_src)
        assert te < 2.0 and re < 2.0
        assert set(res.timings) == {"rejection", "ransac", "refine", "total"}
        assert res.timings["total"] >= res.timings["rejection"] >= 0


def test_every_rejector_and_settings_routing():
    cs = make_correspondences(200, 0.7, np.random.default_rng(1))
    for name in ("none", "neighbor", "spectral", "clique"):
        res = sgloc.register(cs.src, cs.dst, name, noise_bound=2.5, iterations=2000)
        assert res.success, name
        assert cs.inlier[res.inliers].mean() > 0.9
    res = sgloc.register(cs.src, cs.dst, tau=3.0, eta=0.6, threshold=4.0, refine="kabsch")
    assert res.success


def test_failure_is_a_result_with_a_reason():
    rng = np.random.default_rng(0)
    src, dst = rng.uniform(0, 100, (40, 3)), rng.uniform(0, 100, (40, 3))
    res = sgloc.register(src, dst, "neighbor", noise_bound=0.05)
    assert not res.success and res.transform is None and res.reason


@pytest.mark.parametrize(
    "src, dst, kwargs, error, match",
    [
        (np.zeros((5, 2)), np.zeros((5, 2)), {}, SglocError, r"\(m,3\)"),
        (np.zeros((5, 3)), np.zeros((4, 3)), {}, SglocError, "same number"),
        (np.full((5, 3), np.nan), np.zeros((5, 3)), {}, SglocError, "NaN"),
        (np.zeros((5, 3)), np.zeros((5, 3)), {"noise_bound": 0.0}, SglocError, "noise_bound"),
        (np.zeros((5, 3)), np.zeros((5, 3)), {"rejection": "magic"}, UnknownNameError, "magic"),
        (np.zeros((5, 3)), np.zeros((5, 3)), {"sigma_x": 1}, UnknownNameError, "sigma_x"),
        (np.zeros((5, 3)), np.zeros((5, 3)), {"refine": "icp"}, UnknownNameError, "refine"),
    ],
)
def test_bad_input_names_the_input(src, dst, kwargs, error, match):
    with pytest.raises(error, match=match):
        sgloc.register(src, dst, **kwargs)


@pytest.mark.parametrize("ratio", [0.0, 0.5, 0.9])
@pytest.mark.parametrize("scoring", ["msac", "count"])
def test_compiled_ransac_equals_numpy(ratio, scoring):
    cfg = RansacConfig(threshold=5.0, scoring=scoring, dof=6, max_tilt=None)
    for seed in range(8):
        cs = make_correspondences(120, ratio, np.random.default_rng(seed))
        a = ransac_reference(cs.src, cs.dst, cfg, np.random.default_rng(seed))
        b = ransac_compiled(cs.src, cs.dst, cfg, np.random.default_rng(seed))
        assert np.array_equal(a.inliers, b.inliers)
        assert (a.transform is None) == (b.transform is None)
        if a.transform is not None:
            assert np.abs(a.transform - b.transform).max() < 1e-9


def test_compiled_ransac_degenerate_inputs_as_numpy():
    line = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
    for src in (line, line[:2]):
        cfg = RansacConfig(dof=6, max_tilt=None)
        a = ransac_reference(src, src, cfg)
        b = ransac_compiled(src, src, cfg)
        assert a.transform is None and b.transform is None and a.reason == b.reason


def test_compiled_fits_equal_numpy():
    for seed in range(6):
        cs = make_correspondences(80, 0.3, np.random.default_rng(seed))
        w = np.random.default_rng(seed).uniform(0.5, 2.0, 80)
        T_w = weighted_kabsch(cs.src, cs.dst, w)
        assert np.abs(fit.kabsch(cs.src, cs.dst, w) - T_w).max() < 1e-9
        T0 = weighted_kabsch(cs.src, cs.dst)
        ref = irls_refine(cs.src, cs.dst, T0, w)
        assert np.abs(fit.irls(cs.src, cs.dst, T0, w, 15) - ref).max() < 1e-9


def test_compiled_fit_reflection_guard_planar_and_median():
    rng = np.random.default_rng(7)
    src = rng.normal(size=(30, 3)) * [50.0, 20.0, 5.0]
    for dst in (src * [1.0, 1.0, -1.0], src * [1.0, 1.0, 0.0] + 3.0, src[:, [1, 0, 2]]):
        ref = weighted_kabsch(src, dst)
        T = fit.kabsch(src, dst, np.ones(len(src)))
        assert np.abs(T - ref).max() < 1e-9
        assert np.linalg.det(T[:3, :3]) > 0
    for n in (1, 2, 3, 4, 9, 10, 101):
        x = rng.normal(size=n)
        x[: n // 3] = x[0]  # ties
        assert fit.median(x) == np.median(x)


def test_import_sgloc_stays_light():
    """numba, the kernels and scipy.stats load on first use, not on `import sgloc`."""
    import subprocess
    import sys

    code = ("import sys, sgloc; heavy = [m for m in ('numba', "
            "'sgloc.consistency.pairwise_kernels', "
            "'scipy.stats', 'matplotlib', 'dask') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_covariance_is_computed_when_asked_and_settings_are_reused():
    """A registration loop pays neither for a covariance it never reads nor for re-checking
    the same settings; the covariance is the one `transform_covariance` gives."""
    from sgloc import register
    from sgloc.estimation.covariance import transform_covariance
    from sgloc.pipeline.registration import settings_cache_info

    rng = np.random.default_rng(3)
    src = rng.uniform(-50, 50, (200, 3))
    dst = src + [3.0, 1.0, 0.0]
    before = settings_cache_info().hits
    a = register(src, dst, noise_bound=1.0, seed=0, eta=0.5)
    b = register(src, dst, noise_bound=1.0, seed=0, eta=0.5)
    assert settings_cache_info().hits > before
    assert "covariance" not in a.__dict__  # not computed yet
    f = a.fitted
    expected = transform_covariance(f.src, f.dst, a.transform, None, f.dof, f.max_tilt)
    np.testing.assert_array_equal(a.covariance, expected)
    np.testing.assert_array_equal(a.transform, b.transform)
    with pytest.raises(Exception, match="eta"):
        register(src, dst, noise_bound=1.0, eta=True)  # a bool is still refused
