"""Pose estimation: weighted Kabsch/Umeyama (paper Eq. 4), RANSAC, optional ICP refinement."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from sgloc.errors import DegenerateGeometryError
from sgloc.geometry import make_transform
from sgloc.validation import InvalidSettingError, validate_settings

#: Relative size under which a point set counts as collinear (second principal extent over the
#: first). Objects of a city map are metres apart; 1e-3 is a line to within a millimetre per metre.
COLLINEAR_RATIO = 1e-3
#: Metres: a point set whose second principal standard deviation is at least this is not
#: collinear however long it is (a 1,000 km stretch of street mapped 240 m wide fixes the roll
#: about its line; by the ratio alone it would count as a line).
COLLINEAR_WIDTH = 5.0


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
    R = _rot_z(np.array([theta]))[0]
    return make_transform(R, cd - R @ cs)


def _rot_z(theta: np.ndarray) -> np.ndarray:
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
    R = _rot_z(theta)
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
    centred for precision.
    """
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


@dataclass
class RansacConfig:
    """RANSAC over correspondences (Guo's settings as defaults).

    threshold: inlier when ||R src + t - dst|| < threshold (metres; the paper's T_error).
    iterations: hypotheses drawn (each from 3 distinct matches).
    min_inliers, min_inlier_ratio: accept a model only with >= min_inliers inliers and
        >= min_inlier_ratio of the matches given to RANSAC (Guo: 5 and 1 %).
    scoring: "msac" (least truncated quadratic cost sum(min(r^2, threshold^2)); the default:
        it separates hypotheses with equal inlier counts), "count" (most inliers, ties by least
        inlier residual) or "first" (Guo's code: most inliers, ties to the first drawn).
    confidence: stop drawing once, with this probability, an all-inlier sample has been drawn
        given the best inlier ratio so far (the standard adaptive stop); None draws all
        `iterations` (Guo's fixed 1000).
    batch: hypotheses generated and scored per block (the adaptive stop is checked per block).
    refit_rounds: refits on all inliers (inliers recomputed after each).
    dof: 6 (any rigid motion; hypotheses from 3 matches) or 4 (ground vehicles: x, y, z and
        yaw, roll and pitch fixed by gravity; hypotheses from 2 matches, about the z axis).
    max_tilt: degrees; when set, the maps share gravity (z up) up to this tilt: hypotheses and
        fits that tilt the up axis more (upside-down or mirrored alignments) are refused. With
        dof=4 the refits may tilt up to this much (None or 0: yaw only). None: no assumption.
    sampler: "minimal" (the default: samples of 3 distinct, non-collinear matches, 2 with
        dof=4, each hypothesis exact on its sample) or "guo" (Guo et al.'s code: samples of
        4 matches drawn with replacement, each hypothesis the unweighted Kabsch fit of its 4,
        degenerate samples kept; dof=6 only).
    """

    threshold: float = 5.0
    iterations: int = 1000
    min_inliers: int = 5
    min_inlier_ratio: float = 0.01
    scoring: str = "msac"
    confidence: float | None = 0.999
    batch: int = 100
    refit_rounds: int = 2
    dof: int = 4
    max_tilt: float | None = 15.0
    sampler: str = "minimal"

    def __post_init__(self) -> None:
        validate_settings(self)  # type, range, finiteness of every field (sgloc.validation)

    def get_params(self) -> dict:
        return asdict(self)


@dataclass
class RansacResult:
    """Outcome of RANSAC: `transform` (T_dst_src) is None when no model is accepted."""

    transform: np.ndarray | None
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    reason: str = ""


# Bound on hypotheses x matches scored at once (memory of the residual block, ~16 MB).
_BLOCK = 2_000_000


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


def ransac(
    src: np.ndarray,
    dst: np.ndarray,
    config: RansacConfig | None = None,
    rng: np.random.Generator | None = None,
    weights: np.ndarray | None = None,
) -> RansacResult:
    """Robustly fit T_dst_src to correspondences src[i] <-> dst[i] (both (m,3), metres).

    The ground vehicle's model (dof=4) and any rigid motion without a gravity gate (dof=6,
    max_tilt=None) run the compiled loop of `sgloc.kernels.ransac` (same samples, same result
    as `ransac_reference`); dof=6 with max_tilt, Guo's sampler and "first" scoring run
    `ransac_reference`.
    """
    cfg = config or RansacConfig()
    kernel_model = cfg.dof == 4 or cfg.max_tilt is None
    if kernel_model and cfg.sampler == "minimal" and cfg.scoring != "first":
        from sgloc.kernels import use_compiled

        if use_compiled(len(src)):
            from sgloc.kernels.ransac import ransac as compiled_ransac

            return compiled_ransac(src, dst, cfg, rng, weights)
    return ransac_reference(src, dst, cfg, rng, weights)


def ransac_reference(
    src: np.ndarray,
    dst: np.ndarray,
    config: RansacConfig | None = None,
    rng: np.random.Generator | None = None,
    weights: np.ndarray | None = None,
) -> RansacResult:
    """`ransac` in numpy, every motion model: all hypotheses come from minimal samples
    (3 matches; 2 with dof=4) at once and are scored in blocks by matrix products; the best is
    refit on its inliers (`fit_rigid`)."""
    cfg = config or RansacConfig()
    rng = rng or np.random.default_rng(0)
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    m = len(src)
    if m < 3:
        return RansacResult(
            None, reason=f"only {m} match(es) reached RANSAC; at least 3 are needed"
        )
    if cfg.scoring not in ("count", "msac", "first"):
        raise ValueError(f"unknown RANSAC scoring {cfg.scoring!r}; use 'msac', 'count' or 'first'")
    if cfg.dof not in (4, 6):
        raise ValueError(f"RANSAC dof must be 4 (x, y, z, yaw) or 6, got {cfg.dof!r}")
    if cfg.sampler == "guo" and cfg.dof != 6:
        raise InvalidSettingError(
            f"setting ransac.sampler='guo' needs ransac.dof=6 (got dof={cfg.dof}): Guo's samples "
            "fix any rigid motion; use sampler='minimal' for dof=4."
        )
    # Centre both sets: better conditioned residual expansion; undone at the end.
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    src_c, dst_c = src - cs, dst - cd
    thr2 = cfg.threshold**2
    best_key, best_T, drawn, needed = (np.inf, np.inf), None, 0, cfg.iterations
    batch = max(1, min(cfg.batch, _BLOCK // m))
    sample_size = GUO_SAMPLE if cfg.sampler == "guo" else 2 if cfg.dof == 4 else 3
    while drawn < min(needed, cfg.iterations):
        # A small first block: after rejection the inlier ratio is often near 1 and a handful
        # of draws settles it.
        n = min(batch if drawn else min(batch, 16), cfg.iterations - drawn)
        drawn += n
        hyp = _hypotheses(src_c, dst_c, rng, n, cfg)
        if hyp is None:
            continue
        R, t = hyp
        r2 = squared_residuals(R, t, src_c, dst_c)
        inl = r2 < thr2
        counts = inl.sum(axis=1)
        if cfg.scoring == "first":  # Guo: a later hypothesis must have strictly more inliers
            primary = -counts.astype(np.float64)
            secondary = np.arange(drawn - len(counts), drawn, dtype=np.float64)
        elif cfg.scoring == "count":
            primary = -counts.astype(np.float64)
            # Tie-break by inlier residual, computed only for the tied best hypotheses.
            secondary = np.full(len(primary), np.inf)
            top = np.flatnonzero(primary == primary.min())
            secondary[top] = np.where(inl[top], r2[top], 0.0).sum(axis=1)
        else:
            primary = np.minimum(r2, thr2).sum(axis=1)
            secondary = -counts.astype(np.float64)
        h = np.lexsort((secondary, primary))[0]
        if (primary[h], secondary[h]) < best_key:
            best_key, best_T = (primary[h], secondary[h]), make_transform(R[h], t[h])
        if cfg.confidence is not None:
            w = counts.max() / m
            needed = min(needed, _needed_draws(w, cfg.confidence, cfg.iterations, sample_size))
    if best_T is None:
        return RansacResult(None, reason=_no_hypothesis_reason(cfg))
    return finish(best_T, src, src_c, dst_c, cs, cd, weights, cfg)


#: fit(src, dst, weights or None) -> T_dst_src under a motion model.
Fit = Callable[[np.ndarray, np.ndarray, np.ndarray | None], np.ndarray]
#: find(T, src, dst, thr2) -> sorted indices of the matches with squared residual < thr2.
FindInliers = Callable[[np.ndarray, np.ndarray, np.ndarray, float], np.ndarray]


def finish(
    best_T: np.ndarray,
    src: np.ndarray,
    src_c: np.ndarray,
    dst_c: np.ndarray,
    cs: np.ndarray,
    cd: np.ndarray,
    weights: np.ndarray | None,
    cfg: RansacConfig,
    fit: Fit | None = None,
    find: FindInliers | None = None,
) -> RansacResult:
    """RANSAC's last steps, shared by `ransac_reference` and the compiled loop: the best
    hypothesis (4x4, between src_c = src - cs and dst_c = dst - cd) refit on its inliers, the
    centring undone, and the result checked (enough inliers; dof=6: not degenerate). `fit`
    and `find` default to `fit_rigid` under cfg's motion model and numpy residuals."""
    m = len(src)
    fit = fit or (lambda s, d, w: fit_rigid(s, d, w, cfg.dof, cfg.max_tilt))
    T, inliers = _refit(best_T, src_c, dst_c, cfg, weights, fit, find or _inliers)
    # Undo the centring: T_dst_src = Tr(cd) @ T_c @ Tr(-cs).
    T = make_transform(T[:3, :3], T[:3, 3] + cd - T[:3, :3] @ cs)
    need = max(cfg.min_inliers, int(np.ceil(cfg.min_inlier_ratio * m)), 3)
    if len(inliers) < need:
        return RansacResult(
            None,
            inliers,
            reason=f"best model has {len(inliers)} inliers of "
            f"{m} matches; at least {need} are needed",
        )
    if cfg.dof == 6:
        try:
            check_not_degenerate(src[inliers], "inlier points")
        except DegenerateGeometryError as e:
            return RansacResult(None, inliers, reason=str(e))
    return RansacResult(T, inliers)


def _no_hypothesis_reason(cfg: RansacConfig) -> str:
    if cfg.max_tilt is not None and cfg.dof == 6:
        return (
            "every RANSAC hypothesis was degenerate (collinear sample) or tilted the up axis "
            f"beyond max_tilt={cfg.max_tilt} deg (an upside-down or mirrored map?)"
        )
    return "every RANSAC sample was collinear; the matched points lie (nearly) on a line"


def _hypotheses(
    src: np.ndarray, dst: np.ndarray, rng: np.random.Generator, n: int, cfg: RansacConfig
) -> tuple[np.ndarray, np.ndarray] | None:
    """Up to n hypotheses (R (B,3,3), t (B,3)) from random minimal samples; None if none.
    With sampler="guo": the Kabsch fits of samples of 4 matches drawn with replacement."""
    if cfg.sampler == "guo":
        samples = rng.integers(0, len(src), (n, GUO_SAMPLE))
        return _upright(*kabsch_batch(src[samples], dst[samples]), cfg.max_tilt)
    if cfg.dof == 4:
        i = rng.integers(0, len(src), n)
        j = rng.integers(0, len(src) - 1, n)
        j += j >= i
        S, D = src[np.stack([i, j], 1)], dst[np.stack([i, j], 1)]
        ls = np.linalg.norm(S[:, 1, :2] - S[:, 0, :2], axis=1)
        ld = np.linalg.norm(D[:, 1, :2] - D[:, 0, :2], axis=1)
        # Pairs too close in xy fix no yaw; pairs whose lengths disagree cannot both be inliers.
        ok = (np.minimum(ls, ld) > 1e-6) & (np.abs(ls - ld) < 2.0 * cfg.threshold)
        return yaw_from_pairs(S[ok], D[ok]) if ok.any() else None
    samples = draw_triplets(len(src), n, rng)
    S, D = src[samples], dst[samples]
    ok = non_collinear(S) & non_collinear(D)
    if not ok.any():
        return None
    return _upright(*rigid_from_triplets(S[ok], D[ok]), cfg.max_tilt)


def _upright(
    R: np.ndarray, t: np.ndarray, max_tilt: float | None
) -> tuple[np.ndarray, np.ndarray] | None:
    """The hypotheses that tilt the up axis by at most `max_tilt` degrees (all when None)."""
    if max_tilt is None:
        return R, t
    up = tilt_deg(R) <= max_tilt
    return (R[up], t[up]) if up.any() else None


def _refit(
    T: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    cfg: RansacConfig,
    weights: np.ndarray | None,
    fit: Fit,
    find: FindInliers,
) -> tuple[np.ndarray, np.ndarray]:
    """Refit T on its inliers `refit_rounds` times (inliers recomputed after each) while the
    inlier set does not shrink; (T, inliers)."""
    thr2 = cfg.threshold**2
    inliers = find(T, src, dst, thr2)
    for _ in range(cfg.refit_rounds):
        if len(inliers) < 3:
            break
        w = None if weights is None else weights[inliers]
        try:
            if cfg.dof == 6:
                check_not_degenerate(src[inliers], "matched points")
            T_new = fit(src[inliers], dst[inliers], w)
        except DegenerateGeometryError:
            break
        if cfg.dof == 6 and cfg.max_tilt is not None and tilt_deg(T_new[:3, :3]) > cfg.max_tilt:
            break
        new_inliers = find(T_new, src, dst, thr2)
        if len(new_inliers) < len(inliers):
            break
        T, same = T_new, np.array_equal(new_inliers, inliers)
        inliers = new_inliers
        if same:
            break
    return T, inliers


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


def _needed_draws(inlier_ratio: float, confidence: float, cap: int, size: int = 3) -> int:
    """Samples of `size` needed to draw one all-inlier sample with probability `confidence`."""
    p = inlier_ratio**size
    if p >= 1.0:
        return 1
    if p <= 0.0:
        return cap
    return int(min(cap, np.ceil(np.log(1.0 - confidence) / np.log(1.0 - p))))


def _inliers(T: np.ndarray, src: np.ndarray, dst: np.ndarray, thr2: float) -> np.ndarray:
    r2 = np.sum((src @ T[:3, :3].T + T[:3, 3] - dst) ** 2, axis=1)
    return np.flatnonzero(r2 < thr2)


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
    """
    prior = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    from sgloc.kernels import use_compiled

    if use_compiled(len(src)):
        from sgloc.kernels.fit import irls_class_scaled, irls_model

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
    w_prev = None
    for _ in range(iterations):
        d = src @ T[:3, :3].T + T[:3, 3] - dst
        r = np.linalg.norm(d, axis=1)
        sigma = 1.4826 * np.median(r)
        if sigma <= 1e-12:
            break
        if classes is not None:
            s_xy, s_z = class_scales(d, classes, sigma, class_axes)
            u = np.sqrt((d[:, 0] ** 2 + d[:, 1] ** 2) / s_xy**2 + d[:, 2] ** 2 / s_z**2) / 4.685
        else:
            u = r / (4.685 * sigma)
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
    all_xy, all_z = 1.4826 * np.median(h), 1.4826 * np.median(v)
    uniq, inv, cnt = np.unique(classes, return_inverse=True, return_counts=True)
    order = np.argsort(inv, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(cnt)])
    sxy, sz = np.empty(len(uniq)), np.empty(len(uniq))
    for c in range(len(uniq)):
        idx = order[bounds[c] : bounds[c + 1]]
        few = cnt[c] < MIN_CLASS_MATCHES
        sxy[c] = all_xy if few or axes == "height" else 1.4826 * np.median(h[idx])
        sz[c] = all_z if few else 1.4826 * np.median(v[idx])
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
        J[:, 0, 1], J[:, 0, 2] = q[:, 2], -q[:, 1]
        J[:, 1, 0], J[:, 1, 2] = -q[:, 2], q[:, 0]
        J[:, 2, 0], J[:, 2, 1] = q[:, 1], -q[:, 0]
        J[:, 0, 3] = J[:, 1, 4] = J[:, 2, 5] = 1.0
        J = J[:, :, cols]
        H = np.einsum("nki,nk,nkj->ij", J, W, J)
        g = np.einsum("nki,nk,nk->i", J, W, dst - p)
        try:
            x = np.zeros(6)
            x[cols] = np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        dR = _rotvec_to_matrix(x[:3])
        R = dR @ T[:3, :3]
        if max_tilt and len(cols) == 6 and tilt_deg(R) > max_tilt:
            break
        T = make_transform(R, dR @ (T[:3, 3] - c) + c + x[3:])
        if np.abs(x).max() < 1e-12:
            break
    return T


def _rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation (3,3) by angle |v| about v / |v|."""
    a = float(np.linalg.norm(v))
    if a < 1e-15:
        return np.eye(3)
    k = v / a
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)


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
    # Classes are separated by a 4th coordinate so one KD-tree per side serves all classes.
    offset = 4.0 * (np.abs(np.concatenate([src, dst])).max() + max_distance) + 1.0
    dst4 = np.column_stack([dst, dst_labels * offset])
    from scipy.spatial import cKDTree  # deferred: scipy.spatial loads in ~0.2 s

    tree_dst = cKDTree(dst4)
    pairs_prev = None
    for _ in range(iterations):
        moved4 = np.column_stack([src @ T[:3, :3].T + T[:3, 3], src_labels * offset])
        d, j = tree_dst.query(moved4, distance_upper_bound=max_distance)
        _, i_back = cKDTree(moved4).query(dst4)
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
