"""Pose estimation: weighted Kabsch/Umeyama (paper Eq. 4), RANSAC, optional ICP refinement."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from sgloc.errors import DegenerateGeometryError
from sgloc.geometry import make_transform

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
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if s[0] == 0 or s[1] / s[0] < COLLINEAR_RATIO:
        raise DegenerateGeometryError(
            f"the {len(points)} {what} are (nearly) collinear, so the rotation about their line "
            "is undetermined; more spread-out matches are needed."
        )


def weighted_kabsch(
    src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """T_dst_src (4x4) minimising sum_i w_i ||R src_i + t - dst_i||^2, with a reflection guard.

    Raises DegenerateGeometryError for fewer than 3 or collinear points.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    check_not_degenerate(src, "matched points")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    cs, cd = w @ src, w @ dst
    H = ((src - cs) * w[:, None]).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return make_transform(R, cd - R @ cs)


def kabsch_batch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unweighted Kabsch for a batch: src, dst (B,k,3) -> R (B,3,3), t (B,3) (dst = R src + t)."""
    cs, cd = src.mean(axis=1), dst.mean(axis=1)
    H = np.einsum("bki,bkj->bij", src - cs[:, None], dst - cd[:, None])
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, 1, 2)))
    d[d == 0] = 1.0
    D = np.zeros((len(src), 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    R = V @ D @ np.swapaxes(U, 1, 2)
    t = cd - np.einsum("bij,bj->bi", R, cs)
    return R, t


@dataclass
class RansacConfig:
    """RANSAC over correspondences (Guo's settings as defaults).

    threshold: inlier when ||R src + t - dst|| < threshold (metres; the paper's T_error).
    iterations: hypotheses drawn (each from `sample_size` distinct matches).
    min_inliers, min_inlier_ratio: accept a model only with >= min_inliers inliers and
        >= min_inlier_ratio of the matches given to RANSAC (Guo: 5 and 1 %).
    refit_rounds: refits on all inliers (inliers recomputed after each).
    """

    threshold: float = 5.0
    iterations: int = 1000
    sample_size: int = 3
    min_inliers: int = 5
    min_inlier_ratio: float = 0.01
    refit_rounds: int = 2

    def get_params(self) -> dict:
        return asdict(self)


@dataclass
class RansacResult:
    """Outcome of RANSAC: `transform` (T_dst_src) is None when no model is accepted."""

    transform: np.ndarray | None
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    reason: str = ""


# Bound on hypotheses x matches scored at once (memory of the residual block, ~50 MB).
_BLOCK = 2_000_000


def ransac(
    src: np.ndarray,
    dst: np.ndarray,
    config: RansacConfig | None = None,
    rng: np.random.Generator | None = None,
    weights: np.ndarray | None = None,
) -> RansacResult:
    """Robustly fit T_dst_src to correspondences src[i] <-> dst[i] (both (m,3), metres).

    All hypotheses are fitted at once (batched SVD) and scored in blocks; the best (most inliers,
    then least inlier residual) is refit on its inliers with the weighted Kabsch.
    """
    cfg = config or RansacConfig()
    rng = rng or np.random.default_rng(0)
    m = len(src)
    k = cfg.sample_size
    if m < max(k, 3):
        return RansacResult(
            None, reason=f"only {m} match(es) reached RANSAC; at least {max(k, 3)} are needed"
        )
    # Distinct indices per sample: argsort of random keys, first k columns.
    if m <= 64:
        samples = np.argsort(rng.random((cfg.iterations, m)), axis=1)[:, :k]
    else:
        samples = rng.integers(0, m, size=(cfg.iterations, k))
        dup = (samples[:, :, None] == samples[:, None, :]).sum(axis=(1, 2)) > k
        samples = samples[~dup]
    S, D = src[samples], dst[samples]
    # Skip nearly collinear samples: triangle area small against the longest side squared.
    e1, e2 = S[:, 1] - S[:, 0], S[:, 2] - S[:, 0]
    area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
    longest = np.maximum(np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e2, e2))
    ok = area2 > COLLINEAR_RATIO * np.maximum(longest, 1e-12)
    if not ok.any():
        return RansacResult(
            None,
            reason="every RANSAC sample was collinear; the matched points lie (nearly) on a line",
        )
    R, t = kabsch_batch(S[ok], D[ok])
    best_count, best_cost, best_h = -1, np.inf, 0
    thr2 = cfg.threshold**2
    step = max(1, _BLOCK // m)
    for b0 in range(0, len(R), step):
        Rb, tb = R[b0 : b0 + step], t[b0 : b0 + step]
        pred = np.einsum("bij,mj->bmi", Rb, src) + tb[:, None, :]
        r2 = np.sum((pred - dst[None]) ** 2, axis=2)
        inl = r2 < thr2
        counts = inl.sum(axis=1)
        cost = np.where(inl, r2, 0.0).sum(axis=1)
        h = np.lexsort((cost, -counts))[0]
        if counts[h] > best_count or (counts[h] == best_count and cost[h] < best_cost):
            best_count, best_cost, best_h = int(counts[h]), float(cost[h]), b0 + h
    T = make_transform(R[best_h], t[best_h])
    inliers = _inliers(T, src, dst, thr2)
    for _ in range(cfg.refit_rounds):
        if len(inliers) < 3:
            break
        try:
            T_new = weighted_kabsch(
                src[inliers], dst[inliers], None if weights is None else weights[inliers]
            )
        except DegenerateGeometryError:
            break
        new_inliers = _inliers(T_new, src, dst, thr2)
        if len(new_inliers) < len(inliers):
            break
        T, same = T_new, np.array_equal(new_inliers, inliers)
        inliers = new_inliers
        if same:
            break
    need = max(cfg.min_inliers, int(np.ceil(cfg.min_inlier_ratio * m)), 3)
    if len(inliers) < need:
        return RansacResult(
            None,
            inliers,
            reason=f"best model has {len(inliers)} inliers of "
            f"{m} matches; at least {need} are needed",
        )
    try:
        check_not_degenerate(src[inliers], "inlier points")
    except DegenerateGeometryError as e:
        return RansacResult(None, inliers, reason=str(e))
    return RansacResult(T, inliers)


def _inliers(T: np.ndarray, src: np.ndarray, dst: np.ndarray, thr2: float) -> np.ndarray:
    r2 = np.sum((src @ T[:3, :3].T + T[:3, 3] - dst) ** 2, axis=1)
    return np.flatnonzero(r2 < thr2)


def icp_refine(
    src: np.ndarray,
    src_labels: np.ndarray,
    dst: np.ndarray,
    dst_labels: np.ndarray,
    T: np.ndarray,
    max_distance: float = 2.0,
    iterations: int = 10,
) -> np.ndarray:
    """Refine T_dst_src by point-to-point ICP between two object sets, pairing each source
    object with its nearest same-class target object within `max_distance` metres."""
    offset = (np.abs(np.concatenate([src, dst])).max() + max_distance) * 4 + 1.0
    # Separate classes in a 4th coordinate so one KD-tree serves all classes.
    tree = cKDTree(np.column_stack([dst, dst_labels * offset]))
    for _ in range(iterations):
        moved = src @ T[:3, :3].T + T[:3, 3]
        d, j = tree.query(
            np.column_stack([moved, src_labels * offset]), distance_upper_bound=max_distance
        )
        ok = np.isfinite(d)
        if ok.sum() < 3:
            break
        try:
            T_new = weighted_kabsch(src[ok], dst[j[ok]])
        except DegenerateGeometryError:
            break
        if np.allclose(T_new, T, atol=1e-6):
            T = T_new
            break
        T = T_new
    return T
