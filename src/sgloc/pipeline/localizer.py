"""Localizer / localize(): run the stages graph pair -> transform, timing each one.

A call puts both graphs in canonical form (`sgloc.maps.canonical`) and holds each in a
`PreparedGraph` (`sgloc.maps.prepared_graph`: its descriptors, neighbour grids, class counts and
matching indexes), which it hands to the stages: the prepared query and target live for the
call, unless the target comes as a `PreparedMap`, whose own prepared graph serves every query.
Nothing is kept between calls anywhere else, so a result does not depend on what ran before."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from sgloc.acceptance import Verdict, accept
from sgloc.descriptors import make_descriptor
from sgloc.errors import InvalidGraphError, SglocError
from sgloc.estimation import FinalFit, PoseEstimate, estimate_pose, final_fit, icp_refine
from sgloc.estimation.covariance import FittedPoints
from sgloc.maps.canonical import CanonicalPair
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.prepared_graph import PreparedGraph
from sgloc.maps.scale import AUTO, ScaleEstimate, estimate_scale, scene_hint
from sgloc.maps.units import units_hint
from sgloc.matching.candidates import match_flagged
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.prepared import PreparedMap, prepare
from sgloc.pipeline.presets import at_estimated_scale
from sgloc.rejection import make_rejector
from sgloc.runtime.timing import StageTimer, run_clock
from sgloc.validation import check_seed

MIN_VERTICES = 3


class NotLocalizedError(SglocError):
    """Raised by `LocalizationResult.raise_if_failed` when no transform was accepted."""


@dataclass
class LocalizationResult:
    """What `localize` found.

    accepted: whether the acceptance test passed (`sgloc.acceptance`; the online records' name
        too); False when the evidence is not enough: then `transform` is None and `reason` says
        why. `success` is a read-only alias of it (the name of earlier versions).
    transform: (4,4) T_target_query, mapping points of the query graph's frame into the target's.
    matches: (k,2) int (query index, target index), the final (RANSAC inlier) matches.
    candidates: (m,2) the descriptor matches before rejection; `scores` their similarities.
    survivors: (s,2) the matches that passed rejection (the input of RANSAC).
    timings: seconds per stage: descriptors, matching, rejection, ransac, estimation, total.
    confidence: in [0, 1], how far the result is to be trusted (None when not assessed).
    covariance: (6,6) covariance of `transform` (None when not localized): tangent order
        [rx, ry, rz, tx, ty, tz] (rad, m), T_true = transform @ Exp(xi), xi in the QUERY frame
        (gtsam.Pose3's convention); measured on real data (`sgloc.estimation.covariance`). Computed
        when first read, from `fitted`.
    config: the call's settings as a nested dict (`LocalizerConfig.to_dict` of `settings`),
        built when first read; `config["scale"]` is the scene scale used (metres).
    scale_estimate: how that scale was estimated from the target map (`sgloc.maps.scale.
        ScaleEstimate`: unit, scene, spacing, extent) when the settings asked for
        scale="auto"; None when the scale was given.
    """

    accepted: bool
    transform: np.ndarray | None
    matches: np.ndarray
    candidates: np.ndarray
    survivors: np.ndarray
    scores: np.ndarray
    timings: dict[str, float]
    reason: str = ""
    confidence: float | None = None
    #: The settings of the call (`config` is their dict).
    settings: LocalizerConfig | None = field(default=None, repr=False)
    #: The matched points the transform was fitted on (`covariance` is computed from them).
    fitted: FittedPoints | None = field(default=None, repr=False)
    scale_estimate: ScaleEstimate | None = None

    @property
    def success(self) -> bool:
        """Read-only alias of `accepted` (the name of earlier versions; kept for user code)."""
        return self.accepted

    @cached_property
    def config(self) -> dict[str, Any]:
        """The call's settings as a nested dict of plain values (`LocalizerConfig.to_dict`)."""
        return {} if self.settings is None else self.settings.to_dict()

    @cached_property
    def covariance(self) -> np.ndarray | None:
        """(6,6) covariance of `transform` (see the class docstring), computed when first read
        (None when not localized)."""
        return None if self.fitted is None else self.fitted.covariance(self.transform)

    def raise_if_failed(self) -> LocalizationResult:
        if not self.accepted:
            raise NotLocalizedError(f"not localized: {self.reason}")
        return self

    def to_dict(self) -> dict[str, Any]:
        """The JSON result document with every match (`sgloc.io.results.document`; schema
        in docs/formats.md)."""
        from sgloc.io.results import document

        return document(self, full=True)


def _canonical_pair(
    query: SemanticGraph, target: SemanticGraph | PreparedMap, config: LocalizerConfig
) -> CanonicalPair:
    """The pair in canonical vertex order and class ids 0..L-1 (`sgloc.maps.canonical`; its
    restore() undoes it): the prepared map's own when it has every class of the query."""
    canonical = target.pair(query, config) if isinstance(target, PreparedMap) else None
    if canonical is None:  # a graph, or a query with a class the prepared map lacks
        target = target.graph if isinstance(target, PreparedMap) else target
        _check_graph(target, "target")
        canonical = CanonicalPair(query, target, config)
    return canonical


def _check_graph(graph: SemanticGraph, role: str) -> None:
    if not isinstance(graph, SemanticGraph):
        raise InvalidGraphError(f"{role} must be a SemanticGraph, got {type(graph).__name__}.")
    if len(graph) < MIN_VERTICES:
        raise InvalidGraphError(
            f"{role} graph {graph.name!r} has {len(graph)} vertices; localization needs at least "
            f"{MIN_VERTICES} objects (map a larger area)."
        )


#: The stages that draw random numbers, each from its own stream, spawned in this order from
#: the seed (`stage_streams`): changing one stage's draws (e.g. n_walks of the random-walk
#: descriptor) leaves every other stage's samples as they were.
RANDOM_STAGES = ("descriptors", "ransac", "acceptance")


def stage_streams(rng: np.random.Generator | int | None) -> dict[str, np.random.Generator]:
    """One independent generator per stage of RANDOM_STAGES: from `np.random.SeedSequence(
    seed).spawn` for a seed (None: fresh entropy), from `Generator.spawn` for a generator."""
    if isinstance(rng, np.random.Generator):
        children = rng.spawn(len(RANDOM_STAGES))
    else:
        seeds = np.random.SeedSequence(check_seed(rng)).spawn(len(RANDOM_STAGES))
        children = [np.random.default_rng(s) for s in seeds]
    return dict(zip(RANDOM_STAGES, children, strict=True))


@dataclass
class _Matched:
    """The matching stage's output: candidates (m,2), their scores, the flags of the
    acceptance test's ratio test (or None) and that ratio."""

    candidates: np.ndarray
    scores: np.ndarray
    distinct: np.ndarray | None
    flag_ratio: float | None


class Localizer:
    """The pipeline with a fixed configuration; call it on (query, target) graphs."""

    def __init__(self, config: LocalizerConfig | None = None) -> None:
        self.config = config or LocalizerConfig()
        self.descriptor = make_descriptor(self.config.descriptor, **self.config.descriptor_params)
        self.rejector = make_rejector(self.config.rejection, **self.config.rejection_params)
        #: With scale="auto": the localizer of each scene estimated so far, by (unit, scene).
        self._at_scale: dict[tuple[float, str], Localizer] = {}

    def prepare(self, target: SemanticGraph) -> PreparedMap:
        """`target` prepared for this localizer's calls (`sgloc.pipeline.prepared`): its canonical
        form,
        descriptors and matching blocks built once; pass it where a target graph goes."""
        return prepare(target, self.config)

    def __call__(
        self,
        query: SemanticGraph,
        target: SemanticGraph | PreparedMap,
        rng: np.random.Generator | int | None = 0,
        clock: Callable[[], float] = run_clock,
    ) -> LocalizationResult:
        """Localize `query` in `target`. `rng`: a seed or generator, split into one stream
        per random stage (`stage_streams`); `clock` (seconds) times the stages (default: wall
        time without compiling the kernels on first use; e.g. time.thread_time for CPU time).
        `target` may be a PreparedMap (the same result).
        With scale="auto" the scene scale is estimated from the target map first."""
        _check_graph(query, "query")
        if self.config.scale == AUTO:
            return self._at_estimated_scale(query, target, rng, clock)
        canonical = _canonical_pair(query, target, self.config)  # undone by restore()
        query, target, cfg = canonical.query, canonical.target, canonical.config
        streams, timer = stage_streams(rng), StageTimer(clock)
        n_classes = max(query.n_classes, target.n_classes)
        prepared = canonical.prepared_target or PreparedGraph(target)  # kept or for this call
        with timer("descriptors"):
            dq, dt = self._describe(query, target, prepared, n_classes, streams["descriptors"])
        prepared_query = PreparedGraph(query, dq)
        with timer("matching"):
            matched = _match(prepared_query, prepared, cfg)
        c = matched.candidates
        weights = _match_weights(cfg, query, c, n_classes)
        pose = estimate_pose(
            query.positions[c[:, 0]],
            target.positions[c[:, 1]],
            self.rejector,
            cfg.ransac,
            streams["ransac"],
            scores=matched.scores,
            weights=weights,
            labels=query.labels[c[:, 0]],
            fit=_final_fit(cfg, query, target),
            timer=timer,
        )
        verdict = self._accept(
            query, prepared, cfg, (dq, dt), matched, pose, streams["acceptance"], timer
        )
        result = LocalizationResult(
            accepted=verdict.accepted,
            transform=verdict.transform,
            matches=verdict.matches,
            candidates=c,
            survivors=c[pose.survivors],
            scores=matched.scores,
            timings=timer.timings,
            reason=verdict.reason,
            confidence=verdict.confidence,
            settings=self.config,
            fitted=_fitted(query, target, verdict, pose, weights, cfg),
        )
        return canonical.restore(result)  # the caller's vertex indices and config

    def _describe(
        self, query: SemanticGraph, target: SemanticGraph, prepared: PreparedGraph,
        n_classes: int, rng: np.random.Generator,
    ) -> tuple:
        """(query descriptors, target descriptors): the target's kept on `prepared` (computed
        there when missing), both drawn from the one descriptors stream `rng`, query first."""
        dq = self.descriptor(query, n_classes, rng)
        if prepared.descriptors is None:
            prepared.descriptors = self.descriptor(target, n_classes, rng)
        return dq, prepared.descriptors

    def _at_estimated_scale(
        self,
        query: SemanticGraph,
        target: SemanticGraph | PreparedMap,
        rng: np.random.Generator | int | None,
        clock: Callable[[], float],
    ) -> LocalizationResult:
        """Localize with the scale of the target map (`sgloc.maps.scale.estimate_scale`; a prepared
        map's own estimate when it was prepared with scale="auto") and its scene's preset
        (`sgloc.pipeline.presets.at_estimated_scale`); the result says so."""
        graph = target.graph if isinstance(target, PreparedMap) else target
        _check_graph(graph, "target")
        estimate = getattr(target, "scale_estimate", None) or estimate_scale(graph)
        key = (estimate.unit, estimate.scene)
        if key not in self._at_scale:  # the same settings for every map of that scene
            self._at_scale[key] = Localizer(at_estimated_scale(self.config, estimate))
        result = self._at_scale[key](query, target, rng, clock)
        result.scale_estimate = estimate
        return result

    def _accept(
        self,
        query: SemanticGraph,
        prepared: PreparedGraph,
        cfg: LocalizerConfig,
        descriptors: tuple[Any, Any],
        matched: _Matched,
        pose: PoseEstimate,
        rng: np.random.Generator,
        timer: StageTimer,
    ) -> Verdict:
        """The acceptance stage (sgloc.acceptance.accept): the test of the pose and, for a
        refused small query, the whole-map verification, refitted by the same final fit, on
        the `prepared` target."""
        target = prepared.graph
        c = matched.candidates
        final = c[pose.inliers] if pose.inliers.size else np.zeros((0, 2), np.int64)
        verdict = accept(
            query, target, *descriptors, c, matched.distinct, pose.transform, final,
            pose.reason, radius=cfg.ransac.threshold, config=cfg.acceptance,
            matching=cfg.matching, motion=cfg.motion, rng=rng, clock=timer.clock,
            refit=lambda matches: _fit_matches(query, target, matches, cfg), prepared=prepared,
        )  # fmt: skip
        timer.add(verdict.timings)
        if not verdict.accepted:
            verdict.reason += units_hint(query, target) + scene_hint(query, target, cfg.scale)
        return verdict


def _match(query: PreparedGraph, target: PreparedGraph, cfg: LocalizerConfig) -> _Matched:
    """Candidate matches of the prepared graphs' descriptors (the target's kept blocks and
    indexes used); also flags the candidates the acceptance test counts (its ratio test) in
    the same pass."""
    flag_ratio = cfg.acceptance.evidence.ratio_for(len(query))
    candidates, scores, distinct = match_flagged(
        query.descriptors, target.descriptors, query.graph.labels, target.graph.labels,
        cfg.matching, flag_ratio, target,
    )  # fmt: skip
    return _Matched(candidates, scores, distinct, flag_ratio)


def _fitted(
    query: SemanticGraph,
    target: SemanticGraph,
    verdict: Verdict,
    pose: PoseEstimate,
    weights: np.ndarray | None,
    cfg: LocalizerConfig,
) -> FittedPoints | None:
    """The points an accepted transform was fitted on, for its covariance
    (sgloc.estimation.covariance):
    RANSAC's inliers with their class weights, or the verification's matches, unweighted."""
    if not verdict.accepted:
        return None
    m = verdict.matches
    w = None if weights is None or verdict.verified else weights[pose.inliers]
    return FittedPoints(query.positions[m[:, 0]], target.positions[m[:, 1]], w,
                        cfg.motion.dof, cfg.motion.max_tilt)  # fmt: skip


def _match_weights(
    cfg: LocalizerConfig, query: SemanticGraph, candidates: np.ndarray, n_classes: int
) -> np.ndarray | None:
    """Per candidate, the weight of its query object's class (cfg.class_weights), or None."""
    if not cfg.class_weights:
        return None
    w = np.ones(n_classes)
    for c, v in cfg.class_weights.items():
        if 0 <= int(c) < n_classes:
            w[int(c)] = v
    return w[query.labels[candidates[:, 0]]]


def _final_fit(cfg: LocalizerConfig, query: SemanticGraph, target: SemanticGraph) -> FinalFit:
    """The final fit these settings ask for (robust refit, class scales, ICP)."""
    icp = None
    if cfg.icp:

        def icp(T: np.ndarray) -> np.ndarray:
            return icp_refine(
                query.positions, query.labels, target.positions, target.labels, T,
                cfg.icp_max_distance,
            )  # fmt: skip

    return FinalFit(
        refine="irls" if cfg.robust_refit else "kabsch",
        class_axes=None if cfg.class_scale == "none" else cfg.class_scale,
        icp=icp,
    )


def _fit_matches(
    query: SemanticGraph, target: SemanticGraph, matches: np.ndarray, cfg: LocalizerConfig
) -> np.ndarray | None:
    """The final fit of `matches` (k,2) (query index, target index), or None if refused."""
    return final_fit(
        query.positions[matches[:, 0]], target.positions[matches[:, 1]], cfg.motion,
        cfg.ransac.threshold, None, query.labels[matches[:, 0]], _final_fit(cfg, query, target),
    )[0]  # fmt: skip


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
        seed: seed of the random generators, one stream per random stage (random walks,
            RANSAC, acceptance: `stage_streams`); ignored when `rng` is given.
        config: a full LocalizerConfig to start from; arguments given here override it.
        preset: named settings applied over `config` (sgloc.pipeline.presets: "paper" = the paper's
        own
            pipeline, "guo" = its baseline, "default", dataset presets).
        **settings: any stage setting by name, e.g. tau=3.0, eta=0.5, min_similarity=0.6,
            top_k=2, mutual=True, strategy="all", iterations=2000, dof=6, max_tilt=None,
            descriptor_radius=40.0 (distance_histogram), class_weights={3: 11.0}, icp=True,
            min_confidence=0.9999 (acceptance strictness, sgloc.acceptance), acceptance=False.
    """
    named = {"descriptor": descriptor, "rejection": rejection, "ransac_threshold": ransac_threshold}
    overrides = {k: v for k, v in named.items() if v is not None} | settings
    if preset is not None:
        from sgloc.pipeline.presets import localizer_settings

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
