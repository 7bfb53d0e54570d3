"""Correspondence-level registration: matched points in, T_dst_src out.

    res = sgloc.register(src, dst, rejection="neighbor", noise_bound=0.5, seed=0)
    res.transform  # 4x4 T_dst_src, or None when res.success is False (res.reason says why)

The drop-in for TEASER++ / KISS-Matcher's `solve` on given correspondences: outlier rejection
(`sgloc.rejection`), RANSAC (`sgloc.estimation.ransac`) and a final robust fit on its inliers:
`sgloc.estimation.estimate_pose`, the middle of `localize` too.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from sgloc.errors import SglocError, UnknownNameError
from sgloc.estimation import (
    ANY_RIGID,
    REFINES,
    FinalFit,
    MotionModel,
    RansacConfig,
    estimate_pose,
)
from sgloc.estimation.covariance import FittedPoints
from sgloc.rejection import REJECTORS, Rejector, make_rejector
from sgloc.runtime.timing import StageTimer
from sgloc.validation import random_generator


@dataclass
class RegistrationResult:
    """Outcome of `register`.

    success: a transform was found with enough inliers.
    transform: (4,4) T_dst_src (p_dst = R p_src + t), None when not successful.
    inliers: sorted indices of the input matches the transform explains (RANSAC's inliers).
    survivors: sorted indices of the matches kept by outlier rejection.
    timings: seconds per stage: rejection, ransac, refine (the final fit), total.
    reason: why it failed ("" on success).
    covariance: (6,6) covariance of `transform` (None when not successful): tangent order
        [rx, ry, rz, tx, ty, tz] (rad, m), T_true = transform @ Exp(xi), xi in the src frame;
        the inflation measured on object maps (`sgloc.estimation.covariance`; for other data call
        `transform_covariance(..., inflation=NO_INFLATION)` for the plain least-squares one).
    """

    success: bool
    transform: np.ndarray | None
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    survivors: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    timings: dict[str, float] = field(default_factory=dict)
    reason: str = ""
    #: The inlier points the covariance is computed from, on first access.
    fitted: FittedPoints | None = field(default=None, repr=False)

    @cached_property
    def covariance(self) -> np.ndarray | None:
        """(6,6) covariance of `transform` (see the class docstring), computed when first
        asked for (a registration loop that never reads it does not pay for it)."""
        return None if self.fitted is None else self.fitted.covariance(self.transform)


def _points(a: Any, name: str) -> np.ndarray:
    p = np.asarray(a, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise SglocError(f"{name} must be an (m,3) array of points, got shape {p.shape}.")
    if not np.isfinite(p).all():
        raise SglocError(f"{name} holds NaN or infinite coordinates; drop those matches first.")
    return p


def _rejector_fields(cls: type[Rejector]) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else set()


def _settings_for_call(
    rejection: str | Rejector, noise_bound: float, motion: MotionModel, settings: dict[str, Any]
) -> tuple[Rejector, RansacConfig]:
    """`_stage_settings`, built once per distinct (rejection name, noise bound, motion,
    settings) and reused: a registration loop does not re-check its settings every call
    (rejectors and RansacConfig hold no state a call changes)."""
    if not isinstance(rejection, str):
        return _stage_settings(rejection, noise_bound, motion, settings)
    key = tuple(sorted((k, type(v).__name__, v) for k, v in settings.items()))
    try:
        hash(key)
    except TypeError:  # a list or dict value: built for this call only
        return _stage_settings(rejection, noise_bound, motion, settings)
    return _cached_stage_settings(rejection, float(noise_bound), motion, key)


@functools.lru_cache(maxsize=64)
def _cached_stage_settings(
    rejection: str, noise_bound: float, motion: MotionModel, key: tuple
) -> tuple[Rejector, RansacConfig]:
    return _stage_settings(rejection, noise_bound, motion, {k: v for k, _, v in key})


def settings_cache_info() -> functools._CacheInfo:
    """Hits and misses of the per-settings cache of `register` (lru_cache statistics)."""
    return _cached_stage_settings.cache_info()


def _stage_settings(
    rejection: str | Rejector,
    noise_bound: float,
    motion: MotionModel,
    settings: dict[str, Any],
) -> tuple[Rejector, RansacConfig]:
    """The rejector and RANSAC settings: tau and threshold default to 2 * noise_bound (two
    correct matches' pair distances differ by at most twice the noise bound); other settings
    are routed by name to the rejector or to RansacConfig."""
    if isinstance(rejection, Rejector):
        rej_cls, rej = type(rejection), rejection
    else:
        rej_cls, rej = REJECTORS.lookup(rejection), None
    rej_fields = _rejector_fields(rej_cls)
    ransac_fields = {f.name for f in dataclasses.fields(RansacConfig)}
    unknown = set(settings) - rej_fields - ransac_fields
    if unknown:
        raise UnknownNameError(
            f"unknown register setting(s) {', '.join(sorted(unknown))}; rejection "
            f"{rej_cls.name!r} takes {', '.join(sorted(rej_fields)) or 'none'}, RANSAC takes "
            f"{', '.join(sorted(ransac_fields))}."
        )
    if rej is None:
        params = {k: v for k, v in settings.items() if k in rej_fields}
        if "tau" in rej_fields:
            params.setdefault("tau", 2.0 * noise_bound)
        rej = make_rejector(rej_cls.name, **params)
    fields = {"threshold": 2.0 * noise_bound, "dof": motion.dof, "max_tilt": motion.max_tilt}
    fields |= {k: v for k, v in settings.items() if k in ransac_fields}
    return rej, RansacConfig(**fields)


def register(
    src: np.ndarray,
    dst: np.ndarray,
    rejection: str | Rejector = "neighbor",
    noise_bound: float = 2.5,
    seed: int | None = 0,
    refine: str = "irls",
    rng: np.random.Generator | None = None,
    motion: MotionModel = ANY_RIGID,
    **settings: Any,
) -> RegistrationResult:
    """Rigid transform T_dst_src from matched points src[i] <-> dst[i] ((m,3) each, metres).

    rejection: a name in `sgloc.rejection.REJECTORS` ("neighbor": the paper's Alg. 1, "none",
        "spectral", "clique") or a Rejector instance.
    noise_bound: metres; the largest residual of a correct match. Sets the consistency
        tolerance tau and the RANSAC inlier threshold to 2 * noise_bound unless given.
    seed / rng: RANSAC's randomness (rng wins when given).
    refine: final fit on RANSAC's inliers: "irls" (Tukey M-estimator), "kabsch", "none"
        (`sgloc.estimation.FinalFit`).
    motion: the motion model (`sgloc.estimation.MotionModel`); by default any rigid motion,
        as correspondences may come in any orientation. The flat settings dof= and max_tilt=
        override its fields.
    settings: rejector parameters (tau, eta, form, scope, local_radius, ...) and RansacConfig
        fields (threshold, iterations, confidence, min_inliers, ...).

    Rejection, RANSAC and the final fit are `sgloc.estimation.estimate_pose`, as in `localize`.
    """
    src, dst = _points(src, "src"), _points(dst, "dst")
    if len(src) != len(dst):
        raise SglocError(
            f"src and dst must hold the same number of matched points, got {len(src)} and "
            f"{len(dst)}; row i of each is match i."
        )
    if not noise_bound > 0:
        raise SglocError(f"noise_bound must be > 0 metres, got {noise_bound}.")
    if refine not in REFINES:
        raise UnknownNameError(f"unknown refine {refine!r}; choose one of {', '.join(REFINES)}.")
    rej, cfg = _settings_for_call(rejection, noise_bound, motion, settings)
    timer = StageTimer(names={"estimation": "refine"})
    pose = estimate_pose(
        src, dst, rej, cfg, rng if rng is not None else random_generator(seed),
        fit=FinalFit(refine=refine), timer=timer,
    )  # fmt: skip
    return RegistrationResult(
        success=pose.transform is not None,
        transform=pose.transform,
        inliers=pose.inliers,
        survivors=pose.survivors,
        timings=timer.timings,
        reason=pose.reason,
        fitted=FittedPoints(src[pose.inliers], dst[pose.inliers], None, cfg.motion.dof,
                            cfg.motion.max_tilt),  # fmt: skip
    )
