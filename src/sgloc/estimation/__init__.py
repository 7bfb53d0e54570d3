"""Pose estimation, by job: `fits` (closed-form fits: weighted Kabsch/Umeyama, paper Eq. 4,
the 4-dof yaw fit, minimal-sample hypotheses), `ransac` (one adaptive loop, numpy or compiled
scoring), `refine` (Tukey IRLS, per-class scales, ICP), `pose` (`estimate_pose`: rejection ->
RANSAC -> final fit) and `motion` (`MotionModel`: dof and gravity tilt)."""

from sgloc.estimation.fits import (
    COLLINEAR_RATIO,
    GUO_SAMPLE,
    check_not_degenerate,
    draw_pairs,
    draw_triplets,
    fit_rigid,
    kabsch_batch,
    non_collinear,
    rigid_from_triplets,
    rot_z,
    sample_hypotheses,
    squared_residuals,
    tilt_deg,
    upright,
    weighted_kabsch,
    yaw_fit,
    yaw_from_pairs,
)
from sgloc.estimation.motion import ANY_RIGID, GROUND_VEHICLE, MotionModel
from sgloc.estimation.pose import (
    REFINES,
    FinalFit,
    PoseEstimate,
    demanded_tilt,
    estimate_pose,
    final_fit,
    tilt_reason,
)
from sgloc.estimation.ransac import (
    FindInliers,
    Fit,
    RansacConfig,
    RansacResult,
    Scorer,
    adaptive_search,
    finish,
    needed_draws,
    no_hypothesis_reason,
    ransac,
    ransac_compiled,
    ransac_reference,
)
from sgloc.estimation.refine import (
    CLASS_AXES,
    MIN_CLASS_MATCHES,
    MIN_SCALE_RATIO,
    anisotropic_fit,
    class_scales,
    icp_refine,
    irls_refine,
)

__all__ = [
    "ANY_RIGID", "CLASS_AXES", "COLLINEAR_RATIO", "GROUND_VEHICLE", "GUO_SAMPLE",
    "MIN_CLASS_MATCHES", "MIN_SCALE_RATIO", "REFINES", "FinalFit", "FindInliers", "Fit",
    "MotionModel", "PoseEstimate", "RansacConfig", "RansacResult", "Scorer", "adaptive_search",
    "anisotropic_fit", "check_not_degenerate", "class_scales", "demanded_tilt", "draw_pairs",
    "draw_triplets", "estimate_pose", "final_fit", "finish", "fit_rigid", "icp_refine",
    "irls_refine", "kabsch_batch", "needed_draws", "no_hypothesis_reason", "non_collinear",
    "ransac", "ransac_compiled", "ransac_reference", "rigid_from_triplets", "rot_z",
    "sample_hypotheses", "squared_residuals", "tilt_deg", "tilt_reason", "upright",
    "weighted_kabsch", "yaw_fit", "yaw_from_pairs",
]  # fmt: skip
