"""Acceptance test: is an estimated alignment backed by evidence, or could chance explain it?

Guo's rule (>= 5 inliers and >= 1 % of the matches) accepts pairs of maps that do not overlap:
repeated city objects always offer a few consistent-looking matches, and outlier rejection
concentrates exactly those. This module scores an estimated transform T_target_query with an
*a-contrario* test (as AC-RANSAC does) on the descriptor candidates, not on the survivors of
rejection, which were selected for being consistent.

Two null models, and the estimate must beat both:

H0u (uniform): the descriptor matches carry no information about *which* object of the same
class is the partner: the target of candidate i is a uniformly random target object of its class.
For a fixed transform T, candidate i is then an inlier (||T q_i - t_i|| < radius) with probability
p_i = N_c(T q_i) / n_c (N_c: class-c target objects within `radius` of T q_i, n_c: all class-c
target objects), so the number of inliers is Poisson-binomial with mean lambda = sum_i p_i.
RANSAC searches over the transforms fixed by triples of candidates; only triples whose pairwise
distances agree within 2 * radius in both graphs can all be inliers, so the number of tests N is
the number of such triples (triangles of the pairwise-consistency graph; at most C(m, 3)), and
the number of false alarms is NFA_u = N * P(Poisson(lambda) >= k - 3) (k inliers among the m
candidates, counted per query object: an object with several candidate targets is one inlier;
Poisson has a heavier tail than the binomial of the same mean: conservative in p).
As in AC-RANSAC the radius adapts to the precision of the fit: the NFA is evaluated with the
inliers within 1/4, 1/2 and all of the radius (the smallest counts, the number of tests
multiplied by 3), each with lambda scaled by (r_fit / radius)^2, r_fit = the largest residual
of those inliers (at least 10 % of the radius), so an exact fit is more significant than a
sloppy one with the same count. With the 4-dof model (`dof=4`) a hypothesis is fixed by 2
matches: the tests are the consistent pairs and the excess is k - 2.

H0p (permutation): the target of candidate i is drawn from the targets the candidates of its
class actually matched (what permuting targets within a class does). Repeated street furniture
concentrates the matches on look-alike objects, which H0u ignores; H0p prices it in
(lambda_p from the candidates' own targets, leave-one-out: candidate i's target is drawn from
the other candidates' targets, so an inlier does not explain itself). A true overlap also
agrees *beyond* the matches: the query objects that are not inliers but land on a same-class
target object after alignment are counted against a label-permutation null
(log10_colocation_p), and that p-value multiplies NFA_p = N * P(Poisson(lambda_p) >= k - 3).
NFA_best = max(NFA_u, NFA_p * p_colocation).

    confidence = 1 / (1 + NFA_best + NFA_best / NFA_runner_up)

This is the weight of the best hypothesis when it, the best *distinct* alternative (a transform
more than `distinct_translation` metres or `distinct_rotation` degrees away, supported by
candidates the best does not explain, found by consistency-guided sampling) and "chance" are
weighed by their a-contrario evidence 1/NFA (chance weighing 1). So it is near 1 only when the
best alignment is far beyond chance *and* far better supported than any different alignment
(two comparably supported alignments give about 0.5: the map is ambiguous). Under H0, NFA has
P(NFA <= e) <= e, so a non-overlapping pair reaches confidence >= c with probability at most
about (1 - c) / c. The confidence is 0 when the inliers are nearly collinear (standard deviation
along their second principal axis under `min_spread` metres): the evidence then does not fix
the rotation about their line (with dof=4 gravity fixes that rotation: their spread along the
first principal axis of their xy counts instead). A result is accepted when confidence >=
`min_confidence` (the one strictness setting; 0 gives back Guo's rule alone). When chance
alone already puts the confidence below `min_confidence`, the runner-up search is skipped (it
could only lower it) and the confidence reported is 1 / (1 + NFA_best).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from sgloc.consistency import (
    ALL_PAIRS_LIMIT,
    ConsistentPairs,
    common_partner_count,
    consistency_bits,
    unpack_rows,
)
from sgloc.errors import SglocError
from sgloc.estimation import (
    non_collinear,
    rigid_from_triplets,
    squared_residuals,
    tilt_deg,
    yaw_from_pairs,
)
from sgloc.geometry import apply
from sgloc.graph import SemanticGraph
from sgloc.kernels import use_compiled
from sgloc.sampled_consistency import SampledConsistency
from sgloc.validation import validate_settings

_LN10 = np.log(10.0)
_TRIANGLE_EDGES = 2048
#: The precision-adapted inlier radius is at least this fraction of the radius.
MIN_RADIUS_FRACTION = 0.1
#: With dof=4, inliers must extend this many times `min_spread` along their first xy axis
#: (measured: at 1 x, clusters of a few exact coincidences in the rendered city's regular
#: blocks, about 8 m long, passed as non-overlapping pairs).
DOF4_SPREAD_FACTOR = 2.0


@dataclass
class AcceptanceConfig:
    """Settings of the acceptance test (see the module docstring for the model).

    enabled: run the test (False: Guo's rule alone decides; confidence is left None).
    min_confidence: accept when confidence >= this (the strictness; in [0, 1]).
    radius: inlier radius in metres for the test; None uses the RANSAC threshold.
    min_spread: metres; inliers whose standard deviation along their second principal axis is
        below this are (nearly) collinear and give confidence 0 (with dof=4, where gravity
        fixes the rotation about such a line: along the first principal axis of their xy,
        at least DOF4_SPREAD_FACTOR = 2 x min_spread).
    distinct_translation, distinct_rotation: metres / degrees; an alternative hypothesis is
        distinct when its transform differs from the best by more than either.
    runner_up_samples: hypotheses drawn when searching for the best distinct alternative.
    distinct_ratio: the test weighs only the distinctive candidates, those whose best match passes
        the ratio test (1 - s_1) / (1 - s_2) <= distinct_ratio (`MatchingConfig.max_ratio`): in a
        repetitive place near-tied matches support a wrong alignment as readily as the right
        one. None: every candidate.
    small_query, small_distinct_ratio: a query graph with fewer than `small_query` objects (one
        scan, a short stretch) is tested with the looser ratio `small_distinct_ratio` (None:
        every candidate counts): its objects see only part of their neighbourhood, so fewer
        of its right matches are distinctive (`ratio_for`). 0: no query is small. Measured on
        the hard-case benchmark's tuning pairs and on small crops of non-overlapping maps
        (docs/acceptance.md): 0.9 or no filter gave false accepts in repetitive places.
    small_exclusion: metres; for a small query, the ratio test's rival is the best same-class
        target farther than this from the candidate's target (`sgloc.distinctive`): a near tie
        with a neighbour in the same place is no ambiguity about the place. 0: the second
        best of the class. (Measured: for large queries too it let 2 of 480 non-overlapping
        pairs of the rendered city through.)
    verify_small: with the 4-dof model, a small query this test refuses is verified against the
        whole target map (`sgloc.verification`): pair hypotheses from each query object's
        `verify_top_k` candidates (at most `verify_hypotheses` scored), scored by how many query
        objects land within `verify_radius` metres of a same-class target object; chance from
        the density of same-class targets within `verify_density_radius` metres. Chosen on the
        hard-case benchmark's tuning pairs and 300 extra one-scan negatives (docs/acceptance.md).
    """

    enabled: bool = True
    min_confidence: float = 0.9999
    radius: float | None = None
    min_spread: float = 5.0
    distinct_translation: float = 10.0
    distinct_rotation: float = 10.0
    runner_up_samples: int = 128
    distinct_ratio: float | None = 0.8
    small_query: int = 30
    small_distinct_ratio: float | None = 0.85
    small_exclusion: float = 10.0
    verify_small: bool = True
    verify_top_k: int = 5
    verify_radius: float = 1.5
    verify_density_radius: float = 15.0
    verify_hypotheses: int = 4096

    def __post_init__(self) -> None:
        validate_settings(self)  # type, range, finiteness of every field (sgloc.validation)
        if not 0.0 <= float(self.min_confidence) <= 1.0:
            raise SglocError(
                f"min_confidence must be in [0, 1], got {self.min_confidence}; 0 keeps Guo's "
                "rule, 0.9999 is the default."
            )
        if self.radius is not None and not float(self.radius) > 0:
            raise SglocError(f"acceptance radius must be > 0 m or None, got {self.radius}.")
        if float(self.min_spread) < 0:
            raise SglocError(f"min_spread must be >= 0 m, got {self.min_spread}.")

    def get_params(self) -> dict:
        return asdict(self)

    def ratio_for(self, n_query: int) -> float | None:
        """The distinctiveness ratio for a query graph of `n_query` objects (None: every
        candidate is evidence): `small_distinct_ratio` below `small_query` objects, else
        `distinct_ratio`."""
        if n_query < self.small_query and self.distinct_ratio is not None:
            return self.small_distinct_ratio
        return self.distinct_ratio

    def exclusion_for(self, n_query: int) -> float:
        """Metres around a candidate's target where no rival is sought, for a query graph of
        `n_query` objects: `small_exclusion` below `small_query` objects, else 0."""
        return float(self.small_exclusion) if n_query < self.small_query else 0.0


@dataclass
class Assessment:
    """Outcome of `assess`: `accepted`, `confidence` in [0, 1], `reason` (empty if accepted),
    and `details` (inliers, lambda, log10 NFA of best and runner-up, spread in metres)."""

    accepted: bool
    confidence: float
    reason: str = ""
    details: dict = field(default_factory=dict)


def _log_comb3(m: int) -> float:
    """ln C(m, 3)."""
    if m < 3:
        return 0.0
    from scipy.special import gammaln  # deferred, as scipy.spatial below: ~0.3 s together

    return float(gammaln(m + 1) - gammaln(4) - gammaln(m - 2))


class _ChanceModel:
    """Chance agreement of a transform under the nulls, from one neighbour search: the
    same-class target objects within the radius of each moved query object."""

    def __init__(self, target: SemanticGraph, radius: float, n_classes: int) -> None:
        self.positions = np.ascontiguousarray(target.positions, dtype=np.float64)
        self.labels = target.labels
        self.n_classes = n_classes
        self.class_count = np.bincount(target.labels, minlength=n_classes).astype(np.float64)
        self.radius = radius
        # The neighbour search: compiled (a grid per call) or by KD-trees (the reference).
        self.compiled = use_compiled(len(target))
        self.tree = None

    def near_counts(
        self, moved: np.ndarray, weights: tuple[np.ndarray | None, ...] = (None,)
    ) -> list[np.ndarray]:
        """For each entry of `weights`: (n, n_classes) number (None) or summed weights of the
        class-c target objects within the radius (distance <= radius) of each point of `moved`
        (n,3)."""
        if self.compiled and len(weights) <= 2 and weights[0] is None:
            from sgloc.kernels.neighbors import near_class_counts

            w = weights[1] if len(weights) == 2 else None
            counts, summed = near_class_counts(
                np.ascontiguousarray(moved, dtype=np.float64),
                self.positions,
                np.asarray(self.labels, dtype=np.int64),
                self.n_classes,
                float(self.radius),
                np.zeros(0) if w is None else np.asarray(w, dtype=np.float64),
            )
            return [counts, summed][: len(weights)]
        return self.near_counts_reference(moved, weights)

    def near_counts_reference(
        self, moved: np.ndarray, weights: tuple[np.ndarray | None, ...] = (None,)
    ) -> list[np.ndarray]:
        """`near_counts` by KD-trees (scipy), the reference of the compiled search."""
        n, k = len(moved), self.n_classes
        if n == 0:
            return [np.zeros((0, k)) for _ in weights]
        from scipy.spatial import cKDTree

        if self.tree is None:
            self.tree = cKDTree(self.positions)
        pairs = cKDTree(moved).sparse_distance_matrix(self.tree, self.radius, output_type="ndarray")
        i, j = pairs["i"], pairs["j"]
        cell = i * k + self.labels[j]
        return [
            np.bincount(cell, None if w is None else w[j], minlength=n * k).reshape(n, k)
            for w in weights
        ]

    def expected_inliers(self, counts: np.ndarray, qi: np.ndarray, tlab: np.ndarray) -> float:
        """lambda = sum over candidates (query qi, target class tlab) of N_c / n_c, with
        `counts` = near_counts of the moved query objects."""
        return float(np.sum(counts[qi, tlab] / self.class_count[tlab]))


def _log10_poisson_tail(k: int, lam: float) -> float:
    """log10 P(Poisson(lam) >= k)."""
    if k <= 0:
        return 0.0
    from scipy.special import pdtrc

    p = pdtrc(k - 1, max(lam, 1e-12))
    if p > 1e-280:
        return float(np.log10(p))
    from scipy.stats import poisson  # deferred: importing scipy.stats costs ~0.3 s

    return float(poisson.logsf(k - 1, max(lam, 1e-12)) / _LN10)


def log10_colocation_p(
    query: SemanticGraph, presence: np.ndarray, exclude: np.ndarray
) -> tuple[float, int, float]:
    """Independent confirmation beyond the inliers: among the query objects not in `exclude`
    (the inliers' query objects), C = those with a same-class target object within the radius
    after alignment. Under a label-permutation null (a query object's class drawn from the query's
    class frequencies f, independent of where it lies) C is Poisson-binomial with mean
    mu = sum_i sum_c presence[i, c] f_c. Returns (log10 P(X >= C), C, mu)."""
    n_classes = presence.shape[1]
    f = np.bincount(query.labels, minlength=n_classes)[:n_classes] / max(len(query), 1)
    keep = np.ones(len(query), dtype=bool)
    keep[exclude] = False
    mu = float((presence[keep] @ f).sum())
    C = int(presence[np.flatnonzero(keep), query.labels[keep]].sum())
    if C == 0:
        return 0.0, C, mu
    return _log10_poisson_tail(C, mu), C, mu


def log10_nfa(k: int, m: int, lam: float, n_tests: float | None = None, sample: int = 3) -> float:
    """log10 of the number of false alarms n_tests * P(Poisson(lam) >= k - sample); n_tests
    defaults to C(m, 3), every triple of the m candidates; `sample` matches fix a hypothesis
    (3 for 6 dof, 2 for 4 dof) and are not evidence for it."""
    log_tests = _log_comb3(m) if n_tests is None else float(np.log(max(n_tests, 1.0)))
    excess = k - sample
    if excess <= 0:
        return log_tests / _LN10
    return float(log_tests / _LN10 + _log10_poisson_tail(excess, lam))


#: Inlier radii, as fractions of the acceptance radius, at which the NFA is evaluated (the
#: smallest NFA counts, times their number: the tests multiply).
RADIUS_FRACTIONS = (0.25, 0.5, 1.0)


def nfa_over_radii(
    res2: np.ndarray, radius: float, lam: float, m: int, n_tests: float, sample: int = 3
) -> tuple[float, int, float]:
    """The smallest log10 NFA over the inlier radii f * radius, f in RADIUS_FRACTIONS, of the
    candidates with squared residuals `res2` (m^2); lam = chance inliers within `radius`.

    At each radius the k_f candidates within it fit within their largest residual r_fit
    (>= MIN_RADIUS_FRACTION * radius) and chance agreement scales with the area of that disc
    (maps are nearly planar): lam * (r_fit / radius)^2, as AC-RANSAC adapts its radius to the
    precision of the fit. The number of tests is multiplied by the number of radii tried.
    Returns (log10 NFA, k_f, r_fit) of the best radius."""
    best = (np.inf, 0, radius)
    extra = np.log10(len(RADIUS_FRACTIONS))
    for f in RADIUS_FRACTIONS:
        within = res2[res2 < (f * radius) ** 2]
        k = int(within.size)
        r_fit = float(np.sqrt(within.max())) if k else f * radius
        r_fit = max(r_fit, MIN_RADIUS_FRACTION * radius)
        shrink = min(r_fit / radius, 1.0) ** 2
        lg = log10_nfa(k, m, lam * shrink, n_tests, sample) + extra
        if lg < best[0]:
            best = (lg, k, r_fit)
    return best


def _consistency(src: np.ndarray, dst: np.ndarray, radius: float) -> tuple[np.ndarray, ...]:
    """Bit-packed rows and degrees (`sgloc.consistency.consistency_bits`) of the pairs whose
    distances agree within 2 * radius in both graphs (no diagonal)."""
    return consistency_bits(src, dst, 2.0 * radius, "distance")


def _hypothesis_graph(
    src: np.ndarray, dst: np.ndarray, radius: float, dof: int, rng: np.random.Generator
) -> tuple[np.ndarray | None, ConsistentPairs | SampledConsistency, float]:
    """(packed rows or None, the consistent pairs, the number of hypotheses RANSAC can form:
    consistent pairs (4 dof) or triples (6 dof)) of the candidates (src, dst). Up to
    ALL_PAIRS_LIMIT candidates from all pairs; above, estimated from a sample of pairs
    (`sgloc.sampled_consistency`: memory linear in the candidates)."""
    m = len(src)
    if m > ALL_PAIRS_LIMIT:
        sampled = SampledConsistency(src, dst, 2.0 * radius, rng)
        return None, sampled, sampled.n_pairs if dof == 4 else sampled.n_triangles()
    if m >= 3:
        consistency, _ = _consistency(src, dst, radius)  # packed rows (m, ceil(m / 64))
    else:
        consistency = np.zeros((m, 1), dtype=np.uint64)
    edges = ConsistentPairs(consistency)  # by position: no list of 16 bytes per pair
    if dof == 4:
        return consistency, edges, float(edges.size)
    return consistency, edges, _triangles(consistency, edges) if m >= 3 else 0.0


def _triangles(bits: np.ndarray, edges: ConsistentPairs) -> float:
    """Number of triangles of the consistency graph (packed rows `bits`) with edges (ii, jj),
    ii < jj: the sum over edges of their common neighbours / 3. Only log10 of the count
    matters, so beyond _TRIANGLE_EDGES edges an evenly spaced subset is scaled up."""
    if edges.size > _TRIANGLE_EDGES:
        pick = np.linspace(0, edges.size - 1, _TRIANGLE_EDGES).astype(np.int64)
        scale, (ii, jj) = edges.size / _TRIANGLE_EDGES, edges.at(pick)
    else:
        scale, (ii, jj) = 1.0, edges.all()
    return float(scale * common_partner_count(bits, ii, jj) / 3.0)


def distinct_from(
    R: np.ndarray, t: np.ndarray, T: np.ndarray, c: np.ndarray, metres: float, degrees: float
) -> np.ndarray:
    """(B,) bool: the hypotheses (R (B,3,3), t (B,3)) that move point `c` (3,) more than
    `metres` away from where T (4x4) moves it, or turn more than `degrees` from T."""
    shift = np.linalg.norm(R @ c + t - (T[:3, :3] @ c + T[:3, 3]), axis=1)
    cosang = (np.einsum("bij,ij->b", R, T[:3, :3]) - 1.0) / 2.0
    turn = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
    return (shift > metres) | (turn > degrees)


def _runner_up(
    src: np.ndarray,
    dst: np.ndarray,
    T: np.ndarray,
    exclude: np.ndarray,
    consistency: np.ndarray | None,
    edges: ConsistentPairs | SampledConsistency,
    radius: float,
    cfg: AcceptanceConfig,
    rng: np.random.Generator,
    dof: int = 6,
    max_tilt: float | None = None,
) -> tuple[int, np.ndarray | None]:
    """Best distinct alternative to T: (its inlier count among the candidates, its 4x4 transform).

    The alternative must stand on its own evidence: it is drawn from, and scored on, only the
    candidates outside `exclude` (those T explains within twice the radius), so a slight tilt of
    T that keeps most of T's matches is not counted as a rival. Hypotheses come from triples of
    pairwise-consistent candidates (`consistency`, packed rows: |D(q_i,q_j) - D(t_i,t_j)| <
    2 * radius; above ALL_PAIRS_LIMIT candidates `edges` is a sample of pairs), drawn at
    random and fitted in one batch; those within the distinctness bounds of T are discarded.
    dof=4: hypotheses about the z axis from the consistent pairs themselves; `max_tilt`
    (degrees): hypotheses tilting the up axis more are not alternatives.
    """
    free = ~exclude
    if free.sum() < 3 or cfg.runner_up_samples <= 0:
        return 0, None
    ps, pd = src[free], dst[free]
    if isinstance(edges, SampledConsistency):
        i, j = edges.draw(free, cfg.runner_up_samples, rng)
        if len(i) == 0:
            return 0, None
    else:
        kept = edges.within(free)
        if kept.size == 0:
            return 0, None
        i, j = kept.at(rng.integers(0, kept.size, cfg.runner_up_samples))
    if dof == 4 and use_compiled(len(src)):
        return _compiled_yaw_runner_up(src, dst, T, exclude, i, j, radius, cfg)
    if dof == 4:
        hyp = _yaw_hypotheses(src, dst, *_first_draws(i, j, len(src)))
    else:
        rows = edges if isinstance(edges, SampledConsistency) else consistency
        hyp = _triplet_hypotheses(src, dst, i, j, rows, free, rng, max_tilt)
    if hyp is None:
        return 0, None
    R, t = hyp
    # Distinctness, measured where it matters: at the centroid of T's support (query frame).
    c = src[exclude].mean(axis=0) if exclude.any() else src.mean(axis=0)
    distinct = distinct_from(R, t, T, c, cfg.distinct_translation, cfg.distinct_rotation)
    if not distinct.any():
        return 0, None
    R, t = R[distinct], t[distinct]
    counts = (squared_residuals(R, t, ps, pd) < radius**2).sum(axis=1)
    h = int(np.argmax(counts))
    T2 = np.eye(4)
    T2[:3, :3], T2[:3, 3] = R[h], t[h]
    return int(counts[h]), T2


def _compiled_yaw_runner_up(
    src, dst, T, exclude, i, j, radius, cfg
) -> tuple[int, np.ndarray | None]:
    """`_runner_up`'s dof=4 branch from the drawn pairs (i, j) on, in one compiled pass
    (`sgloc.kernels.runner_up`): the same alternative, its residuals equal to rounding."""
    from sgloc.kernels.runner_up import best_yaw_alternative

    c = src[exclude].mean(axis=0) if exclude.any() else src.mean(axis=0)
    count, T2, found = best_yaw_alternative(
        np.ascontiguousarray(src, dtype=np.float64),
        np.ascontiguousarray(dst, dtype=np.float64),
        i,
        j,
        ~exclude,
        np.ascontiguousarray(T, dtype=np.float64),
        c,
        float(cfg.distinct_translation),
        float(cfg.distinct_rotation),
        float(radius),
    )
    return (int(count), T2) if found else (0, None)


def _first_draws(i: np.ndarray, j: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The pairs (i, j) without repeats, each at its first draw, in draw order: a pair drawn
    again gives the same 4-dof hypothesis, and the best (first) one stays the same."""
    _, first = np.unique(i * m + j, return_index=True)
    first.sort()
    return i[first], j[first]


def _yaw_hypotheses(src, dst, i, j) -> tuple[np.ndarray, np.ndarray] | None:
    """4-dof hypotheses from consistent candidate pairs (i, j) apart in xy."""
    pair = np.stack([i, j], axis=1)
    S, D = src[pair], dst[pair]
    ok = (
        np.minimum(
            np.linalg.norm(S[:, 1, :2] - S[:, 0, :2], axis=1),
            np.linalg.norm(D[:, 1, :2] - D[:, 0, :2], axis=1),
        )
        > 1e-6
    )
    return yaw_from_pairs(S[ok], D[ok]) if ok.any() else None


def _triplet_hypotheses(
    src, dst, i, j, consistency, free, rng, max_tilt
) -> tuple[np.ndarray, np.ndarray] | None:
    """6-dof hypotheses: each consistent pair (i, j) completed by a random candidate
    consistent with both; tilted beyond `max_tilt` degrees dropped."""
    if isinstance(consistency, SampledConsistency):
        k3 = consistency.third(i, j, free, rng)
        has = k3 >= 0
        if not has.any():
            return None
    else:
        common = unpack_rows(consistency[i] & consistency[j], len(free)) & free
        has = common.any(axis=1)
        if not has.any():
            return None
        keys = np.where(common, rng.random(common.shape, dtype=np.float32), -1.0)
        k3 = np.argmax(keys, axis=1)
    trip = np.column_stack([i, j, k3])[has]
    S, D = src[trip], dst[trip]
    ok = non_collinear(S, 1e-2) & non_collinear(D, 1e-2)
    if not ok.any():
        return None
    R, t = rigid_from_triplets(S[ok], D[ok])
    if max_tilt is not None:
        up = tilt_deg(R) <= max_tilt
        R, t = R[up], t[up]
    return (R, t) if len(R) else None


def permutation_lambda(
    used_near: np.ndarray,
    inlier: np.ndarray,
    tlab: np.ndarray,
    near: np.ndarray,
    chance: _ChanceModel,
) -> float:
    """Expected chance inliers under the permutation null, leave-one-out: candidate i's target
    is drawn from the targets the *other* candidates of its class matched (`used_near`: how
    many of all the class's candidate targets lie within the radius of T q_i; an inlier's own
    target is one of them and is taken out). Drawing from a distribution that holds i's own
    target would make every inlier explain itself: with one candidate of a class its p would
    be 1, whatever the map. A class with a single candidate takes the uniform null's N_c / n_c
    (`near`: class-c target objects within the radius)."""
    m_c = np.bincount(tlab)[tlab].astype(np.float64)
    others = np.maximum(used_near - inlier, 0.0)
    uniform = near / chance.class_count[tlab]
    p = np.where(m_c > 1, others / np.maximum(m_c - 1.0, 1.0), uniform)
    return float(np.sum(p))


def per_object_min(res2: np.ndarray, query_index: np.ndarray) -> np.ndarray:
    """The smallest squared residual per query object of candidates (`query_index` per row): an
    object with several candidate targets is one piece of evidence, inlier when any is."""
    if res2.size == 0 or np.all(query_index[1:] > query_index[:-1]):
        return res2  # one candidate per object (the usual top-1 candidates, sorted by query)
    objects, row_object = np.unique(query_index, return_inverse=True)
    best = np.full(objects.size, np.inf)
    np.minimum.at(best, row_object, res2)
    return best


def inlier_spread(points: np.ndarray, dof: int = 6) -> float:
    """Standard deviation (metres) of `points` (k,3) along their second principal axis; with
    dof=4 along the first principal axis of their xy (with gravity fixing roll and pitch, a
    line of objects fixes the yaw: only its length matters)."""
    if len(points) < 3:
        return 0.0
    if dof == 4:
        s = np.linalg.svd(points[:, :2] - points[:, :2].mean(axis=0), compute_uv=False)
        return float(s[0] / np.sqrt(len(points)))
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return float(s[1] / np.sqrt(len(points)))


def assess(
    query: SemanticGraph,
    target: SemanticGraph,
    candidates: np.ndarray,
    transform: np.ndarray | None,
    radius: float,
    config: AcceptanceConfig | None = None,
    rng: np.random.Generator | None = None,
    dof: int = 6,
    max_tilt: float | None = None,
) -> Assessment:
    """Score an estimated T_target_query against chance (module docstring).

    Args:
        query, target: the two graphs (positions in metres, each in its own frame).
        candidates: (m,2) descriptor matches (query index, target index), before rejection.
        transform: the estimate T_target_query (4x4), or None when estimation failed.
        radius: inlier radius in metres (the RANSAC threshold unless config.radius is set).
        dof, max_tilt: the motion model (as `RansacConfig`) of the runner-up hypotheses.
    """
    cfg = config or AcceptanceConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    if transform is None:
        return Assessment(False, 0.0, "no transform to assess")
    r = float(cfg.radius or radius)
    cand = np.asarray(candidates, dtype=np.int64).reshape(-1, 2)
    m = len(cand)
    src = query.positions[cand[:, 0]]
    dst = target.positions[cand[:, 1]]
    tlab = target.labels[cand[:, 1]]
    moved = src @ transform[:3, :3].T + transform[:3, 3]
    res2 = np.sum((moved - dst) ** 2, axis=1)
    inl = res2 < r**2
    k = int(np.count_nonzero(np.bincount(cand[inl, 0])))  # distinct query objects
    n_classes = max(query.n_classes, target.n_classes)
    chance = _ChanceModel(target, r, n_classes)
    qi = cand[:, 0]
    # Permutation null: target j drawn with the frequency the candidates of its class chose it.
    usage = np.bincount(cand[:, 1], minlength=len(target)).astype(np.float64)
    counts, used = chance.near_counts(apply(transform, query.positions), (None, usage))
    lam = chance.expected_inliers(counts, qi, tlab)
    consistency, edges, n_tests = _hypothesis_graph(src, dst, r, dof, rng)
    sample = 2 if dof == 4 else 3
    obj2 = per_object_min(res2, cand[:, 0])
    lg_uniform, k_fit, r_fit = nfa_over_radii(obj2, r, lam, m, n_tests, sample)
    lam_perm = permutation_lambda(used[qi, tlab], inl, tlab, counts[qi, tlab], chance)
    lg_geo, colocated, mu_geo = log10_colocation_p(query, counts > 0, cand[inl, 0])
    lg_perm = nfa_over_radii(obj2, r, lam_perm, m, n_tests, sample)[0] + min(lg_geo, 0.0)
    lg_best = max(lg_uniform, lg_perm)
    spread = inlier_spread(dst[inl], dof)
    explained = res2 < (2 * r) ** 2
    # The runner-up can only lower the confidence: skip its search when chance alone (or the
    # spread) already rejects; the reported confidence is then 1 / (1 + NFA_best).
    # With dof=4 the spread is along the inliers' first xy axis: a line must be twice as long.
    min_spread = cfg.min_spread * (DOF4_SPREAD_FACTOR if dof == 4 else 1.0)
    hopeless = spread < min_spread or 1.0 / (1.0 + 10.0 ** min(lg_best, 300.0)) < (
        cfg.min_confidence
    )
    if hopeless:
        k2, T2 = 0, None
    else:
        k2, T2 = _runner_up(
            src, dst, transform, explained, consistency, edges, r, cfg, rng, dof, max_tilt
        )
    if T2 is not None:
        (counts2,) = chance.near_counts(apply(T2, query.positions))
        d2 = np.sum((apply(T2, src) - dst) ** 2, axis=1)
        d2 = per_object_min(d2[~explained], cand[~explained, 0])
        lam2 = chance.expected_inliers(counts2, qi, tlab)
        lg_second = nfa_over_radii(d2, r, lam2, m, n_tests, sample)[0]
    else:
        lam2, lg_second = 0.0, np.inf
    details = {
        "inliers": k,
        "candidates": m,
        "expected_chance_inliers": lam,
        "log10_tests": float(np.log10(max(n_tests, 1.0))),
        "log10_nfa": lg_best,
        "fit_radius_m": r_fit,
        "fit_inliers": k_fit,
        "log10_nfa_uniform": lg_uniform,
        "expected_chance_inliers_permutation": lam_perm,
        "colocated_beyond_inliers": colocated,
        "expected_colocated": mu_geo,
        "log10_p_colocation": lg_geo,
        "log10_nfa_permutation_colocation": lg_perm,
        "runner_up_inliers": k2,
        "runner_up_log10_nfa": float(lg_second),
        "spread_m": spread,
    }
    nfa1 = 10.0 ** min(lg_best, 300.0)
    ratio = 0.0 if not np.isfinite(lg_second) else 10.0 ** min(lg_best - lg_second, 300.0)
    confidence = float(np.clip(1.0 / (1.0 + nfa1 + ratio), 0.0, 1.0))
    reason = ""
    if spread < min_spread:
        confidence = 0.0
        reason = (
            f"the {k} inliers lie in a narrow strip (spread {spread:.1f} m < min_spread "
            f"{min_spread} m); the rotation about its line is not determined"
            if dof == 6
            else f"the {k} inliers lie within a few metres (spread {spread:.1f} m along their "
            f"line < {min_spread:g} m = {DOF4_SPREAD_FACTOR:g} x min_spread); too little of the "
            "map agrees to fix the place"
        )
    elif confidence < cfg.min_confidence:
        if ratio > nfa1:
            reason = (
                f"ambiguous: a distinct alignment explains {k2} matches against the best's {k} "
                f"(confidence {confidence:.6g} < min_confidence {cfg.min_confidence})"
            )
        else:
            reason = (
                f"{k} inliers of {m} candidate matches could be chance ({lam:.1f} expected from "
                f"repeated objects; log10 NFA {lg_best:.1f}); confidence {confidence:.6g} < "
                f"min_confidence {cfg.min_confidence}; the maps may not overlap"
            )
    return Assessment(not reason, confidence, reason, details)
