"""Localizer / localize(): run the stages graph pair -> transform, timing each one."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sgloc.acceptance import assess
from sgloc.canonical import CanonicalPair
from sgloc.config import LocalizerConfig
from sgloc.descriptors import make_descriptor
from sgloc.distinctive import spatially_distinct
from sgloc.errors import DegenerateGeometryError, InvalidGraphError, SglocError
from sgloc.estimation import (
    check_not_degenerate,
    fit_rigid,
    icp_refine,
    irls_refine,
    ransac,
    tilt_deg,
    weighted_kabsch,
)
from sgloc.graph import SemanticGraph
from sgloc.matching import match_descriptors, match_flagged
from sgloc.prepared import PreparedMap, prepare
from sgloc.rejection import make_rejector
from sgloc.verification import verify_small_query

MIN_VERTICES = 3


class NotLocalizedError(SglocError):
    """Raised by `LocalizationResult.raise_if_failed` when no transform was accepted."""


@dataclass
class LocalizationResult:
    """What `localize` found.

    success: False when the evidence is not enough; then `transform` is None and `reason` says why.
    transform: (4,4) T_target_query, mapping points of the query graph's frame into the target's.
    matches: (k,2) int (query index, target index), the final (RANSAC inlier) matches.
    candidates: (m,2) the descriptor matches before rejection; `scores` their similarities.
    survivors: (s,2) the matches that passed rejection (the input of RANSAC).
    timings: seconds per stage: descriptors, matching, rejection, ransac, estimation, total.
    confidence: in [0, 1], how far the result is to be trusted (None when not assessed).
    """

    success: bool
    transform: np.ndarray | None
    matches: np.ndarray
    candidates: np.ndarray
    survivors: np.ndarray
    scores: np.ndarray
    timings: dict[str, float]
    reason: str = ""
    confidence: float | None = None
    config: dict[str, Any] = field(default_factory=dict)

    def raise_if_failed(self) -> LocalizationResult:
        if not self.success:
            raise NotLocalizedError(f"not localized: {self.reason}")
        return self

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {
            "success": self.success,
            "reason": self.reason,
            "confidence": self.confidence,
            "transform": None if self.transform is None else self.transform.tolist(),
            "n_candidates": int(len(self.candidates)),
            "n_survivors": int(len(self.survivors)),
            "n_matches": int(len(self.matches)),
            "matches": self.matches.tolist(),
            "timings": self.timings,
            "config": self.config,
        }


def _check_graph(graph: SemanticGraph, role: str) -> None:
    if not isinstance(graph, SemanticGraph):
        raise InvalidGraphError(f"{role} must be a SemanticGraph, got {type(graph).__name__}.")
    if len(graph) < MIN_VERTICES:
        raise InvalidGraphError(
            f"{role} graph {graph.name!r} has {len(graph)} vertices; localization needs at least "
            f"{MIN_VERTICES} objects (map a larger area)."
        )


class Localizer:
    """The pipeline with a fixed configuration; call it on (query, target) graphs."""

    def __init__(self, config: LocalizerConfig | None = None) -> None:
        self.config = config or LocalizerConfig()
        self.descriptor = make_descriptor(self.config.descriptor, **self.config.descriptor_params)
        self.rejector = make_rejector(self.config.rejection, **self.config.rejection_params)

    def prepare(self, target: SemanticGraph) -> PreparedMap:
        """`target` prepared for this localizer's calls (`sgloc.prepared`): its canonical form,
        descriptors and matching blocks built once; pass it where a target graph goes."""
        return prepare(target, self.config)

    def __call__(
        self,
        query: SemanticGraph,
        target: SemanticGraph | PreparedMap,
        rng: np.random.Generator | int | None = 0,
        clock: Callable[[], float] = time.perf_counter,
    ) -> LocalizationResult:
        """Localize `query` in `target`; `clock` (seconds) times the stages (e.g.
        time.thread_time for CPU time). `target` may be a PreparedMap (the same result)."""
        _check_graph(query, "query")
        # Canonical vertex order and class ids 0..L-1 (sgloc.canonical); undone by restore().
        canonical = target.pair(query, self.config) if isinstance(target, PreparedMap) else None
        if canonical is None:  # a graph, or a query with a class the prepared map lacks
            target = target.graph if isinstance(target, PreparedMap) else target
            _check_graph(target, "target")
            canonical = CanonicalPair(query, target, self.config)
        query, target, cfg = canonical.query, canonical.target, canonical.config
        rng = np.random.default_rng(rng)
        timings: dict[str, float] = {}
        t0 = clock()

        n_classes = max(query.n_classes, target.n_classes)
        dq = self.descriptor(query, n_classes, rng)
        dt = canonical.target_descriptors  # None unless prepared
        dt = self.descriptor(target, n_classes, rng) if dt is None else dt
        t1 = clock()
        timings["descriptors"] = t1 - t0

        # Also flags the candidates the acceptance test counts (its ratio test): one pass.
        flag_ratio = cfg.acceptance.ratio_for(len(query))
        candidates, scores, distinct = match_flagged(
            dq, dt, query.labels, target.labels, cfg.matching, flag_ratio, canonical.target_blocks
        )
        t2 = clock()
        timings["matching"] = t2 - t1

        src = query.positions[candidates[:, 0]]
        dst = target.positions[candidates[:, 1]]
        kept = self.rejector(src, dst, scores)
        survivors = candidates[kept]
        t3 = clock()
        timings["rejection"] = t3 - t2

        weights = None
        if cfg.class_weights:
            w = np.ones(n_classes)
            for c, v in cfg.class_weights.items():
                if 0 <= int(c) < n_classes:
                    w[int(c)] = v
            weights = w[query.labels[survivors[:, 0]]]
        rs = ransac(src[kept], dst[kept], cfg.ransac, rng, weights)
        t4 = clock()
        timings["ransac"] = t4 - t3

        transform, reason = None, rs.reason
        final = survivors[rs.inliers] if rs.inliers.size else np.zeros((0, 2), np.int64)
        if rs.transform is not None:
            w_final = None if weights is None else weights[rs.inliers]
            transform, reason = _final_fit(query, target, final, w_final, cfg)
        t5 = clock()
        timings["estimation"] = t5 - t4
        timings["total"] = t5 - t0
        if transform is None and not reason:
            reason = "no model accepted"
        confidence = None
        if transform is not None and cfg.acceptance.enabled:
            tested = candidates
            if flag_ratio is not None:
                # Only distinctive matches count as evidence: in a repetitive place near-tied
                # matches line up with a wrong alignment as readily as with the right one.
                exclusion = cfg.acceptance.exclusion_for(len(query))
                if exclusion > 0:  # rivals only at other places (sgloc.distinctive)
                    tested = candidates[
                        spatially_distinct(
                            dq, dt, target.labels, target.positions, candidates, flag_ratio,
                            exclusion,
                        )
                    ]
                elif distinct is not None:
                    tested = candidates[distinct]
                else:
                    strict = dataclasses.replace(cfg.matching, max_ratio=flag_ratio)
                    tested = match_descriptors(dq, dt, query.labels, target.labels, strict)[0]
            verdict = assess(
                query,
                target,
                tested,
                transform,
                cfg.ransac.threshold,
                cfg.acceptance,
                rng,
                dof=cfg.ransac.dof,
                max_tilt=cfg.ransac.max_tilt,
            )
            confidence, reason = verdict.confidence, verdict.reason
            transform = transform if verdict.accepted else None
            timings["acceptance"] = clock() - t5
            timings["total"] += timings["acceptance"]
        if transform is None and _verifies(cfg, len(query)):
            # A small query's candidates are too few to decide: check its whole geometry.
            t6 = clock()
            check = verify_small_query(
                query, target, dq, dt, cfg.acceptance, cfg.matching.min_similarity,
                cfg.ransac.max_tilt,
            )
            # The same final fit as RANSAC's inliers get, on the co-located objects.
            fitted = None
            if check.accepted:
                fitted = _final_fit(query, target, check.matches, None, cfg)[0]
            if fitted is not None:
                transform, final, reason = fitted, check.matches, ""
                confidence = check.confidence
            elif check.reason:
                reason = f"{reason}; checked against the whole map: {check.reason}"
            timings["verification"] = clock() - t6
            timings["total"] += timings["verification"]
        if len(candidates) < 3 and transform is None:
            reason = (
                f"only {len(candidates)} candidate match(es) between the graphs (fewer than "
                "3); the maps may not overlap, or lower min_similarity"
            )
        result = LocalizationResult(
            success=transform is not None,
            transform=transform,
            matches=final if transform is not None else np.zeros((0, 2), np.int64),
            candidates=candidates,
            survivors=survivors,
            scores=scores,
            timings=timings,
            reason="" if transform is not None else reason,
            confidence=confidence,
        )
        return canonical.restore(result)  # the caller's vertex indices and config


def _verifies(cfg: LocalizerConfig, n_query: int) -> bool:
    """Whether a refused query is verified against the whole map (sgloc.verification): the
    acceptance test on, 4-dof model, fewer than `small_query` objects."""
    a = cfg.acceptance
    return a.enabled and a.verify_small and cfg.ransac.dof == 4 and n_query < a.small_query


def _final_fit(
    query: SemanticGraph,
    target: SemanticGraph,
    final: np.ndarray,
    weights: np.ndarray | None,
    cfg: LocalizerConfig,
) -> tuple[np.ndarray | None, str]:
    """The fit on RANSAC's inliers `final` (weighted least squares, then the optional robust
    and ICP refinements) under the motion model; (transform or None, reason)."""
    src, dst = query.positions[final[:, 0]], target.positions[final[:, 1]]
    dof, max_tilt = cfg.ransac.dof, cfg.ransac.max_tilt
    if dof == 6:
        try:
            check_not_degenerate(src, "matched points")
        except DegenerateGeometryError as e:
            return None, str(e)
    transform = fit_rigid(src, dst, weights, dof, max_tilt)
    if dof == 4 and max_tilt is not None:
        tilt = _demanded_tilt(src, dst, weights, transform, cfg.ransac.threshold)
        if tilt > max_tilt:
            return None, _tilt_reason(tilt, max_tilt)
    if cfg.robust_refit:
        scaled = cfg.class_scale != "none"
        plain = transform
        transform = irls_refine(
            src,
            dst,
            transform,
            weights,
            dof=dof,
            max_tilt=max_tilt,
            classes=query.labels[final[:, 0]] if scaled else None,
            class_axes=cfg.class_scale if scaled else "full",
        )
        if not np.all(np.isfinite(transform)):
            # Never hand on a non-finite pose: keep the plain fit if the refit ever fails.
            transform = plain
    if cfg.icp:
        transform = icp_refine(
            query.positions,
            query.labels,
            target.positions,
            target.labels,
            transform,
            cfg.icp_max_distance,
        )
    if max_tilt is not None:
        tilt = tilt_deg(transform[:3, :3])
        if tilt > max(max_tilt, 1e-6):
            return None, _tilt_reason(tilt, max_tilt)
    return transform, ""


def _demanded_tilt(
    src: np.ndarray,
    dst: np.ndarray,
    weights: np.ndarray | None,
    fit: np.ndarray,
    threshold: float,
) -> float:
    """The tilt (degrees) the matches demand: that of their free rigid fit when it explains
    them clearly better than the gravity-bound `fit` (RMS residual lower by more than a tenth
    of the RANSAC threshold), else 0. A yaw-only fit of maps that do not share gravity is
    wrong by their tilt; noisy heights on a narrow strip tilt the free fit without need."""
    try:
        free = weighted_kabsch(src, dst, weights)
    except DegenerateGeometryError:
        return 0.0  # (nearly) collinear: the tilt about their line is not observable

    def rms(T: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((src @ T[:3, :3].T + T[:3, 3] - dst) ** 2, 1))))

    if rms(fit) - rms(free) <= 0.1 * threshold:
        return 0.0
    return float(tilt_deg(free[:3, :3]))


def _tilt_reason(tilt: float, max_tilt: float) -> str:
    return (
        f"the alignment tilts the up axis by {tilt:.0f} deg (> max_tilt {max_tilt} deg): the "
        "maps do not share gravity (set max_tilt=None and dof=6 for any orientation), or one "
        "is mirrored or upside down"
    )


def localize(
    query: SemanticGraph,
    target: SemanticGraph | PreparedMap,
    descriptor: str | None = None,
    rejection: str | None = None,
    ransac_threshold: float | None = None,
    seed: int | None = 0,
    *,
    config: LocalizerConfig | None = None,
    preset: str | None = None,
    rng: np.random.Generator | None = None,
    **settings: Any,
) -> LocalizationResult:
    """Find T_target_query, the rigid transform from `query`'s frame into `target`'s.

    Args:
        query, target: the two robots' semantic graphs (positions in metres); `target` may be
            a PreparedMap (`sgloc.prepare`) for repeated queries against one map.
        descriptor: "distance_histogram" (default) | "triangles" | "histogram" (the paper's) |
            "random_walk" | "fast".
        rejection: "neighbor" (default; the paper's Alg. 1) | "none" (RANSAC alone) | others
            registered in `sgloc.rejection.REJECTORS`.
        ransac_threshold: RANSAC inlier distance T_error, metres (default 5).
            The motion model defaults to a ground vehicle's (dof=4: x, y, z, yaw; maps share
            gravity up to max_tilt=15 deg); dof=6, max_tilt=None allows any rigid motion.
        seed: seed of the random generator (RANSAC, random walks); ignored when `rng` is given.
        config: a full LocalizerConfig to start from; arguments given here override it.
        preset: named settings applied over `config` (sgloc.presets: "paper" = the paper's own
            pipeline, "guo" = its baseline, "default", dataset presets).
        **settings: any stage setting by name, e.g. tau=3.0, eta=0.5, min_similarity=0.6,
            top_k=2, mutual=True, strategy="all", iterations=2000, dof=6, max_tilt=None,
            descriptor_radius=40.0 (distance_histogram), class_weights={3: 11.0}, icp=True,
            min_confidence=0.9999 (acceptance strictness, sgloc.acceptance), acceptance=False.
    """
    named = {"descriptor": descriptor, "rejection": rejection, "ransac_threshold": ransac_threshold}
    overrides = {k: v for k, v in named.items() if v is not None} | settings
    if preset is not None:
        from sgloc.presets import localizer_settings

        overrides = localizer_settings(preset) | overrides
    if config is None and not overrides:
        localizer = _default_localizer()
    else:
        localizer = Localizer((config or LocalizerConfig()).with_overrides(**overrides))
    return localizer(query, target, rng if rng is not None else seed)


_DEFAULT: list[Localizer] = []


def _default_localizer() -> Localizer:
    """The Localizer of the default settings, built once per process (it holds no state that
    a call changes)."""
    if not _DEFAULT:
        _DEFAULT.append(Localizer(LocalizerConfig()))
    return _DEFAULT[0]
