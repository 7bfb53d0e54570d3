"""RANSAC over correspondences: one adaptive loop over blocks of hypotheses, scored in numpy
(`ransac_reference`, every setting) or by the compiled kernels of `sgloc.estimation.ransac_kernels`
(`ransac_compiled`: minimal samples, dof=4 or no gravity gate), then refits on the inliers."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sgloc.errors import DegenerateGeometryError
from sgloc.estimation.fits import (
    COLLINEAR_RATIO,
    GUO_SAMPLE,
    check_not_degenerate,
    draw_pairs,
    draw_triplets,
    fit_rigid,
    sample_hypotheses,
    squared_residuals,
    tilt_deg,
)
from sgloc.estimation.motion import MotionModel
from sgloc.geometry import make_transform
from sgloc.validation import (
    MAX_COORDINATE,
    MAX_ITERATIONS,
    MAX_VERTICES,
    InvalidSettingError,
    choice,
    int_choice,
    integer,
    real,
    setting,
    validate_settings,
)


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
    dof, max_tilt: the motion model (`MotionModel`, held here as its two flat settings and
        handed on as `motion`): 4 (x, y, z, yaw) or 6 degrees of freedom; the largest tilt of
        the up axis in degrees (None: no gravity assumption).
    sampler: "minimal" (the default: samples of 3 distinct, non-collinear matches, 2 with
        dof=4, each hypothesis exact on its sample) or "guo" (Guo et al.'s code: samples of
        4 matches drawn with replacement, each hypothesis the unweighted Kabsch fit of its 4,
        degenerate samples kept; dof=6 only).
    """

    threshold: float = setting(5.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    iterations: int = setting(1000, check=integer(1, MAX_ITERATIONS))
    min_inliers: int = setting(5, check=integer(0, MAX_VERTICES))
    min_inlier_ratio: float = setting(0.01, check=real(0.0, 1.0))
    scoring: str = setting(
        "msac", check=choice("msac", "count", "first", what="how RANSAC scores a hypothesis")
    )
    confidence: float | None = setting(
        0.999, check=real(0.0, 1.0, low_open=True, high_open=True, none_ok=True)
    )
    batch: int = setting(100, check=integer(1, MAX_ITERATIONS))
    refit_rounds: int = setting(2, check=integer(0, 100))
    dof: int = setting(4, check=int_choice(4, 6))
    max_tilt: float | None = setting(
        15.0, check=real(0.0, 180.0, low_open=True, none_ok=True, unit="degrees")
    )
    sampler: str = setting(
        "minimal", check=choice("minimal", "guo", what="how RANSAC draws its samples")
    )

    def __post_init__(self) -> None:
        validate_settings(self, "ransac")  # the checks declared beside the fields

    @property
    def motion(self) -> MotionModel:
        """The motion model of these settings (`dof`, `max_tilt`)."""
        return _motion_model(self.dof, self.max_tilt)


@functools.lru_cache(maxsize=16, typed=True)
def _motion_model(dof: int, max_tilt: float | None) -> MotionModel:
    """MotionModel(dof, max_tilt), built (and checked) once per pair of values: the settings
    hand it on several times per call (it is frozen)."""
    return MotionModel(dof, max_tilt)


@dataclass
class RansacResult:
    """Outcome of RANSAC: `transform` (T_dst_src) is None when no model is accepted."""

    transform: np.ndarray | None
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    reason: str = ""


# Bound on hypotheses x matches scored at once (memory of the residual block, ~16 MB).
_BLOCK = 2_000_000

#: score(n, drawn) -> the best of n new hypotheses as (primary, secondary, T (4x4), largest
#: inlier count), or None when none could be formed; `drawn` counts the hypotheses drawn so far
#: including these n. Lower (primary, secondary) is better; ties go to the first drawn.
Scorer = Callable[[int, int], tuple[float, float, np.ndarray, int] | None]


def ransac(
    src: np.ndarray,
    dst: np.ndarray,
    config: RansacConfig | None = None,
    rng: np.random.Generator | None = None,
    weights: np.ndarray | None = None,
) -> RansacResult:
    """Robustly fit T_dst_src to correspondences src[i] <-> dst[i] (both (m,3), metres).

    The ground vehicle's model (dof=4) and any rigid motion without a gravity gate (dof=6,
    max_tilt=None) score with the compiled kernels (`ransac_compiled`: same samples, same
    result as `ransac_reference`); dof=6 with max_tilt, Guo's sampler and "first" scoring run
    `ransac_reference`. """
    cfg = config or RansacConfig()
    kernel_model = cfg.dof == 4 or cfg.max_tilt is None
    if kernel_model and cfg.sampler == "minimal" and cfg.scoring != "first":
        return ransac_compiled(src, dst, cfg, rng, weights)
    return ransac_reference(src, dst, cfg, rng, weights)


def ransac_reference(
    src: np.ndarray,
    dst: np.ndarray,
    config: RansacConfig | None = None,
    rng: np.random.Generator | None = None,
    weights: np.ndarray | None = None,
) -> RansacResult:
    """`ransac` in numpy, every setting: the hypotheses of each block come from minimal
    samples (3 matches; 2 with dof=4; Guo's 4) at once and are scored by matrix products; the
    best is refit on its inliers (`fit_rigid`)."""
    cfg = config or RansacConfig()
    return _run(src, dst, cfg, rng or np.random.default_rng(0), weights, compiled=False)


def ransac_compiled(
    src: np.ndarray,
    dst: np.ndarray,
    config: RansacConfig | None = None,
    rng: np.random.Generator | None = None,
    weights: np.ndarray | None = None,
) -> RansacResult:
    """`ransac_reference` with each block of hypotheses fitted and scored in one compiled call
    (`sgloc.estimation.ransac_kernels`: no (B,m) residual matrix) and compiled refits
    (`sgloc.estimation.fit_kernels`),
    for dof=4 (any max_tilt) and for dof=6 without max_tilt: same arguments, samples and result."""
    cfg = config or RansacConfig()
    if cfg.dof == 6 and cfg.max_tilt is not None:
        raise ValueError("the compiled RANSAC has no gravity gate for dof=6: use ransac_reference")
    return _run(src, dst, cfg, rng or np.random.default_rng(0), weights, compiled=True)


def _run(
    src: np.ndarray,
    dst: np.ndarray,
    cfg: RansacConfig,
    rng: np.random.Generator,
    weights: np.ndarray | None,
    compiled: bool,
) -> RansacResult:
    """Centre the matches, search the best hypothesis with the numpy or the compiled scorer,
    refit it on its inliers (`finish`)."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    m = len(src)
    if m < 3:
        return RansacResult(
            None, reason=f"only {m} match(es) reached RANSAC; at least 3 are needed"
        )
    _check_settings(cfg, compiled)
    # Centre both sets: better conditioned residual expansion; undone at the end.
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    src_c, dst_c = np.ascontiguousarray(src - cs), np.ascontiguousarray(dst - cd)
    scorer = _compiled_scorer if compiled else _numpy_scorer
    best_T = adaptive_search(m, cfg, scorer(src_c, dst_c, cfg, rng))
    if best_T is None:
        return RansacResult(None, reason=no_hypothesis_reason(cfg.motion))
    if not compiled:
        return finish(best_T, src, src_c, dst_c, cs, cd, weights, cfg)
    from sgloc.estimation.fit_kernels import fit_model
    from sgloc.estimation.ransac_kernels import inliers

    w_all = np.ones(m) if weights is None else np.asarray(weights, dtype=np.float64)
    max_tilt = float(cfg.max_tilt or 0.0)

    def fit(s: np.ndarray, d: np.ndarray, w: np.ndarray) -> np.ndarray:
        return fit_model(s, d, w, cfg.dof, max_tilt)

    return finish(best_T, src, src_c, dst_c, cs, cd, w_all, cfg, fit, inliers)


def _check_settings(cfg: RansacConfig, compiled: bool) -> None:
    """Refuse settings the chosen scorer cannot run (checked once matches reach RANSAC)."""
    scorings = ("count", "msac") if compiled else ("count", "msac", "first")
    if cfg.scoring not in scorings:
        raise ValueError(
            f"unknown RANSAC scoring {cfg.scoring!r} for the "
            f"{'compiled' if compiled else 'numpy'} scorer; use one of {', '.join(scorings)}"
        )
    if cfg.dof not in (4, 6):
        raise ValueError(f"RANSAC dof must be 4 (x, y, z, yaw) or 6, got {cfg.dof!r}")
    if cfg.sampler == "guo" and (compiled or cfg.dof != 6):
        if compiled:
            raise ValueError("the compiled RANSAC draws minimal samples: use ransac_reference")
        raise InvalidSettingError(
            f"setting ransac.sampler='guo' needs ransac.dof=6 (got dof={cfg.dof}): Guo's samples "
            "fix any rigid motion; use --set sampler=minimal for dof=4 (Python: sampler='minimal')."
        )


def adaptive_search(m: int, cfg: RansacConfig, score: Scorer) -> np.ndarray | None:
    """The best hypothesis (4x4) of blocks of `cfg.batch` drawn until `cfg.iterations`, or,
    with `cfg.confidence`, until an all-inlier sample has been drawn with that probability
    given the best inlier ratio so far (the standard adaptive stop); None if none was formed."""
    size = GUO_SAMPLE if cfg.sampler == "guo" else cfg.motion.sample_size
    best_key, best_T, drawn, needed = (np.inf, np.inf), None, 0, cfg.iterations
    batch = max(1, min(cfg.batch, _BLOCK // m))
    while drawn < min(needed, cfg.iterations):
        # A small first block: after rejection the inlier ratio is often near 1 and a handful
        # of draws settles it.
        n = min(batch if drawn else min(batch, 16), cfg.iterations - drawn)
        drawn += n
        block = score(n, drawn)
        if block is None:
            continue
        primary, secondary, T, max_count = block
        if (primary, secondary) < best_key:
            best_key, best_T = (primary, secondary), T
        if cfg.confidence is not None:
            w = max_count / m
            needed = min(needed, needed_draws(w, cfg.confidence, cfg.iterations, size))
    return best_T


def _numpy_scorer(
    src: np.ndarray, dst: np.ndarray, cfg: RansacConfig, rng: np.random.Generator
) -> Scorer:
    """Blocks of hypotheses from `sample_hypotheses`, scored by one matrix product each."""
    thr2 = cfg.threshold**2

    def score(n: int, drawn: int) -> tuple[float, float, np.ndarray, int] | None:
        hyp = sample_hypotheses(
            src, dst, rng, n, cfg.dof, cfg.max_tilt, 2.0 * cfg.threshold, cfg.sampler
        )
        if hyp is None:
            return None
        R, t = hyp
        r2 = squared_residuals(R, t, src, dst)
        primary, secondary, counts = _rank(r2, thr2, cfg.scoring, drawn)
        h = np.lexsort((secondary, primary))[0]
        return primary[h], secondary[h], make_transform(R[h], t[h]), counts.max()

    return score


def _rank(
    r2: np.ndarray, thr2: float, scoring: str, drawn: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(primary, secondary, inlier counts) of hypotheses with squared residuals r2 (B,m)."""
    inl = r2 < thr2
    counts = inl.sum(axis=1)
    if scoring == "first":  # Guo: a later hypothesis must have strictly more inliers
        primary = -counts.astype(np.float64)
        secondary = np.arange(drawn - len(counts), drawn, dtype=np.float64)
    elif scoring == "count":
        primary = -counts.astype(np.float64)
        # Tie-break by inlier residual, computed only for the tied best hypotheses.
        secondary = np.full(len(primary), np.inf)
        top = np.flatnonzero(primary == primary.min())
        secondary[top] = np.where(inl[top], r2[top], 0.0).sum(axis=1)
    else:
        primary = np.minimum(r2, thr2).sum(axis=1)
        secondary = -counts.astype(np.float64)
    return primary, secondary, counts


def _compiled_scorer(
    src: np.ndarray, dst: np.ndarray, cfg: RansacConfig, rng: np.random.Generator
) -> Scorer:
    """Blocks drawn as `_numpy_scorer` draws them, fitted and scored in one compiled call."""
    from sgloc.estimation.ransac_kernels import score_block, score_pair_block

    m, thr2, msac = len(src), cfg.threshold**2, cfg.scoring == "msac"

    def score(n: int, drawn: int) -> tuple[float, float, np.ndarray, int] | None:
        if cfg.dof == 4:
            found, p, s, T, max_count = score_pair_block(
                src, dst, draw_pairs(m, n, rng), thr2, msac, 2.0 * cfg.threshold
            )
        else:
            found, p, s, T, max_count = score_block(
                src, dst, draw_triplets(m, n, rng), thr2, msac, COLLINEAR_RATIO
            )
        return (p, s, T, max_count) if found else None

    return score


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
    """RANSAC's last steps, shared by `ransac_reference` and `ransac_compiled`: the best
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


def no_hypothesis_reason(motion: MotionModel) -> str:
    """Why RANSAC formed no hypothesis at all, under `motion`."""
    if motion.max_tilt is not None and motion.dof == 6:
        return (
            "every RANSAC hypothesis was degenerate (collinear sample) or tilted the up axis "
            f"beyond max_tilt={motion.max_tilt} deg (an upside-down or mirrored map?)"
        )
    return "every RANSAC sample was collinear; the matched points lie (nearly) on a line"


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


def needed_draws(inlier_ratio: float, confidence: float, cap: int, size: int = 3) -> int:
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
