"""Numpy reference of `sgloc.estimation.irls_refine`'s kernels (`sgloc.estimation.fit_kernels`):
the same Tukey IRLS loop, fitted by `fit_rigid` / `anisotropic_fit` in numpy."""

from __future__ import annotations

import numpy as np

from sgloc.estimation.fits import fit_rigid
from sgloc.estimation.refine import anisotropic_fit, class_scales
from sgloc.kernels.constants import MAD_SCALE, TUKEY_C


def irls_refine(
    src: np.ndarray,
    dst: np.ndarray,
    T: np.ndarray,
    weights: np.ndarray | None = None,
    iterations: int = 15,
    dof: int = 6,
    max_tilt: float | None = None,
    classes: np.ndarray | None = None,
    class_axes: str = "full",
) -> np.ndarray:
    """`sgloc.estimation.irls_refine` in numpy (the same arguments and decisions)."""
    prior = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    w_prev = None
    for _ in range(iterations):
        d = src @ T[:3, :3].T + T[:3, 3] - dst
        r = np.linalg.norm(d, axis=1)
        sigma = MAD_SCALE * np.median(r)
        if sigma <= 1e-12:
            break
        if classes is not None:
            s_xy, s_z = class_scales(d, classes, sigma, class_axes)
            u = np.sqrt((d[:, 0] ** 2 + d[:, 1] ** 2) / s_xy**2 + d[:, 2] ** 2 / s_z**2) / TUKEY_C
        else:
            u = r / (TUKEY_C * sigma)
        w = prior * np.where(u < 1.0, (1.0 - u**2) ** 2, 0.0)
        if np.count_nonzero(w) < 3:
            break
        # The fit is a function of the weights alone: unchanged weights, unchanged fit.
        if w_prev is not None and np.allclose(w, w_prev, rtol=0.0, atol=1e-6):
            break
        w_prev = w
        if classes is not None:
            T_new = anisotropic_fit(src, dst, T, w / s_xy**2, w / s_z**2, dof, max_tilt)
        else:
            T_new = fit_rigid(src, dst, w, dof, max_tilt)
        done = np.abs(T_new - T).max() < 1e-9
        T = T_new
        if done:
            break
    return T
