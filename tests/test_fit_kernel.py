"""The compiled class-scaled robust refit (sgloc.kernels.fit.irls_class_scaled) equals the numpy
reference of `sgloc.estimation.irls_refine`, under every motion model."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc import kernels
from sgloc.estimation import irls_refine, tilt_deg, weighted_kabsch
from sgloc.geometry import apply, random_rigid_transform

MODELS = [(6, None), (6, 15.0), (4, 15.0), (4, None), (4, 1.0)]


def _refit(path, monkeypatch, *args, **kw):
    monkeypatch.setattr(kernels, "FORCE", path)
    return irls_refine(*args, **kw)


@pytest.mark.parametrize("axes", ["full", "height"])
@pytest.mark.parametrize("dof,max_tilt", MODELS)
def test_compiled_class_scaled_refit_equals_reference(monkeypatch, axes, dof, max_tilt):
    rng = np.random.default_rng([dof, int(max_tilt or 0), len(axes)])
    for _ in range(15):
        n = int(rng.integers(4, 90))
        src = rng.uniform(-80, 80, (n, 3)) * [1, 1, 0.1]
        T = random_rigid_transform(rng, 50.0, 5.0)
        dst = apply(T, src) + rng.normal(0, 1, (n, 3)) * rng.uniform(0.01, 2, (n, 1))
        dst[: n // 5] += rng.normal(0, 10, (n // 5, 3))  # outliers
        args = (src, dst, weighted_kabsch(src, dst), rng.uniform(0.5, 2, n))
        kw = {"dof": dof, "max_tilt": max_tilt, "classes": rng.integers(0, 4, n) * 3}
        ref = _refit("reference", monkeypatch, *args, class_axes=axes, **kw)
        got = _refit("compiled", monkeypatch, *args, class_axes=axes, **kw)
        np.testing.assert_allclose(got, ref, atol=1e-9)
        if max_tilt is not None:
            assert tilt_deg(got[:3, :3]) <= max(max_tilt, tilt_deg(args[2][:3, :3])) + 1e-9


def test_compiled_refit_refuses_unknown_axes(monkeypatch):
    src = np.random.default_rng(0).uniform(-10, 10, (10, 3))
    with pytest.raises(ValueError, match="axes"):
        _refit("compiled", monkeypatch, src, src, np.eye(4), classes=np.zeros(10), class_axes="x")
