"""Refinements of a fit on matched points: Tukey IRLS (optionally with per-class,
per-axis residual scales and the anisotropic fit they need) and mutual-nearest-neighbour ICP.

*Refine* here means improving one transform's fit on its matches (`register(refine=...)`,
`FinalFit.refine`, `icp_refine`). Re-estimating a transform on a new set of object pairs is a
*refit* (a link on grown maps: `sgloc.online.refine`; a hypothesis in
`sgloc.acceptance.verification`); the fleet's *joint refinement* is `sgloc.online.joint`."""

from __future__ import annotations

import numpy as np

from sgloc.errors import DegenerateGeometryError
from sgloc.estimation.fits import tilt_deg, weighted_kabsch
from sgloc.geometry import make_transform
from sgloc.kernels.constants import MAD_SCALE
from sgloc.lie import skew, so3_exp
from sgloc.maps.spatial import ClassKDTree


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
    """Refine T_dst_src on matched points (metres) by an M-estimator: iteratively reweighted
    least squares with Tukey's biweight, c = 4.685 * sigma, sigma re-estimated each round as
    1.4826 * the median residual (times the prior `weights`).

    A least-squares fit over RANSAC's inliers is pulled by wrong matches that fall inside the
    threshold (repeated objects); the biweight gives them zero weight once they stand out from
    the residual spread, so exact correspondences give the exact transform back, while on
    uniformly noisy matches (all residuals alike) it stays close to least squares.
    dof, max_tilt: the motion model of each fit (`fit_rigid`).
    classes: (m,) class id of each match: then each class gets its own residual scale,
        horizontal and vertical apart (`class_scales`), re-estimated each round, and each
        fit weighs a match's xy and z residuals by their inverse variances
        (`anisotropic_fit`). The centres of tall or extended objects (buildings, fences) move
        with the viewpoint, most in height; ground-level objects give precise heights: with
        the scales apart, those fix roll and pitch and the others count less.
    class_axes: with `classes`, "full" (per class, horizontal and vertical scales) or
        "height" (per class vertical scales; one horizontal scale shared by all matches).
    Compiled (`sgloc.estimation.fit_kernels`). Without matches, T comes back unchanged.
    """
    if len(src) == 0:
        return T
    prior = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    from sgloc.estimation.fit_kernels import irls_class_scaled, irls_model

    src, dst = (np.ascontiguousarray(a, dtype=np.float64) for a in (src, dst))
    T = np.ascontiguousarray(T, dtype=np.float64)
    if classes is None:
        return irls_model(src, dst, T, prior, iterations, dof, float(max_tilt or 0.0))
    if class_axes not in CLASS_AXES:
        raise ValueError(f"class scale axes must be one of {CLASS_AXES}, got {class_axes!r}")
    uniq, cls = np.unique(classes, return_inverse=True)
    return irls_class_scaled(
        src, dst, T, prior, cls.astype(np.int64), len(uniq), class_axes == "height",
        iterations, dof, float(max_tilt or 0.0), MIN_CLASS_MATCHES, MIN_SCALE_RATIO,
    )  # fmt: skip


#: Matches of a class needed to estimate its own residual scales.
MIN_CLASS_MATCHES = 5
#: Floor of a residual scale relative to the overall one (no class outweighs the rest by more
#: than its square on a few lucky residuals).
MIN_SCALE_RATIO = 0.02


#: What `class_scales` estimates per class: both axes, or the vertical one only.
CLASS_AXES = ("full", "height")


def class_scales(
    d: np.ndarray, classes: np.ndarray, sigma: float, axes: str = "full"
) -> tuple[np.ndarray, np.ndarray]:
    """Per match, the horizontal and vertical residual scales of its class: (s_xy, s_z), each
    (m,), metres per axis, from the residual vectors d (m,3) as 1.4826 * median |residual| per
    axis (xy: the 2D norm / sqrt 2). Classes with fewer than MIN_CLASS_MATCHES matches take the
    scales of all matches together; every scale is at least MIN_SCALE_RATIO * sigma.
    axes="height": only the vertical scale is per class; every match gets the horizontal scale
    of all matches together."""
    if axes not in CLASS_AXES:
        raise ValueError(f"class scale axes must be one of {CLASS_AXES}, got {axes!r}")
    h = np.linalg.norm(d[:, :2], axis=1) / np.sqrt(2.0)
    v = np.abs(d[:, 2])
    floor = max(MIN_SCALE_RATIO * sigma, 1e-9)
    all_xy, all_z = MAD_SCALE * np.median(h), MAD_SCALE * np.median(v)
    uniq, inv, cnt = np.unique(classes, return_inverse=True, return_counts=True)
    order = np.argsort(inv, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(cnt)])
    sxy, sz = np.empty(len(uniq)), np.empty(len(uniq))
    for c in range(len(uniq)):
        idx = order[bounds[c] : bounds[c + 1]]
        few = cnt[c] < MIN_CLASS_MATCHES
        sxy[c] = all_xy if few or axes == "height" else MAD_SCALE * np.median(h[idx])
        sz[c] = all_z if few else MAD_SCALE * np.median(v[idx])
    return np.maximum(sxy, floor)[inv], np.maximum(sz, floor)[inv]


def anisotropic_fit(
    src: np.ndarray,
    dst: np.ndarray,
    T: np.ndarray,
    w_xy: np.ndarray,
    w_z: np.ndarray,
    dof: int = 6,
    max_tilt: float | None = None,
    steps: int = 5,
) -> np.ndarray:
    """T_dst_src minimising sum_i w_xy_i |xy residual_i|^2 + w_z_i (z residual_i)^2, by
    Gauss-Newton from T (a few steps; rotations updated on the manifold). The motion model of
    `fit_rigid`: dof=4 with a tilt tolerance `max_tilt` (degrees) and dof=6 update the whole
    rotation, and with `max_tilt` set a step that would tilt the up axis beyond it is not
    taken; dof=4 without a tolerance updates yaw and translation only (roll and pitch stay as
    in T)."""
    cols = [2, 3, 4, 5] if dof == 4 and not max_tilt else [0, 1, 2, 3, 4, 5]
    W = np.stack([w_xy, w_xy, w_z], axis=1)
    for _ in range(steps):
        p = src @ T[:3, :3].T + T[:3, 3]
        c = (w_xy @ p) / max(w_xy.sum(), 1e-300)
        q = p - c
        J = np.zeros((len(p), 3, 6))  # d(p)/d(rotation vector, translation) about c
        J[:, :, :3] = skew(-q)  # d(w x q)/dw = -[q]x
        J[:, 0, 3] = J[:, 1, 4] = J[:, 2, 5] = 1.0
        J = J[:, :, cols]
        H = np.einsum("nki,nk,nkj->ij", J, W, J)
        g = np.einsum("nki,nk,nk->i", J, W, dst - p)
        try:
            x = np.zeros(6)
            x[cols] = np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        dR = so3_exp(x[:3])
        R = dR @ T[:3, :3]
        if max_tilt and len(cols) == 6 and tilt_deg(R) > max_tilt:
            break
        T = make_transform(R, dR @ (T[:3, 3] - c) + c + x[3:])
        if np.abs(x).max() < 1e-12:
            break
    return T


def icp_refine(
    src: np.ndarray,
    src_labels: np.ndarray,
    dst: np.ndarray,
    dst_labels: np.ndarray,
    T: np.ndarray,
    max_distance: float = 5.0,
    iterations: int = 10,
) -> np.ndarray:
    """Refine T_dst_src by point-to-point ICP between two object sets (metres).

    Each round pairs objects that are MUTUAL nearest same-class neighbours closer than
    `max_distance` after the current transform (one-to-one, so repeated objects cannot pile onto
    one target), then refits with the Kabsch. Stops when the pairing no longer changes.
    """
    extent = np.abs(np.concatenate([src, dst])).max()
    tree_dst = ClassKDTree(dst, dst_labels, max_distance, extent=extent)
    pairs_prev = None
    for _ in range(iterations):
        moved = src @ T[:3, :3].T + T[:3, 3]
        d, j = tree_dst.query(moved, src_labels, max_distance)
        _, i_back = ClassKDTree(moved, src_labels, max_distance, extent=extent).query(
            dst, dst_labels
        )
        ok = np.isfinite(d)
        ok[ok] &= i_back[j[ok]] == np.flatnonzero(ok)
        if ok.sum() < 3:
            break
        pairs = np.flatnonzero(ok), j[ok]
        if pairs_prev is not None and all(
            np.array_equal(a, b) for a, b in zip(pairs, pairs_prev, strict=True)
        ):
            break
        try:
            T = weighted_kabsch(src[pairs[0]], dst[pairs[1]])
        except DegenerateGeometryError:
            break
        pairs_prev = pairs
    return T
