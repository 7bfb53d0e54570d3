"""estimate_pose: outlier rejection -> RANSAC -> the final fit on its inliers (with the motion
model's tilt checks); the middle of both `localize` and `register`."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sgloc.errors import DegenerateGeometryError
from sgloc.estimation.fits import check_not_degenerate, fit_rigid, tilt_deg, weighted_kabsch
from sgloc.estimation.motion import MotionModel
from sgloc.estimation.ransac import RansacConfig, ransac
from sgloc.estimation.refine import irls_refine
from sgloc.runtime.timing import StageTimer

#: Final fits on RANSAC's inliers: "irls" (weighted least squares, then the Tukey IRLS),
#: "kabsch" (weighted least squares, paper Eq. 4), "none" (RANSAC's own refit).
REFINES = ("irls", "kabsch", "none")

#: rejector(src, dst, scores or None) -> indices of the matches kept (`sgloc.rejection`).
Rejector = Callable[[np.ndarray, np.ndarray, np.ndarray | None], np.ndarray]


@dataclass(frozen=True)
class FinalFit:
    """How the final transform is fitted on RANSAC's inliers.

    refine: one of REFINES.
    class_axes: with refine="irls" and match labels, per-class residual scales ("full" or
        "height", `irls_refine`); None: one scale for all matches.
    icp: a last refinement T -> T (e.g. ICP on every object of two graphs); None: none.
    """

    refine: str = "irls"
    class_axes: str | None = None
    icp: Callable[[np.ndarray], np.ndarray] | None = None


@dataclass
class PoseEstimate:
    """Outcome of `estimate_pose`: `transform` (4x4 T_dst_src) is None when no model is
    accepted (`reason` says why); `survivors` (sorted indices of the input matches kept by
    rejection) and `inliers` (RANSAC's inliers among them, as input indices)."""

    transform: np.ndarray | None
    survivors: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    reason: str = ""


def estimate_pose(
    src: np.ndarray,
    dst: np.ndarray,
    rejector: Rejector,
    config: RansacConfig,
    rng: np.random.Generator,
    *,
    scores: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    labels: np.ndarray | None = None,
    fit: FinalFit = FinalFit(),
    timer: StageTimer | None = None,
) -> PoseEstimate:
    """T_dst_src from matches src[i] <-> dst[i] ((m,3) each, metres): outlier rejection
    (`rejector`, given the match `scores`), RANSAC (`config`, its motion model, `rng`), then
    the final fit (`fit`, `final_fit`) on RANSAC's inliers under the same motion model.

    weights: (m,) per-match weights of RANSAC's refits and the final fit (None: equal).
    labels: (m,) class of each match, for `fit.class_axes` (unused without).
    timer: times the stages "rejection", "ransac" and "estimation" (the final fit).
    """
    timer = timer or StageTimer()
    with timer("rejection"):
        kept = np.zeros(0, np.int64)
        if len(src):
            kept = np.asarray(rejector(src, dst, scores), dtype=np.int64)
    with timer("ransac"):
        w = None if weights is None else weights[kept]
        rs = ransac(src[kept], dst[kept], config, rng, w)
    inliers = kept[rs.inliers]
    with timer("estimation"):
        T, reason = rs.transform, rs.reason
        if T is not None and fit.refine != "none":
            classes = None if labels is None else labels[inliers]
            w_in = None if w is None else w[rs.inliers]
            T, reason = final_fit(
                src[inliers], dst[inliers], config.motion, config.threshold, w_in, classes, fit
            )
    return PoseEstimate(T, kept, inliers, reason)


def final_fit(
    src: np.ndarray,
    dst: np.ndarray,
    motion: MotionModel,
    threshold: float,
    weights: np.ndarray | None = None,
    classes: np.ndarray | None = None,
    fit: FinalFit = FinalFit(),
) -> tuple[np.ndarray | None, str]:
    """The fit of T_dst_src on matched points (RANSAC's inliers): weighted least squares under
    `motion`, then the optional IRLS and `fit.icp`; (transform or None, reason). Refused when
    the points are degenerate (dof=6) or the alignment tilts the up axis beyond
    `motion.max_tilt`, also when the matches demand that tilt (`demanded_tilt`; `threshold`:
    RANSAC's inlier distance, metres)."""
    dof, max_tilt = motion.dof, motion.max_tilt
    if dof == 6:
        try:
            check_not_degenerate(src, "matched points")
        except DegenerateGeometryError as e:
            return None, str(e)
    transform = fit_rigid(src, dst, weights, dof, max_tilt)
    # A tilted fit is the free fit itself (fit_rigid): only one held to yaw may be refused.
    if dof == 4 and max_tilt is not None and transform[2, 2] == 1.0:
        tilt = demanded_tilt(src, dst, weights, transform, threshold)
        if tilt > max_tilt:
            return None, tilt_reason(tilt, max_tilt)
    if fit.refine == "irls":
        plain = transform
        transform = irls_refine(
            src, dst, transform, weights, dof=dof, max_tilt=max_tilt,
            classes=classes if fit.class_axes else None, class_axes=fit.class_axes or "full",
        )  # fmt: skip
        if not np.all(np.isfinite(transform)):
            # Never hand on a non-finite pose: keep the plain fit if the refit ever fails.
            transform = plain
    if fit.icp is not None:
        transform = fit.icp(transform)
    if max_tilt is not None:
        tilt = tilt_deg(transform[:3, :3])
        if tilt > max(max_tilt, 1e-6):
            return None, tilt_reason(tilt, max_tilt)
    return transform, ""


def demanded_tilt(
    src: np.ndarray,
    dst: np.ndarray,
    weights: np.ndarray | None,
    fit: np.ndarray,
    threshold: float,
) -> float:
    """The tilt (degrees) the matches demand: that of their free rigid fit when it explains
    them clearly better than the gravity-bound `fit` (RMS residual lower by more than a tenth
    of the RANSAC threshold), else 0. A yaw-only fit of maps that do not share gravity is
    wrong by their tilt; noisy heights on a narrow strip tilt the free fit without need."""
    try:
        free = weighted_kabsch(src, dst, weights)
    except DegenerateGeometryError:
        return 0.0  # (nearly) collinear: the tilt about their line is not observable

    def rms(T: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((src @ T[:3, :3].T + T[:3, 3] - dst) ** 2, 1))))

    if rms(fit) - rms(free) <= 0.1 * threshold:
        return 0.0
    return float(tilt_deg(free[:3, :3]))


def tilt_reason(tilt: float, max_tilt: float) -> str:
    """Why an alignment tilting the up axis by `tilt` degrees (> `max_tilt`) is refused."""
    return (
        f"the alignment tilts the up axis by {tilt:.0f} deg (> max_tilt {max_tilt} deg): the "
        "maps do not share gravity (--set max_tilt=null --set dof=6 for any orientation; "
        "Python: max_tilt=None, dof=6), or one is mirrored or upside down"
    )
