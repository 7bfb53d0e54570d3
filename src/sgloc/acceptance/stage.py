"""The acceptance stage's one entry point: `accept(...) -> Verdict`.

In order: the evidence (`evidence.select_evidence`), the test of the estimate against chance
and a distinct rival (`assessment.assess`), and, for a small query the test refuses (or that
estimation could not localize) under the 4-dof model, the whole-map verification
(`verification.verify_small_query`). The verification's alignment is handed to `refit`, the
caller's final fit (the same one RANSAC's inliers get), on the objects it found co-located:
the stage decides, the caller keeps its own fitting.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sgloc.acceptance.assessment import Assessment, assess
from sgloc.acceptance.config import AcceptanceConfig
from sgloc.acceptance.evidence import select_evidence
from sgloc.acceptance.mirror import looks_mirrored
from sgloc.acceptance.places import elsewhere
from sgloc.acceptance.verification import Verification, verify_small_query
from sgloc.estimation import GROUND_VEHICLE, MotionModel
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.prepared_graph import PreparedGraph
from sgloc.matching.candidates import MatchingConfig
from sgloc.runtime.timing import run_clock

#: Fewer candidate matches than this fix no transform (a triple).
MIN_CANDIDATES = 3


@dataclass
class Verdict:
    """What the acceptance stage decided.

    accepted: the alignment stands; then `transform` (4x4 T_target_query) is set.
    matches: (k,2) (query index, target index) the transform was fitted on: the estimate's
        when the test accepted it, the co-located objects when the whole-map verification
        found it (`verified`); empty when refused.
    confidence: in [0, 1]; None when no test ran (acceptance disabled, or nothing to test).
    reason: why refused (empty when accepted).
    timings: seconds of the parts that ran: "acceptance" (evidence and test) and
        "verification".
    assessment, verification: the parts' own outcomes with their details (None: not run).
    """

    accepted: bool
    transform: np.ndarray | None
    matches: np.ndarray
    confidence: float | None
    reason: str = ""
    verified: bool = False
    timings: dict[str, float] = field(default_factory=dict)
    assessment: Assessment | None = None
    verification: Verification | None = None


def verifies(config: AcceptanceConfig, motion: MotionModel, n_query: int) -> bool:
    """Whether a refused query is verified against the whole map: the acceptance test on,
    `verify_small`, the 4-dof model, a small query (`EvidenceConfig.small_query`)."""
    return (
        config.enabled
        and config.verification.verify_small
        and motion.dof == 4
        and config.evidence.is_small(n_query)
    )


def accept(
    query: SemanticGraph,
    target: SemanticGraph,
    desc_q,
    desc_t,
    candidates: np.ndarray,
    distinct_flags: np.ndarray | None,
    transform: np.ndarray | None,
    matches: np.ndarray,
    reason: str = "",
    *,
    radius: float,
    config: AcceptanceConfig | None = None,
    matching: MatchingConfig | None = None,
    motion: MotionModel = GROUND_VEHICLE,
    refit: Callable[[np.ndarray], np.ndarray | None] | None = None,
    rng: np.random.Generator | None = None,
    clock: Callable[[], float] = run_clock,
    prepared: PreparedGraph | None = None,
) -> Verdict:
    """Accept or refuse the estimate `transform` (T_target_query, None when estimation failed
    with `reason`) fitted on `matches` (k,2).

    Args:
        query, target: the graphs (positions in metres, each in its own frame).
        desc_q, desc_t: their vertex descriptors (dense or CSR).
        candidates: (m,2) the descriptor matches (query index, target index) before rejection;
            `distinct_flags` (m,) bool: which pass the evidence's ratio test
            (`sgloc.matching.candidates.match_flagged` at `config.evidence.ratio_for(len(query))`),
            or None.
        radius: the RANSAC inlier threshold (metres): the test's radius unless config.radius.
        matching: the matching settings (min_similarity; the ratio re-match without flags).
        motion: the motion model (`sgloc.estimation.MotionModel`) of the estimate.
        refit: the final fit of a verified alignment on its co-located matches (k,2) -> 4x4 or
            None (the verification's own refined transform when refit is None).
        rng: draws the runner-up hypotheses; clock: seconds, for `Verdict.timings`; prepared:
            the target's `PreparedGraph` (its grids, counts and indexes used, new ones kept).
    """
    cfg = config or AcceptanceConfig()
    matching = matching or MatchingConfig()
    if transform is None and not reason:
        reason = "no model accepted"
    verdict = Verdict(transform is not None, transform, matches, None, reason)
    if transform is not None and cfg.enabled:
        t0 = clock()
        tested = select_evidence(query, target, desc_q, desc_t, candidates, distinct_flags,
                                 matching, cfg.evidence, prepared)  # fmt: skip
        verdict = _assessed(verdict, query, target, tested, radius, cfg, rng, motion, prepared)
        verdict.timings["acceptance"] = clock() - t0
    if not verdict.accepted and verifies(cfg, motion, len(query)):
        t0 = clock()
        _verify(verdict, query, target, desc_q, desc_t, cfg, matching, motion, refit, prepared)
        verdict.timings["verification"] = clock() - t0
    if verdict.accepted and cfg.enabled and cfg.other_places and verdict.confidence:
        t0 = clock()
        _refuse_elsewhere(verdict, query, target, float(cfg.radius or radius), cfg, motion)
        verdict.timings["acceptance"] = verdict.timings.get("acceptance", 0.0) + clock() - t0
    return _settled(verdict, len(candidates), matching.min_similarity)


def _assessed(
    verdict: Verdict,
    query: SemanticGraph,
    target: SemanticGraph,
    tested: np.ndarray,
    radius: float,
    cfg: AcceptanceConfig,
    rng: np.random.Generator | None,
    motion: MotionModel,
    prepared: PreparedGraph | None,
) -> Verdict:
    """The chance test of `verdict`'s estimate on the evidence matches `tested` (`assess`),
    then the mirror check of an accepted one: a new Verdict carrying the assessment."""
    transform = verdict.transform
    a = assess(query, target, tested, transform, radius, cfg, rng, motion, prepared)
    verdict = Verdict(a.accepted, transform if a.accepted else None, verdict.matches,
                      a.confidence, a.reason, assessment=a)  # fmt: skip
    if verdict.accepted:  # a self-similar strip of a mirrored map (acceptance.mirror)
        known = a.landed if a.radius_m == radius else None
        _refuse_mirrored(verdict, query, target, radius, known, prepared)
    return verdict


def _refuse_elsewhere(
    verdict: Verdict,
    query: SemanticGraph,
    target: SemanticGraph,
    radius: float,
    cfg: AcceptanceConfig,
    motion: MotionModel,
) -> None:
    """Lower `verdict`'s confidence by the query's fit at the target's other places
    (`places.elsewhere`), and refuse it when that falls below min_confidence."""
    conf, reason, _ = elsewhere(query, target, verdict.transform, float(verdict.confidence),
                                radius, cfg, motion)  # fmt: skip
    verdict.confidence = conf
    if reason:
        verdict.accepted, verdict.transform, verdict.reason = False, None, reason


def _refuse_mirrored(
    verdict: Verdict,
    query: SemanticGraph,
    target: SemanticGraph,
    radius: float,
    plain_landed: np.ndarray | None = None,
    prepared: PreparedGraph | None = None,
) -> None:
    """Refuse `verdict`'s alignment when the query, reflected across its inliers' line, lands
    clearly more objects on the target (`looks_mirrored`; `plain_landed`: the test's own
    count of the aligned query, when at this radius); updates `verdict`."""
    inliers = np.flatnonzero(np.bincount(verdict.matches[:, 0]))  # np.unique, without a sort
    mirrored, plain, flipped = looks_mirrored(
        query, target, verdict.transform, inliers, radius, plain_landed, prepared
    )
    if mirrored:
        verdict.accepted, verdict.transform, verdict.confidence = False, None, 0.0
        verdict.reason = (
            f"the query looks mirrored against the target: reflected across the line of its "
            f"{len(inliers)} inliers it lands {flipped} objects on the target's, the alignment "
            f"only {plain}; check the frame conventions (one map may be left-handed, x -> -x)"
        )


def _settled(verdict: Verdict, n_candidates: int, min_similarity: float) -> Verdict:
    """The verdict as handed on: no reason when accepted; no transform and no matches when
    refused, and the reason of too few candidates when that was the cause (with a lower
    `min_similarity` than the one used to try)."""
    if verdict.accepted:
        verdict.reason = ""
        return verdict
    verdict.transform, verdict.matches = None, np.zeros((0, 2), np.int64)
    if n_candidates < MIN_CANDIDATES:
        verdict.reason = (
            f"only {n_candidates} candidate match(es) between the graphs (fewer than "
            f"{MIN_CANDIDATES}); the maps may not overlap, or {_similarity_hint(min_similarity)}"
        )
    return verdict


def _similarity_hint(used: float) -> str:
    """How to ask for more candidate matches than `min_similarity=used` gave: the default when
    `used` is above it, else half of `used`."""
    if used <= 0.0:
        return "min_similarity is 0 already: every same-class pair was a candidate"
    default = MatchingConfig().min_similarity
    lower = default if used > default else round(used / 2, 3)
    return (
        f"lower the similarity needed for a match (min_similarity {used:g} now; e.g. --set "
        f"min_similarity={lower:g}; Python: min_similarity={lower:g})"
    )


def _verify(
    verdict: Verdict,
    query: SemanticGraph,
    target: SemanticGraph,
    desc_q,
    desc_t,
    cfg: AcceptanceConfig,
    matching: MatchingConfig,
    motion: MotionModel,
    refit: Callable[[np.ndarray], np.ndarray | None] | None,
    prepared: PreparedGraph | None = None,
) -> None:
    """A small query's candidates are too few to decide: check its whole geometry against the
    map, and take its alignment (refitted by `refit`) when it passes; updates `verdict`."""
    check = verify_small_query(
        query, target, desc_q, desc_t, cfg, matching.min_similarity, motion, prepared
    )
    verdict.verification = check
    fitted = None
    if check.accepted:
        fitted = check.transform if refit is None else refit(check.matches)
    if fitted is not None:
        verdict.accepted, verdict.verified = True, True
        verdict.transform, verdict.matches = fitted, check.matches
        verdict.confidence, verdict.reason = check.confidence, ""
    elif check.reason:
        verdict.reason = f"{verdict.reason}; checked against the whole map: {check.reason}"
