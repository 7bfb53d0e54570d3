"""Correspondence-level registration: matched points in, T_dst_src out.

    res = sgloc.register(src, dst, rejection="neighbor", noise_bound=0.5, seed=0)
    res.transform  # 4x4 T_dst_src, or None when res.success is False (res.reason says why)

The drop-in for TEASER++ / KISS-Matcher's `solve` on given correspondences: outlier rejection
(`sgloc.rejection`), RANSAC (`sgloc.estimation.ransac`) and a final robust fit on its inliers.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sgloc.errors import SglocError, UnknownNameError
from sgloc.estimation import RansacConfig, irls_refine, ransac, weighted_kabsch
from sgloc.kernels import use_compiled
from sgloc.registry import lookup
from sgloc.rejection import REJECTORS, Rejector, make_rejector

#: Final fits on RANSAC's inliers: "irls" (Tukey biweight, as `localize`), "kabsch" (least
#: squares), "none" (RANSAC's own refit).
REFINES = ("irls", "kabsch", "none")


@dataclass
class RegistrationResult:
    """Outcome of `register`.

    success: a transform was found with enough inliers.
    transform: (4,4) T_dst_src (p_dst = R p_src + t), None when not successful.
    inliers: sorted indices of the input matches the transform explains (RANSAC's inliers).
    survivors: sorted indices of the matches kept by outlier rejection.
    timings: seconds per stage: rejection, ransac, refine, total.
    reason: why it failed ("" on success).
    """

    success: bool
    transform: np.ndarray | None
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    survivors: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    timings: dict[str, float] = field(default_factory=dict)
    reason: str = ""


def _points(a: Any, name: str) -> np.ndarray:
    p = np.asarray(a, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise SglocError(f"{name} must be an (m,3) array of points, got shape {p.shape}.")
    if not np.isfinite(p).all():
        raise SglocError(f"{name} holds NaN or infinite coordinates; drop those matches first.")
    return p


def _rejector_fields(cls: type[Rejector]) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else set()


def _stage_settings(
    rejection: str | Rejector, noise_bound: float, settings: dict[str, Any]
) -> tuple[Rejector, RansacConfig]:
    """The rejector and RANSAC settings: tau and threshold default to 2 * noise_bound (two
    correct matches' pair distances differ by at most twice the noise bound); other settings
    are routed by name to the rejector or to RansacConfig."""
    if isinstance(rejection, Rejector):
        rej_cls, rej = type(rejection), rejection
    else:
        rej_cls, rej = lookup(REJECTORS, rejection, "rejection"), None
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
    # Correspondences may come in any orientation: any rigid motion unless told otherwise.
    fields = {"threshold": 2.0 * noise_bound, "dof": 6, "max_tilt": None}
    fields |= {k: v for k, v in settings.items() if k in ransac_fields}
    return rej, RansacConfig(**fields)


def _final_fit(src: np.ndarray, dst: np.ndarray, refine: str) -> np.ndarray:
    """Least squares on the inliers, then the Tukey IRLS when refine == "irls" (the rule of
    `sgloc.estimation.weighted_kabsch` / `irls_refine`, compiled: `sgloc.kernels.fit`; those
    themselves for a small problem early in a process, `sgloc.kernels.use_compiled`)."""
    if not use_compiled(len(src)):
        T = weighted_kabsch(src, dst)  # RANSAC checked that the inliers are not degenerate
        return irls_refine(src, dst, T) if refine == "irls" else T
    from sgloc.kernels.fit import irls, kabsch

    ones = np.ones(len(src))
    T = kabsch(src, dst, ones)
    return irls(src, dst, T, ones, 15) if refine == "irls" else T


def register(
    src: np.ndarray,
    dst: np.ndarray,
    rejection: str | Rejector = "neighbor",
    noise_bound: float = 2.5,
    seed: int | None = 0,
    refine: str = "irls",
    rng: np.random.Generator | None = None,
    **settings: Any,
) -> RegistrationResult:
    """Rigid transform T_dst_src from matched points src[i] <-> dst[i] ((m,3) each, metres).

    rejection: a name in `sgloc.rejection.REJECTORS` ("neighbor": the paper's Alg. 1, "none",
        "spectral", "clique") or a Rejector instance.
    noise_bound: metres; the largest residual of a correct match. Sets the consistency
        tolerance tau and the RANSAC inlier threshold to 2 * noise_bound unless given.
    seed / rng: RANSAC's randomness (rng wins when given).
    refine: final fit on RANSAC's inliers: "irls" (Tukey M-estimator), "kabsch", "none".
    settings: rejector parameters (tau, eta, form, scope, local_radius, ...) and RansacConfig
        fields (threshold,
        iterations, confidence, min_inliers, ...).
    """
    t0 = time.perf_counter()
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
    rej, cfg = _stage_settings(rejection, noise_bound, settings)
    rng = rng if rng is not None else np.random.default_rng(seed)
    timings: dict[str, float] = {}

    t1 = time.perf_counter()
    kept = np.asarray(rej(src, dst, None), dtype=np.int64) if len(src) else np.zeros(0, np.int64)
    t2 = time.perf_counter()
    timings["rejection"] = t2 - t1
    rs = ransac(src[kept], dst[kept], cfg, rng)
    t3 = time.perf_counter()
    timings["ransac"] = t3 - t2
    inliers = kept[rs.inliers]
    T = rs.transform
    if T is not None and refine != "none":
        T = _final_fit(src[inliers], dst[inliers], refine)
    t4 = time.perf_counter()
    timings["refine"] = t4 - t3
    timings["total"] = t4 - t0
    return RegistrationResult(
        success=T is not None,
        transform=T,
        inliers=inliers,
        survivors=kept,
        timings=timings,
        reason=rs.reason if T is None else "",
    )
