"""Verification against the whole map, for small queries (one scan, a short stretch).

A small query's descriptor candidates are too few to carry the decision: an object sees only
part of its neighbourhood, so its best match is often not its partner. Its whole geometry is
cheap to check instead, as relocalization systems do:

1. candidates: each query object's `top_k` most similar same-class target objects;
2. hypotheses: every pair of candidates (two query objects, two target objects) whose distances
   agree within 2 * radius and whose query objects are >= 2 * radius apart in xy fixes a 4-dof
   transform (x, y, z, yaw);
3. score: per hypothesis, the query objects (all of them, not only the matched ones) that land
   within `radius` of a target object of their class (one KD-tree for all classes: the class is
   a fourth coordinate; heights count Z_SCALE), the summed squared distance breaking ties;
4. refit: the best is re-fitted (the 4-dof model's least squares, tilted up to `max_tilt`) to
   the nearest same-class target of each query object within the radius, a few rounds;
5. decide, a-contrario: k = co-located query objects after the refit. Chance model: query
   object i, placed at random near its hypothesised place, lands within r of one of the N_i
   same-class target objects within `verify_density_radius` R of it with probability
   p_i = 1 - exp(-N_i (r / R)^2) (the local density of its class; the object's own partner
   counts in N_i). NFA = (consistent pairs: the hypotheses) * P(Poisson(sum p_i) >= k - 2)
   (two objects fix a hypothesis), evaluated at 1/4, 1/2 and all of the radius
   (`chance.nfa_over_radii`). Rivals: the best of a few refitted hypotheses more
   than 2 * radius (at the query's centroid) or `distinct_rotation` degrees away from the best,
   and the best other place of the target where the constellation the query landed on fits
   again (a world built of copies, such as regular blocks or roadside rows, has such places;
   a query cannot tell the copies apart). confidence = 1 / (1 + NFA + NFA / NFA_rival)
   (`chance.confidence`, as the test's), accepted when >= 1 - (1 - min_confidence) / OPTIMISM,
   when at least MIN_DISTINCT_SUPPORT co-located pairs are distinctive best matches (the
   acceptance test's evidence for the query's size, `select_evidence`: a place without one
   distinctive pair is not recognisable; maps of ONE class are not held to this: their
   descriptors tell objects apart by distances alone, a ratio test seldom passes for the
   right pairs and the wrong alike, and the chance model and the rivals carry the decision),
   and when the co-located objects extend along their first xy axis as there (spread gate).
   Roadside rows are lines, where an area density underestimates the chance: on one-scan
   queries against maps they never saw the model is optimistic by about a decade (the best
   of 283 such pairs reached NFA 10^-3.5, docs/acceptance.md), hence OPTIMISM.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sgloc.acceptance.assessment import inlier_spread, required_spread
from sgloc.acceptance.chance import ChanceModel, confidence, nfa_over_radii
from sgloc.acceptance.config import AcceptanceConfig
from sgloc.acceptance.evidence import select_evidence
from sgloc.acceptance.rivals import distinct_from
from sgloc.estimation import GROUND_VEHICLE, MotionModel, fit_rigid, yaw_from_pairs
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.prepared_graph import PreparedGraph
from sgloc.maps.spatial import ClassKDTree
from sgloc.matching.candidates import MatchingConfig, match_descriptors, match_flagged

#: Rounds of nearest-neighbour re-association and refit of the best hypothesis.
REFIT_ROUNDS = 3
#: Distinct hypotheses refitted in the search for the runner-up (the best scored first).
RUNNER_UPS = 4
#: Co-located pairs that must be distinctive best matches: the minimal sample (a pair) that the
#: whole geometry then extends. Maps of one class are not held to it (`_decide`).
MIN_DISTINCT_SUPPORT = 2
#: The chance model is optimistic by about this factor on real roadside objects (the best of 283
#: one-scan queries against maps they never saw reached NFA 10^-3.5, chance expects ~10^-2.5):
#: the verification requires 1 - confidence this many times below 1 - min_confidence.
OPTIMISM = 10.0


#: Heights count this much in the co-location distance: a yaw-only hypothesis of maps whose
#: gravity differs by a few degrees (up to max_tilt) is metres off in height 30 m away.
Z_SCALE = 0.25


@dataclass
class Verification:
    """Outcome of `verify_small_query`: `accepted`, `transform` T_target_query (None when no
    hypothesis), `confidence` in [0, 1], `matches` (k,2) the co-located (query, target) objects,
    `reason` (empty if accepted), `details` (counts, log10 NFA, spread)."""

    accepted: bool
    transform: np.ndarray | None
    confidence: float
    matches: np.ndarray
    reason: str = ""
    details: dict = field(default_factory=dict)


class ClassTree(ClassKDTree):
    """Nearest same-class target object of many points at once, within `radius` (metres),
    heights scaled by Z_SCALE (`sgloc.maps.spatial.ClassKDTree` over the target's objects)."""

    def __init__(self, target: SemanticGraph, radius: float) -> None:
        super().__init__(target.positions, target.labels, radius, scale=(1.0, 1.0, Z_SCALE))
        self.radius = radius

    def nearest(self, points: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """points (..., n, 3), labels (n,) -> (distance (..., n), inf beyond the radius; target
        index (..., n), len(target) beyond it)."""
        return self.query(points, labels, self.radius)


def _pair_hypotheses(
    qpos: np.ndarray, tpos: np.ndarray, cand: np.ndarray, radius: float, cap: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """4-dof hypotheses (R (H,3,3), t (H,3)) from the candidate pairs consistent in distance,
    at most `cap` (the most similar pairs first: `cand` is sorted by query, then similarity);
    and the number of consistent pairs (the tests)."""
    m = len(cand)
    ii, jj = np.triu_indices(m, 1)
    two_objects = cand[ii, 0] != cand[jj, 0]
    ii, jj = ii[two_objects], jj[two_objects]
    S = np.stack([qpos[cand[ii, 0]], qpos[cand[jj, 0]]], axis=1)
    D = np.stack([tpos[cand[ii, 1]], tpos[cand[jj, 1]]], axis=1)
    dq = np.linalg.norm(S[:, 1] - S[:, 0], axis=1)
    dt = np.linalg.norm(D[:, 1] - D[:, 0], axis=1)
    xy = np.linalg.norm(S[:, 1, :2] - S[:, 0, :2], axis=1)
    ok = (np.abs(dq - dt) < 2.0 * radius) & (xy >= 2.0 * radius) & (cand[ii, 1] != cand[jj, 1])
    n_tests = int(ok.sum())
    S, D = S[ok], D[ok]
    if len(S) > cap:
        S, D = S[:cap], D[:cap]
    if len(S) == 0:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), 0
    R, t = yaw_from_pairs(S, D)
    return R, t, n_tests


def _refit(
    query: SemanticGraph,
    tpos: np.ndarray,
    tree: ClassTree,
    T: np.ndarray,
    max_tilt: float | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Re-associate each query object with its nearest same-class target within the radius and
    refit (4-dof model: tilted up to `max_tilt` degrees), REFIT_ROUNDS times; (T, distances
    (n,), target index (n,))."""
    q = query.positions
    for _ in range(REFIT_ROUNDS):
        d, j = tree.nearest(q @ T[:3, :3].T + T[:3, 3], query.labels)
        ok = np.isfinite(d)
        if ok.sum() < 2:
            break
        T = fit_rigid(q[ok], tpos[j[ok]], None, dof=4, max_tilt=max_tilt)
    d, j = tree.nearest(q @ T[:3, :3].T + T[:3, 3], query.labels)
    return T, d, j


def _local_chance(
    chance: ChanceModel, query: SemanticGraph, T: np.ndarray, radius: float
) -> float:
    """Expected chance co-locations of the query under T: sum over objects of
    1 - exp(-N_i (radius / R)^2), N_i = same-class target objects within R = chance.radius of
    the moved object (the local density of its class times the disc of the radius)."""
    moved = query.positions @ T[:3, :3].T + T[:3, 3]
    (counts,) = chance.near_counts(moved)
    n = counts[np.arange(len(query)), query.labels]
    return float(np.sum(1.0 - np.exp(-n * (radius / chance.radius) ** 2)))


def _log10_nfa(d: np.ndarray, lam: float, n_tests: int, radius: float) -> tuple[float, int]:
    """(log10 NFA, co-located count at the best radius) of per-object distances `d`."""
    d2 = np.where(np.isfinite(d), d, np.inf) ** 2
    lg, k, _ = nfa_over_radii(d2, radius, lam, 0, max(n_tests, 1), sample=2)
    return lg, k


def _scored_hypotheses(
    graph: SemanticGraph, tpos: np.ndarray, tree: ClassTree, cand: np.ndarray, cap: int
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """Pair hypotheses of `graph` (positions in its own frame) onto the target from candidates
    `cand` (graph index, target index), best first: (R, t, consistent pairs, order)."""
    R, t, n_tests = _pair_hypotheses(graph.positions, tpos, cand, tree.radius, cap)
    if len(R) == 0:
        return R, t, n_tests, np.zeros(0, np.int64)
    moved = np.einsum("hij,nj->hni", R, graph.positions) + t[:, None, :]
    d, _ = tree.nearest(moved, graph.labels)
    hit = np.isfinite(d)
    r = tree.radius
    score = hit.sum(axis=1) - np.where(hit, d, r).sum(axis=1) / (r * (len(graph) + 1))
    return R, t, n_tests, np.argsort(-score, kind="stable")


@dataclass
class SearchContext:
    """What the search for rival places needs: the target's positions (n,3), its `ClassTree`,
    the density `ChanceModel`, the motion model's `max_tilt` (degrees) and the rotation
    (degrees) beyond which an alignment is distinct."""

    tpos: np.ndarray
    tree: ClassTree
    chance: ChanceModel
    max_tilt: float | None
    degrees: float


def _best_distinct(
    graph: SemanticGraph,
    hyps: tuple[np.ndarray, np.ndarray, np.ndarray],
    T: np.ndarray,
    context: SearchContext,
    n_tests: int,
) -> tuple[float, int]:
    """(log10 NFA, co-located count) of the best of the RUNNER_UPS best-scored hypotheses
    `hyps` = (R, t, order) that, refitted, stay distinct from T at the centroid of `graph`
    (inf, 0: none)."""
    R, t, order = hyps
    tpos, tree, chance = context.tpos, context.tree, context.chance
    max_tilt, degrees = context.max_tilt, context.degrees
    r = tree.radius
    c = graph.positions.mean(axis=0)
    distinct = distinct_from(R, t, T, c, 2.0 * r, degrees)
    best = (np.inf, 0)
    for h in order[distinct[order]][:RUNNER_UPS]:
        T2 = np.eye(4)
        T2[:3, :3], T2[:3, 3] = R[h], t[h]
        T2, d2, _ = _refit(graph, tpos, tree, T2, max_tilt)
        if distinct_from(T2[None, :3, :3], T2[None, :3, 3], T, c, 2.0 * r, degrees)[0]:
            lg2, k2 = _log10_nfa(d2, _local_chance(chance, graph, T2, r), n_tests, r)
            best = min(best, (lg2, k2))
    return best


def self_rival(
    target: SemanticGraph,
    desc_t,
    placed: np.ndarray,
    context: SearchContext,
    cfg: AcceptanceConfig,
    min_similarity: float,
    n_tests: int,
) -> tuple[float, int]:
    """The target objects the query landed on (`placed`), matched against the rest of the
    target: (log10 NFA, count) of the best other place where the same constellation fits. A
    world built of copies (repeated blocks, repeated roadside rows) fits a query wherever one
    copy is; if the map holds another copy, the place is ambiguous whatever the query."""
    tpos, tree = context.tpos, context.tree
    if len(placed) < 3:
        return np.inf, 0
    sub = SemanticGraph(tpos[placed], target.labels[placed])
    k = int(cfg.verification.verify_top_k) + 1
    matching = MatchingConfig(top_k=k, min_similarity=min_similarity)
    cand, _ = match_descriptors(desc_t[placed], desc_t, sub.labels, target.labels, matching,
                                context.chance.prepared)  # fmt: skip
    cand = cand[cand[:, 1] != placed[cand[:, 0]]]  # not itself
    R, t, _, order = _scored_hypotheses(sub, tpos, tree, cand, cfg.verification.verify_hypotheses)
    if len(R) == 0:
        return np.inf, 0
    return _best_distinct(sub, (R, t, order), np.eye(4), context, n_tests)


def _distinct_support(
    query: SemanticGraph,
    target: SemanticGraph,
    desc_q,
    desc_t,
    matches: np.ndarray,
    cfg: AcceptanceConfig,
    min_similarity: float,
    prepared: PreparedGraph | None = None,
) -> int:
    """How many co-located (query, target) pairs `matches` are the query object's best
    descriptor match and count as evidence for the acceptance test (`select_evidence`)."""
    if len(matches) == 0:
        return 0
    best_match = MatchingConfig(min_similarity=min_similarity)
    ratio = cfg.evidence.ratio_for(len(query))
    best, _, flags = match_flagged(desc_q, desc_t, query.labels, target.labels, best_match, ratio,
                                   prepared)  # fmt: skip
    best = select_evidence(query, target, desc_q, desc_t, best, flags, best_match, cfg.evidence,
                           prepared)  # fmt: skip
    n_t = len(target) + 1
    return int(np.isin(matches[:, 0] * n_t + matches[:, 1], best[:, 0] * n_t + best[:, 1]).sum())


@dataclass
class _Fit:
    """The best hypothesis refitted: T (4x4), per query object distance to its nearest
    same-class target within the radius (inf beyond) and that target's index."""

    T: np.ndarray
    dist: np.ndarray
    j: np.ndarray

    @property
    def matches(self) -> np.ndarray:
        """(k,2) the co-located (query, target) objects."""
        ok = np.isfinite(self.dist)
        return np.column_stack([np.flatnonzero(ok), self.j[ok]]).astype(np.int64)


def verify_small_query(
    query: SemanticGraph,
    target: SemanticGraph,
    desc_q,
    desc_t,
    config: AcceptanceConfig | None = None,
    min_similarity: float = 0.5,
    motion: MotionModel = GROUND_VEHICLE,
    prepared: PreparedGraph | None = None,
) -> Verification:
    """Localize a small `query` by checking its whole geometry against `target` (module
    docstring); desc_q, desc_t: the graphs' vertex descriptors (dense or CSR). `motion`: a 4-dof
    model (the hypotheses are rotations about z), its max_tilt (degrees) bounding the refits;
    candidates need `min_similarity`. prepared: the target's `PreparedGraph` (of `target` and
    desc_t: its grids and matching indexes are used and kept), or None."""
    if motion.dof != 4:
        raise ValueError(f"the whole-map verification needs the 4-dof motion model, got {motion}")
    max_tilt = motion.max_tilt
    cfg = config or AcceptanceConfig()
    vcfg = cfg.verification
    r = float(vcfg.verify_radius)
    matching = MatchingConfig(top_k=int(vcfg.verify_top_k), min_similarity=min_similarity)
    cand, _ = match_descriptors(desc_q, desc_t, query.labels, target.labels, matching, prepared)
    tree = ClassTree(target, r)
    R, t, n_tests, order = _scored_hypotheses(
        query, target.positions, tree, cand, vcfg.verify_hypotheses
    )
    if len(R) == 0:
        empty = np.zeros((0, 2), np.int64)
        return Verification(False, None, 0.0, empty, "no consistent pair of candidates")
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R[order[0]], t[order[0]]
    fit = _Fit(*_refit(query, target.positions, tree, T, max_tilt))
    n_classes = max(query.n_classes, target.n_classes)
    chance = ChanceModel(target, float(vcfg.verify_density_radius), n_classes, prepared)
    context = SearchContext(target.positions, tree, chance, max_tilt, cfg.distinct_rotation)
    evidence = _evidence(query, target, desc_t, fit, (R, t, order), context, cfg,
                         min_similarity, n_tests)  # fmt: skip
    support = _distinct_support(query, target, desc_q, desc_t, fit.matches, cfg, min_similarity,
                                prepared)  # fmt: skip
    classes = len(np.union1d(query.labels, target.labels))
    details = {"candidates": len(cand), **evidence, "distinct_support": support,
               "classes": classes}
    return _decide(query, fit, details, cfg)


def _required(cfg: AcceptanceConfig) -> float:
    """The confidence a verified small query needs (OPTIMISM times closer to 1)."""
    return 1.0 - (1.0 - cfg.min_confidence) / OPTIMISM


def _evidence(
    query: SemanticGraph,
    target: SemanticGraph,
    desc_t,
    fit: _Fit,
    hyps: tuple[np.ndarray, np.ndarray, np.ndarray],
    context: SearchContext,
    cfg: AcceptanceConfig,
    min_similarity: float,
    n_tests: int,
) -> dict:
    """The fit's a-contrario evidence and its rivals: another alignment of the query, or
    another place of the map like this one (searched only when the fit could pass)."""
    r = context.tree.radius
    lam = _local_chance(context.chance, query, fit.T, r)
    lg_best, k = _log10_nfa(fit.dist, lam, n_tests, r)
    ok = np.isfinite(fit.dist)
    spread = inlier_spread(context.tpos[fit.j[ok]], dof=4)
    lg_second, k2 = _best_distinct(query, hyps, fit.T, context, n_tests)
    required = _required(cfg)
    lg_self, k_self = np.inf, 0
    could_pass = required >= 1.0 or lg_best < np.log10(1.0 / required - 1.0)
    if spread >= required_spread(cfg.min_spread, 4) and could_pass:
        placed = np.unique(fit.j[ok])
        lg_self, k_self = self_rival(target, desc_t, placed, context, cfg, min_similarity,
                                     n_tests)  # fmt: skip
    return {
        "hypotheses": n_tests, "colocated": int(ok.sum()), "fit_colocated": k,
        "expected_chance": lam, "log10_nfa": lg_best, "runner_up_colocated": k2,
        "runner_up_log10_nfa": float(lg_second), "self_rival_colocated": k_self,
        "self_rival_log10_nfa": float(lg_self), "spread_m": spread,
    }  # fmt: skip


def _decide(query: SemanticGraph, fit: _Fit, details: dict, cfg: AcceptanceConfig) -> Verification:
    """The verification's verdict from its evidence (`_evidence`): spread gate, distinctive
    support, then the confidence against the best rival."""
    lg_rival = min(details["runner_up_log10_nfa"], details["self_rival_log10_nfa"])
    conf = confidence(details["log10_nfa"], lg_rival)
    n_fit, spread, support = details["colocated"], details["spread_m"], details["distinct_support"]
    min_spread, required = required_spread(cfg.min_spread, 4), _required(cfg)
    reason = ""
    if spread < min_spread:
        conf = 0.0
        reason = (
            f"the {n_fit} objects of the query that fit the map lie within a few metres "
            f"(spread {spread:.1f} m < {min_spread:g} m = 2 x min_spread); too little of the "
            "map agrees (a smaller scene needs a smaller min_spread: --set min_spread=1)"
        )
    elif support < MIN_DISTINCT_SUPPORT and details.get("classes", 2) > 1:
        reason = (
            f"{n_fit} of the query's {len(query)} objects fit the map, but only {support} "
            f"of them are distinctive best matches (< {MIN_DISTINCT_SUPPORT}): a place without "
            "distinctive objects cannot be told from its look-alikes"
        )
    elif conf < required:
        reason = (
            f"{n_fit} of the query's {len(query)} objects fit the map, which chance or "
            f"another place explains as well (confidence {conf:.6g} < {required:.6g}, "
            "min_confidence for a verified small query)"
        )
    return Verification(not reason, fit.T, conf, fit.matches, reason, details)
