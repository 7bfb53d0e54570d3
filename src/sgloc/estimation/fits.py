"""Closed-form rigid fits and minimal-sample hypotheses (paper Eq. 4: weighted Kabsch/Umeyama;
the 4-dof yaw fit; hypotheses from match pairs and triplets; their residuals)."""

from __future__ import annotations

import numpy as np

from sgloc.errors import DegenerateGeometryError
from sgloc.geometry import make_transform
from sgloc.kernels.constants import COLLINEAR_WIDTH

#: Relative size under which a point set counts as collinear (second principal extent over the
#: first). Objects of a city map are metres apart; 1e-3 is a line to within a millimetre per metre.
COLLINEAR_RATIO = 1e-3


def check_not_degenerate(points: np.ndarray, what: str = "points") -> None:
    """Raise DegenerateGeometryError if `points` (n,3) are fewer than 3 or (nearly) collinear."""
    if len(points) < 3:
        raise DegenerateGeometryError(
            f"{len(points)} {what} cannot fix a rigid transform; at least 3 non-collinear are "
            "needed (lower min_similarity or use graphs that overlap more)."
        )
    if _collinear(points):
        raise DegenerateGeometryError(
            f"the {len(points)} {what} are (nearly) collinear, so the rotation about their line "
            "is undetermined; more spread-out matches are needed."
        )


def _collinear(points: np.ndarray) -> bool:
    """True when `points` (n,3) are fewer than 3 or (nearly) collinear: the second principal
    extent under COLLINEAR_RATIO times the first and its standard deviation under
    COLLINEAR_WIDTH metres."""
    if len(points) < 3:
        return True
    c = points - points.mean(axis=0)
    ev = np.linalg.eigvalsh(c.T @ c)
    second = max(ev[1], 0.0)
    thin = second < COLLINEAR_WIDTH**2 * len(points)
    return bool(ev[2] <= 0 or (np.sqrt(second / ev[2]) < COLLINEAR_RATIO and thin))


def weighted_kabsch(
    src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """T_dst_src (4x4) minimising sum_i w_i ||R src_i + t - dst_i||^2, with a reflection guard.

    Raises DegenerateGeometryError for fewer than 3 or collinear points.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    check_not_degenerate(src, "matched points")
    return _kabsch(src, dst, np.ones(len(src)) if weights is None else weights)


def _kabsch(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """weighted_kabsch without the input checks (for inner loops on validated points)."""
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    cs, cd = w @ src, w @ dst
    H = ((src - cs) * w[:, None]).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return make_transform(R, cd - R @ cs)


def tilt_deg(R: np.ndarray) -> np.ndarray:
    """Angle (degrees) between the up axis z and its image under R (3,3) or (B,3,3):
    0 for a rotation about z, 180 for an upside-down map."""
    return np.degrees(np.arccos(np.clip(np.asarray(R)[..., 2, 2], -1.0, 1.0)))


def yaw_fit(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """T_dst_src (4x4) with a rotation about z only (x, y, z, yaw: 4 degrees of freedom)
    minimising sum_i w_i ||R src_i + t - dst_i||^2, in closed form (the angle of the weighted
    xy cross-covariance). Needs two points apart in xy; never a reflection."""
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    cs, cd = w @ src, w @ dst
    a, b = (src - cs)[:, :2] * w[:, None], (dst - cd)[:, :2]
    theta = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b))
    R = rot_z(np.array([theta]))[0]
    return make_transform(R, cd - R @ cs)


def rot_z(theta: np.ndarray) -> np.ndarray:
    """(B,3,3) rotations about z by the angles theta (B,) radians."""
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros((len(theta), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def yaw_from_pairs(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """4-dof hypotheses from minimal samples: src, dst (B,2,3) point pairs -> R (B,3,3) about
    z, t (B,3). The yaw turns the xy direction of the source pair onto the target pair's."""
    es, ed = src[:, 1, :2] - src[:, 0, :2], dst[:, 1, :2] - dst[:, 0, :2]
    theta = np.arctan2(ed[:, 1], ed[:, 0]) - np.arctan2(es[:, 1], es[:, 0])
    R = rot_z(theta)
    t = dst.mean(axis=1) - np.einsum("bij,bj->bi", R, src.mean(axis=1))
    return R, t


def fit_rigid(
    src: np.ndarray,
    dst: np.ndarray,
    weights: np.ndarray | None = None,
    dof: int = 6,
    max_tilt: float | None = None,
) -> np.ndarray:
    """The weighted least-squares T_dst_src under the motion model (no input checks).

    dof=6: Kabsch. dof=4: the Kabsch if it tilts the up axis by at most `max_tilt` degrees
    (the tilt tolerance: maps whose gravity agrees up to that), else the yaw-only fit.
    """
    w = np.ones(len(src)) if weights is None else weights
    if dof == 4:
        # Collinear points leave the rotation about their line free: only the yaw is fixed.
        if max_tilt and not _collinear(src):
            T = _kabsch(src, dst, w)
            if tilt_deg(T[:3, :3]) <= max_tilt:
                return T
        return yaw_fit(src, dst, w)
    return _kabsch(src, dst, w)


def rigid_from_triplets(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hypotheses from minimal samples: src, dst (B,3,3) point triplets -> R (B,3,3), t (B,3).

    Each triplet defines an orthonormal frame (first edge, triangle normal, their cross product)
    with its origin at the centroid; R maps the source frame onto the target frame. Exact for
    noise-free triplets and free of per-matrix LAPACK calls, so a thousand cost microseconds.
    """

    def frames(p: np.ndarray) -> np.ndarray:
        e1 = p[:, 1] - p[:, 0]
        e3 = np.cross(e1, p[:, 2] - p[:, 0])
        e1 = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
        e3 = e3 / np.linalg.norm(e3, axis=1, keepdims=True)
        return np.stack([e1, np.cross(e3, e1), e3], axis=2)  # columns are the axes

    Fs, Fd = frames(src), frames(dst)
    R = Fd @ np.swapaxes(Fs, 1, 2)
    t = dst.mean(axis=1) - np.einsum("bij,bj->bi", R, src.mean(axis=1))
    return R, t


def squared_residuals(R: np.ndarray, t: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(B,m) squared residuals ||R_b src_i + t_b - dst_i||^2 of B hypotheses on m matches.

    Expanded into matrix products (|s|^2 + |t - d|^2 + 2 (R s).(t - d)), so the work is a
    single (B,17) @ (17,m) product instead of a (B,m,3) temporary. Inputs should be roughly
    centred for precision. """
    B = len(R)
    left = np.empty((B, 17))
    left[:, 0] = 1.0
    left[:, 1] = np.einsum("ij,ij->i", t, t)
    left[:, 2:5] = 2.0 * np.einsum("bji,bj->bi", R, t)  # 2 R^T t
    left[:, 5:14] = -2.0 * R.reshape(B, 9)
    left[:, 14:17] = -2.0 * t
    right = np.empty((17, len(src)))
    right[0] = np.einsum("ij,ij->i", src, src) + np.einsum("ij,ij->i", dst, dst)
    right[1] = 1.0
    right[2:5] = src.T
    right[5:14] = (dst[:, :, None] * src[:, None, :]).reshape(len(src), 9).T  # d_i s_j
    right[14:17] = dst.T
    r2 = left @ right
    return np.maximum(r2, 0.0)


#: Matches per sample of Guo's RANSAC (drawn with replacement).
GUO_SAMPLE = 4


def kabsch_batch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unweighted Kabsch fits of B point samples src, dst (B,k,3) -> R (B,3,3), t (B,3), with
    the reflection guard. A degenerate sample (repeated or collinear points) still gets a
    rotation, arbitrary about the undetermined axes, as Guo's code lets it."""
    cs, cd = src.mean(axis=1), dst.mean(axis=1)
    H = np.einsum("bki,bkj->bij", src - cs[:, None], dst - cd[:, None])
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, 1, 2)))
    V[:, :, 2] *= np.where(d == 0, 1.0, d)[:, None]
    R = V @ np.swapaxes(U, 1, 2)
    return R, cd - np.einsum("bij,bj->bi", R, cs)


def draw_triplets(m: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,3) samples of 3 distinct indices in [0, m), uniformly."""
    i = rng.integers(0, m, n)
    j = rng.integers(0, m - 1, n)
    j += j >= i
    k = rng.integers(0, m - 2, n)
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    k += k >= lo
    k += k >= hi
    return np.stack([i, j, k], axis=1)


def draw_pairs(m: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,2) samples of 2 distinct indices in [0, m), uniformly."""
    i = rng.integers(0, m, n)
    j = rng.integers(0, m - 1, n)
    j += j >= i
    return np.stack([i, j], axis=1)


def sample_hypotheses(
    src: np.ndarray,
    dst: np.ndarray,
    rng: np.random.Generator,
    n: int,
    dof: int,
    max_tilt: float | None,
    max_gap: float,
    sampler: str = "minimal",
) -> tuple[np.ndarray, np.ndarray] | None:
    """Up to n hypotheses (R (B,3,3), t (B,3)) of T_dst_src from random samples of the
    matches src[i] <-> dst[i]; None if none. dof=4: pairs apart in xy whose xy lengths differ
    by less than `max_gap` (metres; else both cannot be inliers); dof=6: non-collinear
    triplets; sampler="guo": the Kabsch fits of samples of GUO_SAMPLE matches drawn with
    replacement. Hypotheses tilting the up axis beyond `max_tilt` degrees are dropped."""
    if sampler == "guo":
        samples = rng.integers(0, len(src), (n, GUO_SAMPLE))
        return upright(*kabsch_batch(src[samples], dst[samples]), max_tilt)
    if dof == 4:
        pairs = draw_pairs(len(src), n, rng)
        S, D = src[pairs], dst[pairs]
        ls = np.linalg.norm(S[:, 1, :2] - S[:, 0, :2], axis=1)
        ld = np.linalg.norm(D[:, 1, :2] - D[:, 0, :2], axis=1)
        # Pairs too close in xy fix no yaw; pairs whose lengths disagree cannot both be inliers.
        ok = (np.minimum(ls, ld) > 1e-6) & (np.abs(ls - ld) < max_gap)
        return yaw_from_pairs(S[ok], D[ok]) if ok.any() else None
    samples = draw_triplets(len(src), n, rng)
    S, D = src[samples], dst[samples]
    ok = non_collinear(S) & non_collinear(D)
    if not ok.any():
        return None
    return upright(*rigid_from_triplets(S[ok], D[ok]), max_tilt)


def upright(
    R: np.ndarray, t: np.ndarray, max_tilt: float | None
) -> tuple[np.ndarray, np.ndarray] | None:
    """The hypotheses that tilt the up axis by at most `max_tilt` degrees (all when None)."""
    if max_tilt is None:
        return R, t
    up = tilt_deg(R) <= max_tilt
    return (R[up], t[up]) if up.any() else None


def non_collinear(P: np.ndarray, ratio: float = COLLINEAR_RATIO) -> np.ndarray:
    """(B,) True where the triplet P (B,3,3) spans a triangle: twice its area is more than
    `ratio` times its longest side squared (duplicate points count as collinear)."""
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    # The cross product by components: np.cross costs more in call overhead than in flops here.
    c0 = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
    c1 = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
    c2 = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    area2 = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    longest = np.maximum(np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e2, e2))
    return area2 > ratio * np.maximum(longest, 1e-12)
