"""The methods compared: sgloc rejectors + sgloc RANSAC, and peers when importable.

Every method maps (src (m,3), dst (m,3), tau, threshold, rng) to T_dst_src (4x4) or None. Its
final matches are then scored the same way for all: the pairs whose residual under the returned
transform is below `threshold` (for ours these are the RANSAC inliers; open3d's own fitness
ignores the given pairs, and KISS-Matcher returns no inlier list, so both are scored here).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sgloc.estimation import weighted_kabsch
from sgloc.geometry import make_transform
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.registration import register

Solver = Callable[[np.ndarray, np.ndarray, float, float, np.random.Generator], np.ndarray | None]


@dataclass
class Method:
    """A named solver; `note` says why it is unavailable (then `solve` is None)."""

    name: str
    solve: Solver | None
    note: str = ""
    ours: bool = False


def sgloc_method(rejection: str, **ransac_settings) -> Method:
    """sgloc's correspondence-level API, `sgloc.register`: rejector `rejection` (tau from the
    set), RANSAC (threshold from the set, other settings overridden by `ransac_settings`), then
    the final fit on its inliers (weighted Kabsch, plus the IRLS robust refit when the default
    LocalizerConfig has it on, as `localize` runs it)."""
    refine = "irls" if LocalizerConfig().robust_refit else "kabsch"

    def solve(src, dst, tau, threshold, rng):
        tau_setting = {} if rejection == "none" else {"tau": tau}
        res = register(
            src, dst, rejection, noise_bound=threshold / 2, refine=refine, rng=rng,
            threshold=threshold, **tau_setting, **ransac_settings,
        )  # fmt: skip
        return res.transform

    label = "RANSAC alone" if rejection == "none" else f"{rejection} + RANSAC"
    if ransac_settings:
        label += " (" + ", ".join(f"{v}" for v in ransac_settings.values()) + ")"
    return Method(label, solve, ours=True)


def _missing(name: str, module: str, why: Exception) -> Method:
    return Method(name, None, f"`{module}` not importable ({type(why).__name__}: {why})")


def kiss_matcher_method() -> Method:
    """KISS-Matcher's `prune_and_solve` (ROBIN max-clique pruning + GNC-TLS), single call.

    Its pairwise test accepts |d_q - d_t| <= 2 * robin_noise_bound, so the bound is tau / 2 (the
    same graph as ours); the solver bound must not exceed it, so it is tau / 2 too. Noise-bound
    clamping is disabled (it would silently cap both at 1 m)."""
    try:
        km = importlib.import_module("kiss_matcher")
    except Exception as e:  # noqa: BLE001 (any import failure means: skip this peer)
        return _missing("KISS-Matcher", "kiss_matcher", e)

    def solve(src, dst, tau, threshold, rng):
        cfg = km.KISSMatcherConfig(
            voxel_size=1.0,
            robin_noise_bound_gain=tau / 2,
            solver_noise_bound_gain=tau / 2,
            enable_noise_bound_clamping=False,
        )
        sol = km.KISSMatcher(cfg).prune_and_solve(src.astype(np.float32), dst.astype(np.float32))
        if not sol.valid:
            return None
        return make_transform(np.asarray(sol.rotation), np.asarray(sol.translation).ravel())

    return Method("KISS-Matcher", solve)


def _open3d():
    return importlib.import_module("open3d")


def _o3d_inputs(o3d, src, dst):
    ps, pt = o3d.geometry.PointCloud(), o3d.geometry.PointCloud()
    ps.points = o3d.utility.Vector3dVector(src)
    pt.points = o3d.utility.Vector3dVector(dst)
    idx = np.arange(len(src), dtype=np.int32)
    corres = o3d.utility.Vector2iVector(np.column_stack([idx, idx]))
    return ps, pt, corres


def open3d_ransac_method() -> Method:
    """open3d correspondence RANSAC (3-point samples, distance and edge-length checkers,
    up to 100,000 iterations at confidence 0.999)."""
    try:
        o3d = _open3d()
    except Exception as e:  # noqa: BLE001
        return _missing("open3d RANSAC", "open3d", e)
    reg = o3d.pipelines.registration

    def solve(src, dst, tau, threshold, rng):
        o3d.utility.random.seed(int(rng.integers(0, 2**31 - 1)))
        ps, pt, corres = _o3d_inputs(o3d, src, dst)
        res = reg.registration_ransac_based_on_correspondence(
            ps,
            pt,
            corres,
            threshold,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [
                reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                reg.CorrespondenceCheckerBasedOnDistance(threshold),
            ],
            reg.RANSACConvergenceCriteria(100_000, 0.999),
        )
        T = np.asarray(res.transformation)
        return None if np.allclose(T, np.eye(4)) and len(res.correspondence_set) == 0 else T

    return Method("open3d RANSAC", solve)


def open3d_fgr_method() -> Method:
    """open3d Fast Global Registration on the given correspondences (absolute scale,
    maximum correspondence distance = threshold)."""
    try:
        o3d = _open3d()
    except Exception as e:  # noqa: BLE001
        return _missing("open3d FGR", "open3d", e)
    reg = o3d.pipelines.registration

    def solve(src, dst, tau, threshold, rng):
        ps, pt, corres = _o3d_inputs(o3d, src, dst)
        opt = reg.FastGlobalRegistrationOption(
            use_absolute_scale=True, maximum_correspondence_distance=threshold
        )
        res = reg.registration_fgr_based_on_correspondence(ps, pt, corres, opt)
        return np.asarray(res.transformation)

    return Method("open3d FGR", solve)


def teaser_method() -> Method:
    """TEASER++ (max-clique pruning + TLS), when `teaserpp_python` is importable."""
    try:
        tp = importlib.import_module("teaserpp_python")
    except Exception as e:  # noqa: BLE001
        return _missing("TEASER++", "teaserpp_python", e)

    def solve(src, dst, tau, threshold, rng):
        p = tp.RobustRegistrationSolver.Params()
        p.cbar2 = 1.0
        p.noise_bound = tau / 2
        p.estimate_scaling = False
        p.rotation_estimation_algorithm = (
            tp.RobustRegistrationSolver.ROTATION_ESTIMATION_ALGORITHM.GNC_TLS
        )
        solver = tp.RobustRegistrationSolver(p)
        solver.solve(src.T.astype(np.float64), dst.T.astype(np.float64))
        sol = solver.getSolution()
        return make_transform(np.asarray(sol.rotation), np.asarray(sol.translation).ravel())

    return Method("TEASER++", solve)


def clipper_method() -> Method:
    """CLIPPER (graph-theoretic densest-clique relaxation) + sgloc's Kabsch on its selection,
    when `clipperpy` is importable."""
    try:
        cp = importlib.import_module("clipperpy")
    except Exception as e:  # noqa: BLE001
        return _missing("CLIPPER", "clipperpy", e)

    def solve(src, dst, tau, threshold, rng):
        iparams = cp.invariants.EuclideanDistanceParams()
        iparams.sigma = tau / 2
        iparams.epsilon = tau
        invariant = cp.invariants.EuclideanDistance(iparams)
        clipper = cp.CLIPPER(invariant, cp.Params())
        idx = np.arange(len(src))
        clipper.score_pairwise_consistency(src.T, dst.T, np.column_stack([idx, idx]))
        clipper.solve()
        sel = np.asarray(clipper.get_selected_associations())[:, 0]
        return weighted_kabsch(src[sel], dst[sel]) if len(sel) >= 3 else None

    return Method("CLIPPER", solve)


def all_methods() -> list[Method]:
    """Ours first, then the peers (unavailable ones carry a note and no solver)."""
    return [
        sgloc_method("none"),
        sgloc_method("neighbor"),
        sgloc_method("spectral"),
        sgloc_method("clique"),
        kiss_matcher_method(),
        open3d_ransac_method(),
        open3d_fgr_method(),
        teaser_method(),
        clipper_method(),
    ]
