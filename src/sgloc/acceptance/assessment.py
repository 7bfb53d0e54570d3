"""The acceptance test: is an estimated alignment backed by evidence, or could chance explain it?

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

A repeating layout (a street grid, a fixed spacing of poles, blocks or rooms of one template)
makes many inliers one coincidence, which the nulls above count as many. With
`repetition_shifts` > 0 (off by default) an estimate that passes is checked against it
(`sgloc.acceptance.repetition`): the query is also scored under
the target's self-similar shifts near the estimate, and the weight p of the best such rival
(the objects only it lands against those only the estimate lands, each against what a shift
lands by chance) joins the rival term: confidence = 1 / (1 / confidence + p), about 1/2 when
a shift explains the query as well ("ambiguous"). With `layout_shifts` > 0 (off by default)
the estimate is also weighed against the maps' own repetition: each map's
part of the claimed overlap moved by the map's self-similar shifts tells, per class, how
often a copy of the layout lands an object; NFA_layout = (the tests) x P(a copy lands as
many of the covered query objects as the estimate) joins the rival term the same way, so
an alignment at a copy of a street grid (a lattice offset) is refused as ambiguous while a
true one, which lands also what the layout does not repeat, passes. With `min_agreement` >
0, an estimate whose claimed overlap mostly disagrees (too few of the query objects it puts
next to target objects land on one of their class) is refused too.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sgloc.acceptance.chance import (
    ChanceModel,
    chance_terms,
    colocation_tail,
    confidence,
    confidence_terms,
    object_nfa_over_radii,
    pair_consistency,
    triangle_count,
)
from sgloc.acceptance.config import AcceptanceConfig
from sgloc.acceptance.repetition import Repetition, check_repetition
from sgloc.acceptance.rivals import runner_up
from sgloc.consistency.pairwise import ALL_PAIRS_LIMIT, ConsistentPairs
from sgloc.consistency.sampled import SampledConsistency
from sgloc.estimation import ANY_RIGID, MotionModel
from sgloc.geometry import apply
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.prepared_graph import PreparedGraph

#: With dof=4, inliers must extend this many times `min_spread` along their first xy axis
#: (measured: at 1 x, clusters of a few exact coincidences in the rendered city's regular
#: blocks, about 8 m long, passed as non-overlapping pairs).
DOF4_SPREAD_FACTOR = 2.0


@dataclass
class Assessment:
    """Outcome of `assess`: `accepted`, `confidence` in [0, 1], `reason` (empty if accepted),
    and `details` (inliers, lambda, log10 NFA of best and runner-up, spread in metres).
    `landed`: (n,) bool, the query objects within `radius_m` (distance <= radius) of a
    same-class target object under the estimate (None when no estimate was tested)."""

    accepted: bool
    confidence: float
    reason: str = ""
    details: dict = field(default_factory=dict)
    landed: np.ndarray | None = field(default=None, repr=False)
    radius_m: float | None = None


def inlier_spread(points: np.ndarray, dof: int = 6) -> float:
    """Standard deviation (metres) of `points` (k,3) along their second principal axis; with
    dof=4 along the first principal axis of their xy (with gravity fixing roll and pitch, a
    line of objects fixes the yaw: only its length matters)."""
    if len(points) < 3:
        return 0.0
    if dof == 4:  # the xy principal axis in closed form (compiled)
        from sgloc.acceptance.evidence_kernels import xy_axis

        return float(xy_axis(np.ascontiguousarray(points, dtype=np.float64))[4]
                     / np.sqrt(len(points)))  # fmt: skip
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return float(s[1] / np.sqrt(len(points)))


def required_spread(min_spread: float, dof: int) -> float:
    """Metres the inliers must spread (`inlier_spread`): `min_spread`, with dof=4 (along their
    line) DOF4_SPREAD_FACTOR times it."""
    return min_spread * (DOF4_SPREAD_FACTOR if dof == 4 else 1.0)


def squared_residuals_of(T: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(m,) squared distances (m^2) of src (m,3) moved by T (4x4) from dst (m,3): compiled in
    one pass."""
    if len(src) == 0:
        return np.zeros(0)
    from sgloc.acceptance.evidence_kernels import moved_residuals

    return moved_residuals(np.ascontiguousarray(T, dtype=np.float64), src, dst)


@dataclass
class _Candidates:
    """The tested candidates under the estimate T: (m,2) indices (their query objects `qi`
    contiguous), their points (m,3) in each
    frame, target classes, squared residuals (m^2) under T and inliers within the radius."""

    cand: np.ndarray
    qi: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    tlab: np.ndarray
    res2: np.ndarray
    inlier: np.ndarray

    @classmethod
    def of(cls, query, target, candidates, transform, radius: float) -> _Candidates:
        cand = np.asarray(candidates, dtype=np.int64).reshape(-1, 2)
        src = query.positions[cand[:, 0]]
        dst = target.positions[cand[:, 1]]
        res2 = squared_residuals_of(transform, src, dst)
        tlab = np.asarray(target.labels[cand[:, 1]], dtype=np.int64)
        qi = np.ascontiguousarray(cand[:, 0])
        return cls(cand, qi, src, dst, tlab, res2, res2 < radius**2)


@dataclass
class _Tests:
    """The hypotheses RANSAC can form from the candidates: consistent pairs (4 dof) or
    consistent triples (6 dof); `sample` matches fix one."""

    consistency: np.ndarray | None
    edges: ConsistentPairs | SampledConsistency
    n_tests: float
    sample: int

    @classmethod
    def of(cls, c: _Candidates, radius: float, dof: int, rng: np.random.Generator) -> _Tests:
        """Up to ALL_PAIRS_LIMIT candidates from all pairs; above, estimated from a sample of
        pairs (`sgloc.consistency.sampled`: memory linear in the candidates)."""
        m = len(c.cand)
        if m > ALL_PAIRS_LIMIT:
            sampled = SampledConsistency(c.src, c.dst, 2.0 * radius, rng)
            n = sampled.n_pairs if dof == 4 else sampled.n_triangles()
            return cls(None, sampled, float(n), 2 if dof == 4 else 3)
        if m >= 3:
            consistency, _ = pair_consistency(c.src, c.dst, radius)  # packed (m, ceil(m / 64))
        else:
            consistency = np.zeros((m, 1), dtype=np.uint64)
        edges = ConsistentPairs(consistency)  # by position: no list of 16 bytes per pair
        if dof == 4:
            n_tests = float(edges.size)
        else:
            n_tests = triangle_count(consistency, edges) if m >= 3 else 0.0
        return cls(consistency, edges, n_tests, 2 if dof == 4 else 3)


def _best_evidence(
    query: SemanticGraph,
    target: SemanticGraph,
    c: _Candidates,
    transform: np.ndarray,
    chance: ChanceModel,
    tests: _Tests,
) -> tuple[dict, np.ndarray]:
    """The evidence for the estimate under both nulls (module docstring): the details of
    `Assessment` up to the runner-up, and (n, n_classes) bool: which classes have a target
    object within the radius of each moved query object."""
    r, cand, qi = chance.radius, c.cand, c.qi
    m = len(cand)
    # Permutation null: target j drawn with the frequency the candidates of its class chose it.
    moved = apply(transform, query.positions)
    counts, used = chance.near_counts_and_targets(moved, cand[:, 1])
    # k: distinct inlier query objects; colocated of mu_geo expected beyond them.
    k, lam, lam_perm, colocated, mu_geo = chance_terms(
        query.labels, counts, used, qi, c.tlab, c.inlier, chance
    )
    (lg_uniform, k_fit, r_fit), (lg_perm, _, _) = object_nfa_over_radii(
        c.res2, qi, np.ones(m, dtype=bool), len(query), r, (lam, lam_perm), m, tests.n_tests,
        tests.sample,
    )  # fmt: skip
    presence = counts > 0
    lg_geo = colocation_tail(colocated, mu_geo)
    lg_perm += min(lg_geo, 0.0)
    return {
        "inliers": k,
        "candidates": m,
        "expected_chance_inliers": lam,
        "log10_tests": float(np.log10(max(tests.n_tests, 1.0))),
        "log10_nfa": max(lg_uniform, lg_perm),
        "fit_radius_m": r_fit,
        "fit_inliers": k_fit,
        "log10_nfa_uniform": lg_uniform,
        "expected_chance_inliers_permutation": lam_perm,
        "colocated_beyond_inliers": colocated,
        "expected_colocated": mu_geo,
        "log10_p_colocation": lg_geo,
        "log10_nfa_permutation_colocation": lg_perm,
    }, presence


def _rival_nfa(
    query: SemanticGraph,
    c: _Candidates,
    T2: np.ndarray | None,
    explained: np.ndarray,
    chance: ChanceModel,
    tests: _Tests,
) -> float:
    """log10 NFA of the runner-up T2 on the candidates the estimate does not explain (inf
    without a runner-up)."""
    if T2 is None:
        return np.inf
    (counts2,) = chance.near_counts(apply(T2, query.positions))
    d2 = squared_residuals_of(T2, c.src, c.dst)
    lam2 = chance.expected_inliers(counts2, c.qi, c.tlab)
    return object_nfa_over_radii(d2, c.qi, ~explained, len(query), chance.radius, (lam2,),
                                 len(c.cand), tests.n_tests, tests.sample)[0][0]  # fmt: skip


def assess(
    query: SemanticGraph,
    target: SemanticGraph,
    candidates: np.ndarray,
    transform: np.ndarray | None,
    radius: float,
    config: AcceptanceConfig | None = None,
    rng: np.random.Generator | None = None,
    motion: MotionModel = ANY_RIGID,
    prepared: PreparedGraph | None = None,
) -> Assessment:
    """Score an estimated T_target_query against chance (module docstring).

    Args:
        query, target: the two graphs (positions in metres, each in its own frame).
        candidates: (m,2) descriptor matches (query index, target index), before rejection.
        transform: the estimate T_target_query (4x4), or None when estimation failed.
        radius: inlier radius in metres (the RANSAC threshold unless config.radius is set).
        rng: draws the runner-up's hypotheses.
        motion: the motion model (`MotionModel`) of the runner-up hypotheses.
        prepared: the target's `PreparedGraph` (its neighbour grids and class counts are
            used and kept), or None.
    """
    dof, max_tilt = motion.dof, motion.max_tilt
    cfg = config or AcceptanceConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    if transform is None:
        return Assessment(False, 0.0, "no transform to assess")
    r = float(cfg.radius or radius)
    c = _Candidates.of(query, target, candidates, transform, r)
    chance = ChanceModel(target, r, max(query.n_classes, target.n_classes), prepared)
    tests = _Tests.of(c, r, dof, rng)
    details, presence = _best_evidence(query, target, c, transform, chance, tests)
    seen = {"landed": presence[np.arange(len(query)), query.labels], "radius_m": r}
    lg_best = details["log10_nfa"]
    spread = inlier_spread(c.dst[c.inlier], dof)
    explained = c.res2 < (2 * r) ** 2
    # The runner-up can only lower the confidence: skip its search when chance alone (or the
    # spread) already rejects; the reported confidence is then 1 / (1 + NFA_best).
    min_spread = required_spread(cfg.min_spread, dof)
    k2, T2 = 0, None
    if not (spread < min_spread or confidence(lg_best) < cfg.min_confidence):
        k2, T2 = runner_up(c.src, c.dst, transform, explained, tests.consistency, tests.edges,
                           r, cfg, rng, dof, max_tilt)  # fmt: skip
    lg_second = _rival_nfa(query, c, T2, explained, chance, tests)
    details |= {"runner_up_inliers": k2, "runner_up_log10_nfa": float(lg_second),
                "spread_m": spread}  # fmt: skip
    conf = confidence(lg_best, lg_second)
    if details["candidates"] == 0 or details["inliers"] < 3:
        return Assessment(False, 0.0, _few_reason(details, r), details, **seen)
    if spread < min_spread:
        return Assessment(False, 0.0, _spread_reason(details, min_spread, dof), details, **seen)
    if conf < cfg.min_confidence:
        return Assessment(False, conf, _chance_reason(details, conf, cfg), details, **seen)
    if cfg.repetition_shifts == 0 and cfg.min_agreement == 0 and not cfg.layout_shifts:
        return Assessment(True, conf, "", details, **seen)
    return _against_repetition(Assessment(True, conf, "", details, **seen), query, target, c,
                               transform, cfg, tests.n_tests)  # fmt: skip


def _against_repetition(
    passed: Assessment,
    query: SemanticGraph,
    target: SemanticGraph,
    c: _Candidates,
    transform: np.ndarray,
    cfg: AcceptanceConfig,
    n_tests: float = 1.0,
) -> Assessment:
    """The assessment `passed` (accepted so far) after the repetition checks: its confidence
    with the best self-similar shift and the layout's copies (NFA_layout over `n_tests`
    hypotheses) as rivals, refused when that falls below min_confidence or when the claimed
    overlap disagrees (`min_agreement`)."""
    rep = _repetition(query, target, c, transform, float(passed.radius_m), cfg)
    passed.details |= _repetition_details(rep)
    lg_layout = -np.inf
    if rep.layout is not None:
        lg_layout = min(rep.layout.log10_tail + float(np.log10(max(n_tests, 1.0))), 300.0)
        passed.details["layout_log10_nfa"] = float(lg_layout)
    before = passed.confidence
    for lg in (rep.log10_p, lg_layout):  # each joins the test's rival term
        if np.isfinite(lg) and passed.confidence > 0:
            passed.confidence = float(1.0 / (1.0 / passed.confidence + 10.0**lg))
    if passed.confidence < cfg.min_confidence and _layout_decides(rep, before, lg_layout, cfg):
        passed.accepted, passed.reason = False, layout_reason(rep, passed.confidence, cfg)
    elif passed.confidence < cfg.min_confidence:
        passed.accepted, passed.reason = False, repeated_reason(rep, passed.confidence, cfg)
    elif cfg.min_agreement > 0 and rep.covered >= cfg.min_covered \
            and rep.agreement < cfg.min_agreement:  # fmt: skip
        passed.accepted, passed.reason = False, disagreement_reason(rep, cfg)
    return passed


def _layout_decides(rep: Repetition, before: float, lg_layout: float,
                    cfg: AcceptanceConfig) -> bool:
    """Whether the layout's copies alone (check 3) refuse a `before` confidence."""
    if rep.layout is None or not np.isfinite(lg_layout) or before <= 0:
        return False
    return 1.0 / (1.0 / before + 10.0**lg_layout) < cfg.min_confidence


def _repetition(
    query: SemanticGraph,
    target: SemanticGraph,
    c: _Candidates,
    transform: np.ndarray,
    radius: float,
    cfg: AcceptanceConfig,
) -> Repetition:
    """The repetition checks (`sgloc.acceptance.repetition`) of the estimate, anchored on the
    target objects of its inliers."""
    shifts = (cfg.distinct_translation, cfg.repetition_search, cfg.repetition_shifts)
    radii = cfg.repetition_radii(radius, _precision(c))
    return check_repetition(query, target, apply(transform, query.positions),
                            c.cand[c.inlier, 1], radii, shifts, cfg.layout_shifts)  # fmt: skip


def _precision(c: _Candidates) -> float:
    """Metres: the median residual of the inlier candidates under the estimate."""
    return float(np.sqrt(np.median(c.res2[c.inlier]))) if c.inlier.any() else 0.0


def _repetition_details(rep: Repetition) -> dict:
    """The repetition checks' figures for `Assessment.details`."""
    return {
        "agreement_landed": rep.landed,
        "agreement_covered": rep.covered,
        "repetition_shifts_tried": rep.shifts_tried,
        "repetition_shift_m": None if rep.shift is None else float(np.hypot(*rep.shift[:2])),
        "repetition_rival_only": rep.rival_only,
        "repetition_estimate_only": rep.estimate_only,
        "repetition_log10_p": float(rep.log10_p),
    } | ({} if rep.layout is None else {
        "layout_shifts_measured": rep.layout.shifts,
        "layout_rate": rep.layout.rate,
        "layout_expected_landed": float(rep.layout.covered @ rep.layout.p),
        "layout_log10_tail": float(rep.layout.log10_tail),
    })  # fmt: skip


def layout_reason(rep: Repetition, conf: float, cfg: AcceptanceConfig) -> str:
    """Why the maps' repeating layout makes the estimate ambiguous (check 3)."""
    lay = rep.layout
    landed, covered = int(lay.landed.sum()), int(lay.covered.sum())
    expected = float(lay.covered @ lay.p)
    return (
        f"ambiguous: the maps repeat themselves (their shifted copies land {100 * lay.rate:.0f} "
        f"% of their objects again); of the {covered} query objects the alignment puts next "
        f"to the target's, {landed} land on an object of their class, against {expected:.1f} "
        f"for a copy of the repeating layout (confidence {conf:.6g} < min_confidence "
        f"{cfg.min_confidence}); the place cannot be told from its copies: a larger map "
        "(more of what does not repeat) decides (--set layout_shifts=0 turns this check off; "
        "Python: layout_shifts=0)"
    )


def repeated_reason(rep: Repetition, conf: float, cfg: AcceptanceConfig) -> str:
    """Why a repeating layout makes the estimate ambiguous."""
    shift = float(np.hypot(*rep.shift[:2])) if rep.shift is not None else 0.0
    return (
        f"ambiguous: the target map repeats itself; moved {shift:.1f} m further along the "
        f"repetition the query lands {rep.rival_only} objects the alignment does not, against "
        f"{rep.estimate_only} only the alignment lands (confidence {conf:.6g} < "
        f"min_confidence {cfg.min_confidence}); the place cannot be told from its copies "
        "(--set repetition_shifts=0 turns this check off; Python: repetition_shifts=0)"
    )


def disagreement_reason(rep: Repetition, cfg: AcceptanceConfig) -> str:
    """Why an alignment whose overlap mostly disagrees is refused."""
    land, cover = rep.radii
    return (
        f"only {rep.landed} of the {rep.covered} query objects the alignment puts next to the "
        f"target's (within {cover:.3g} m) land on an object of their class (within {land:.3g} "
        "m): "
        f"{100 * rep.agreement:.0f} % < min_agreement {100 * cfg.min_agreement:g} %; where two "
        "maps truly overlap most do, so this looks like a coincidence of a repeating layout "
        "(--set min_agreement=0 turns this check off, Python: min_agreement=0; agreement_radius "
        "and cover_radius set the distances)"
    )


def _few_reason(details: dict, radius: float) -> str:
    """Why nothing (no distinctive candidate) or too little (< 3 inliers) backs the estimate."""
    if details["candidates"] == 0:
        return (
            "no candidate match is distinctive: every object's descriptor nearly ties with "
            "another object of its class (objects listed twice side by side, or a scene that "
            "repeats); merge duplicate objects, or turn the ratio test off with "
            "--set distinct_ratio=null (Python: distinct_ratio=None)"
        )
    return (
        f"only {details['inliers']} query object(s) agree with the best alignment (within "
        f"{radius:g} m); the maps may not overlap"
    )


#: What a spread refusal tells about its setting (metres, chosen for street-sized scenes).
_SPREAD_SETTING = (
    "; min_spread is in metres for street-sized maps: a smaller scene needs a smaller one "
    "(--set min_spread=1; Python: min_spread=1)"
)


def _spread_reason(details: dict, min_spread: float, dof: int) -> str:
    k, spread = details["inliers"], details["spread_m"]
    if dof == 6:
        return (
            f"the {k} inliers lie in a narrow strip (spread {spread:.1f} m < min_spread "
            f"{min_spread} m); the rotation about its line is not determined{_SPREAD_SETTING}"
        )
    return (
        f"the {k} inliers lie within a few metres (spread {spread:.1f} m along their "
        f"line < {min_spread:g} m = {DOF4_SPREAD_FACTOR:g} x min_spread); too little of the "
        f"map agrees to fix the place{_SPREAD_SETTING}"
    )


def _chance_reason(details: dict, conf: float, cfg: AcceptanceConfig) -> str:
    """Why a confidence below min_confidence: the rival (ambiguous) or chance."""
    k, k2, lg_best = details["inliers"], details["runner_up_inliers"], details["log10_nfa"]
    nfa, ratio = confidence_terms(lg_best, details["runner_up_log10_nfa"])
    if ratio > nfa:
        return (
            f"ambiguous: a distinct alignment explains {k2} matches against the best's {k} "
            f"(confidence {conf:.6g} < min_confidence {cfg.min_confidence})"
        )
    return (
        f"{k} inliers of {details['candidates']} candidate matches could be chance "
        f"({details['expected_chance_inliers']:.1f} expected from repeated objects; about "
        f"10^{lg_best:.1f} such alignments expected by chance); confidence {conf:.6g} < "
        f"min_confidence {cfg.min_confidence:g} (a lower one accepts more: --set "
        f"min_confidence={_lower_confidence(cfg.min_confidence):g}); the maps may not overlap"
    )


def _lower_confidence(used: float) -> float:
    """A min_confidence that accepts more than `used`: one nine fewer (0.9999 -> 0.999), or half
    of `used` below 0.95."""
    return round(1.0 - 10.0 * (1.0 - used), 12) if used >= 0.95 else round(used / 2, 3)
