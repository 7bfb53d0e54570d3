"""The covariance of a fitted rigid transform T_dst_src (GTSAM Pose3 convention).

Convention: tangent vector xi = [rx, ry, rz, tx, ty, tz] (radians, metres), right perturbation
T_true = T_est @ Exp(xi), so xi is expressed in the SOURCE (query) frame, at its origin; this is
`gtsam.Pose3`'s Logmap / Expmap and the noise model of a `BetweenFactorPose3(target, query)`
(`sgloc.lie` holds Exp, Log and the skew matrices in this convention).

Model (`transform_covariance`):
1. The least-squares fit's covariance. Residuals r_i = R src_i + t - dst_i; a right
   perturbation moves them by R (-[src_i]x omega + v), so the Jacobian of match i is
   G_i = R [-[src_i]x, I] and the information is sum_i w_i G_i^T G_i / sigma^2. The matches are
   those the robust final fit keeps (residual within Tukey's 4.685 robust scales); sigma^2 =
   sum_i w_i |r_i|^2 / (3 n - p) with p the fitted parameters (6, or 4 for a yaw-only fit).
2. Inflation, measured on real data (benchmarks/covariance.py, docs/covariance.md): the noise
   standard deviation is at least `noise_floor`; a shared offset of the two maps (drift, object
   centres that move with the viewpoint, ground-truth error: what no number of matches averages
   away) is added as an independent pose error at the matches' centroid, `offset_t` metres and
   `offset_r` radians per axis; the sum is multiplied by `scale`.
3. dof=4 with a tilt tolerance: roll and pitch come from the data as in a free fit, plus a prior
   of standard deviation max_tilt / 2 (the tilt gate read as a 2-sigma bound). A yaw-only fit
   (dof=4 without a tolerance, or a result without tilt): yaw and translation as estimated with
   roll and pitch held, and roll and pitch independent of them with the free fit's marginal
   (what the data say of the tilt the fit assumed away; plus the prior when there is one).
   A vague prior (pi rad, 10 km) keeps the matrix invertible when the matches leave a
   direction free (collinear matches); the residual spread is taken as at least 1 mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.errors import SglocError
from sgloc.kernels.constants import MAD_SCALE, TUKEY_C
from sgloc.lie import between, se3_log, skew
from sgloc.validation import MAX_COORDINATE, real, setting, validate_settings

#: Tukey biweight's support in robust scales (that of `sgloc.estimation.irls_refine`).
#: Metres: the smallest residual spread assumed (exact matches would give a singular matrix).
MIN_SIGMA = 1e-3
#: Vague prior (rad, m) that keeps the information matrix invertible.
VAGUE_ROTATION, VAGUE_TRANSLATION = np.pi, 1.0e4
_VAGUE = np.r_[[VAGUE_ROTATION**-2] * 3, [VAGUE_TRANSLATION**-2] * 3]
_TILT = np.r_[1.0, 1.0, 0.0, 0.0, 0.0, 0.0]  # the axes of a roll / pitch prior


@dataclass(frozen=True)
class CovarianceInflation:
    """The measured inflation of the least-squares covariance (see the module docstring).

    noise_floor: metres, floor of the residual standard deviation per axis (also the noise
        level when the matches leave no residual degrees of freedom).
    offset_t: metres per axis, shared translation offset of the two maps at the matches.
    offset_r: radians per axis, shared rotation offset of the two maps about the matches.
    scale: factor on the whole covariance (1: none).
    """

    noise_floor: float = setting(0.0, check=real(0.0, MAX_COORDINATE, unit="m"))
    offset_t: float = setting(0.0, check=real(0.0, MAX_COORDINATE, unit="m"))
    offset_r: float = setting(0.0, check=real(0.0, unit="rad"))
    scale: float = setting(1.0, check=real(0.0, low_open=True))

    def __post_init__(self) -> None:
        validate_settings(self, "CovarianceInflation")


#: No inflation: the plain least-squares covariance.
NO_INFLATION = CovarianceInflation()
#: Chosen on the tuning KITTI 00 pairs of benchmarks/hard_cases.py only (`python
#: benchmarks/covariance.py --fit`; docs/covariance.md): 0.2 m noise floor, a shared map offset
#: of 0.225 m and 0.35 deg per axis, times 1.4.
DEFAULT_INFLATION = CovarianceInflation(
    noise_floor=0.2, offset_t=0.225, offset_r=float(np.radians(0.35)), scale=1.4
)


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """xi (6,) with T_true = T_est @ Exp(xi): the error of T_est in the convention of
    `transform_covariance` (query frame, [rotation rad, translation m]; `sgloc.lie`)."""
    return se3_log(between(T_est, T_true))


def point_covariance(covariance: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(3,3) covariance (m^2, source frame) of where T puts `point` (3,), source frame: the
    first-order error omega x p + v of a right perturbation xi = [omega, v]."""
    B = np.hstack([-skew(point), np.eye(3)])
    return B @ covariance @ B.T


def _check(src: np.ndarray, dst: np.ndarray, transform: np.ndarray, weights) -> tuple:
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    T = np.asarray(transform, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape or len(src) == 0:
        raise SglocError(
            f"src and dst must be matching non-empty (n,3) arrays of matched points, got shapes "
            f"{src.shape} and {dst.shape}."
        )
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise SglocError(f"transform must be a finite (4,4) matrix, got shape {T.shape}.")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (len(src),) or not np.all(w >= 0) or not w.any():
        raise SglocError(
            f"weights must be (n,) = ({len(src)},) non-negative numbers, not all zero; got "
            f"shape {w.shape}."
        )
    return src, dst, T, w


def robust_inliers(residuals: np.ndarray) -> np.ndarray:
    """Boolean mask of the matches a Tukey biweight keeps: |r_i| <= 4.685 * 1.4826 * median|r|
    (all when the residuals are (near) zero)."""
    r = np.sqrt(np.einsum("ij,ij->i", residuals, residuals))
    s = MAD_SCALE * np.median(r)
    return r <= TUKEY_C * s if s > 1e-12 else np.ones(len(r), bool)


def fit_statistics(
    src: np.ndarray,
    dst: np.ndarray,
    transform: np.ndarray,
    weights: np.ndarray | None = None,
    dof: int = 4,
    max_tilt: float | None = 15.0,
) -> tuple[np.ndarray, float, float, np.ndarray]:
    """The data's part of the covariance: (information per unit noise variance (6,6),
    residual variance per axis sigma^2 (m^2), its degrees of freedom 3n - p, weighted centroid
    of the kept matches (3,), source frame). NaN variance when there are no degrees of freedom.
    """
    src, dst, T, w = _check(src, dst, transform, weights)
    if dof not in (4, 6):
        raise SglocError(f"dof must be 4 or 6, got {dof!r}.")
    p = free_parameters(T, dof, max_tilt)
    r = src @ T[:3, :3].T + T[:3, 3] - dst
    keep = robust_inliers(r) & (w > 0)
    if not keep.all():
        src, r, w = src[keep], r[keep], w[keep]
    s, w = src, w * (len(w) / w.sum())
    # sum_i w_i G_i^T G_i with G_i = [-[s_i]x, I], from the weighted moments of the points.
    S1, S2 = w @ s, (s * w[:, None]).T @ s
    info = np.empty((6, 6))
    info[:3, :3] = np.trace(S2) * np.eye(3) - S2
    info[:3, 3:] = skew(S1)
    info[3:, :3] = -info[:3, 3:]
    info[3:, 3:] = w.sum() * np.eye(3)
    if p == 4:
        info = _yaw_only(info)
    nu = 3 * len(s) - p
    var = float(w @ np.einsum("ij,ij->i", r, r)) / nu if nu > 0 else float("nan")
    return info, var, float(max(nu, 0)), (w @ s) / w.sum()


def tilt_prior(dof: int, max_tilt: float | None) -> float | None:
    """Radians: standard deviation of the roll / pitch prior of the motion model (max_tilt / 2
    for dof=4 with a tilt tolerance; None otherwise)."""
    return float(np.radians(max_tilt)) / 2.0 if dof == 4 and max_tilt else None


def assemble(
    info: np.ndarray,
    var: np.ndarray,
    resid_dof: np.ndarray,
    centroid: np.ndarray,
    inflation: CovarianceInflation = DEFAULT_INFLATION,
    tilt_prior: float | None = None,
) -> np.ndarray:
    """The covariance (..., 6, 6) from `fit_statistics`' outputs (batched over leading axes):
    floored noise variance, the fit's covariance, the shared map offset at `centroid`, scaled.
    tilt_prior: radians, standard deviation of a prior on roll and pitch (None: none)."""
    info, centroid = np.asarray(info, float), np.asarray(centroid, float)
    var, nu = np.asarray(var, float), np.asarray(resid_dof, float)
    # No residual degrees of freedom (NaN variance): the floor alone.
    floor = max(inflation.noise_floor, MIN_SIGMA) ** 2
    sigma2 = np.where(nu > 0, np.fmax(var, floor), floor)
    total = info / sigma2[..., None, None]
    prior = _VAGUE if tilt_prior is None else _VAGUE + _TILT * tilt_prior**-2
    C = np.linalg.inv(total + np.diag(prior))
    # Offset (omega, delta) at the centroid c: xi = (omega, delta + c x omega), so its
    # covariance is A D A^T with A = [[I, 0], [[c]x, I]], D = diag(r^2 I, t^2 I).
    r2, t2 = inflation.offset_r**2, inflation.offset_t**2
    K = skew(centroid)
    C[..., :3, :3] += r2 * np.eye(3)
    C[..., 3:, :3] += r2 * K
    C[..., :3, 3:] += r2 * np.swapaxes(K, -1, -2)
    C[..., 3:, 3:] += r2 * K @ np.swapaxes(K, -1, -2) + t2 * np.eye(3)
    C *= inflation.scale
    return 0.5 * (C + np.swapaxes(C, -1, -2))


def free_parameters(transform: np.ndarray, dof: int, max_tilt: float | None) -> int:
    """Parameters the final fit estimated: 6, or 4 for a fit held to yaw (dof=4 without a
    tilt tolerance, or a tilt-free result of the dof=4 model)."""
    if dof == 6:
        return 6
    tilted = abs(float(np.asarray(transform)[2, 2]) - 1.0) > 1e-12
    return 6 if max_tilt and tilted else 4


def transform_covariance(
    src: np.ndarray,
    dst: np.ndarray,
    transform: np.ndarray,
    weights: np.ndarray | None = None,
    dof: int = 4,
    max_tilt: float | None = 15.0,
    inflation: CovarianceInflation = DEFAULT_INFLATION,
) -> np.ndarray:
    """(6,6) covariance of `transform` = T_dst_src fitted to matched points src[i] <-> dst[i]
    ((n,3) each, metres; `weights` (n,) the fit's prior weights).

    Tangent order [rx, ry, rz, tx, ty, tz] (rad, m), right perturbation T_true = T @ Exp(xi)
    (xi in the src frame; gtsam.Pose3's convention). dof / max_tilt (degrees): the motion model
    of the fit (`sgloc.estimation.MotionModel`). `inflation`: the measured inflation
    (default: the one chosen on real data, docs/covariance.md; NO_INFLATION for the plain
    least-squares covariance). Symmetric positive definite.
    """
    info, var, nu, c = fit_statistics(src, dst, transform, weights, dof, max_tilt)
    return assemble(info, np.array(var), np.array(nu), c, inflation, tilt_prior(dof, max_tilt))


@dataclass(frozen=True)
class FittedPoints:
    """The matched points a transform was fitted on, kept by a result (`LocalizationResult`,
    `RegistrationResult`) so that its covariance is computed when first read, not per call:
    src, dst (k,3) metres, `weights` (k,) the fit's prior weights or None, and the motion
    model's dof and max_tilt (degrees)."""

    src: np.ndarray
    dst: np.ndarray
    weights: np.ndarray | None
    dof: int
    max_tilt: float | None

    def covariance(self, transform: np.ndarray | None) -> np.ndarray | None:
        """`transform_covariance` of `transform` (T_dst_src) on these points; None without a
        transform."""
        if transform is None:
            return None
        return transform_covariance(
            self.src, self.dst, transform, self.weights, self.dof, self.max_tilt
        )


def _yaw_only(info: np.ndarray) -> np.ndarray:
    """The information of a fit that held roll and pitch: yaw and translation as estimated
    with roll and pitch fixed (their block alone), and roll and pitch decoupled from them with
    what the data alone say of them (the free fit's marginal: the Schur complement)."""
    out = np.zeros((6, 6))  # roll, pitch = axes 0:2; yaw, translation = 2:6
    out[2:, 2:] = info[2:, 2:]
    solved = np.linalg.lstsq(info[2:, 2:], info[2:, :2], rcond=None)[0]
    out[:2, :2] = info[:2, :2] - info[:2, 2:] @ solved
    return out
