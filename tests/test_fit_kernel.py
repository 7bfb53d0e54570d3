"""The compiled class-scaled robust refit (sgloc.estimation.fit_kernels.irls_class_scaled) equals
the numpy reference of `sgloc.estimation.irls_refine` (tests/references/estimation.py), under
every motion model."""

from __future__ import annotations

import numpy as np
import pytest
from references import estimation as reference

from sgloc.estimation import irls_refine, tilt_deg, weighted_kabsch
from sgloc.geometry import apply, random_rigid_transform

MODELS = [(6, None), (6, 15.0), (4, 15.0), (4, None), (4, 1.0)]


def _refit(path, *args, **kw):
    """`irls_refine` on the compiled kernels or on the numpy reference."""
    return (irls_refine if path == "compiled" else reference.irls_refine)(*args, **kw)


@pytest.mark.parametrize("axes", ["full", "height"])
@pytest.mark.parametrize("dof,max_tilt", MODELS)
def test_compiled_class_scaled_refit_equals_reference(axes, dof, max_tilt):
    rng = np.random.default_rng([dof, int(max_tilt or 0), len(axes)])
    for _ in range(15):
        n = int(rng.integers(4, 90))
        src = rng.uniform(-80, 80, (n, 3)) * [1, 1, 0.1]
        T = random_rigid_transform(rng, 50.0, 5.0)
        dst = apply(T, src) + rng.normal(0, 1, (n, 3)) * rng.uniform(0.01, 2, (n, 1))
        dst[: n // 5] += rng.normal(0, 10, (n // 5, 3))  # outliers
        args = (src, dst, weighted_kabsch(src, dst), rng.uniform(0.5, 2, n))
        kw = {"dof": dof, "max_tilt": max_tilt, "classes": rng.integers(0, 4, n) * 3}
        ref = _refit("reference", *args, class_axes=axes, **kw)
        got = _refit("compiled", *args, class_axes=axes, **kw)
        np.testing.assert_allclose(got, ref, atol=1e-9)
        if max_tilt is not None:
            assert tilt_deg(got[:3, :3]) <= max(max_tilt, tilt_deg(args[2][:3, :3])) + 1e-9


def test_compiled_refit_refuses_unknown_axes():
    src = np.random.default_rng(0).uniform(-10, 10, (10, 3))
    with pytest.raises(ValueError, match="axes"):
        _refit("compiled", src, src, np.eye(4), classes=np.zeros(10), class_axes="x")


@pytest.mark.parametrize("path", ["compiled", "reference"])
@pytest.mark.parametrize("dof,max_tilt", MODELS)
def test_refit_on_degenerate_matches_is_a_rotation(path, dof, max_tilt):
    # Every match on one target point (H = 0), and collinear points (rank 1): the fit is not
    # unique, but it must still be a finite proper rotation, never NaN.
    rng = np.random.default_rng(7)
    src = rng.uniform(-20, 20, (8, 3))
    line = np.c_[np.arange(8.0), np.zeros(8), np.zeros(8)]
    for s, d in ((src, np.repeat(src[:1] + 3.0, 8, axis=0)), (line, line + [1.0, 2.0, 0.0])):
        T = _refit(path, s, d, np.eye(4), None, dof=dof, max_tilt=max_tilt)
        R = T[:3, :3]
        assert np.isfinite(T).all()
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
        assert np.linalg.det(R) == pytest.approx(1.0)
