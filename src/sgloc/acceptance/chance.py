"""The chance model of the acceptance stage: how often chance alone explains an alignment.

`ChanceModel` counts the same-class target objects near moved query objects (one compiled
neighbour search on a grid of cells, `sgloc.maps.neighbor_kernels`); `log10_nfa` /
`nfa_over_radii` turn inlier counts and the expected chance inliers into a number of false
alarms (NFA, a-contrario); `confidence` is the one formula that weighs the best hypothesis
against its rival and chance. Used by the test
(`assessment`) and by the whole-map verification (`verification`).
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

from sgloc.consistency.pairwise import ConsistentPairs, common_partner_count, consistency_bits
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.prepared_graph import PreparedGraph

_LN10 = np.log(10.0)
_TRIANGLE_EDGES = 2048
#: The precision-adapted inlier radius is at least this fraction of the radius.
MIN_RADIUS_FRACTION = 0.1
#: `ChanceModel.near_counts_and_targets` searches once when the map has at most this many
#: objects per query object or target.
_ONE_SEARCH = 8
#: NFAs are capped at 10^300 (10.0 ** x overflows beyond about 308).
_MAX_LOG10 = 300.0


def _log_comb3(m: int) -> float:
    """ln C(m, 3)."""
    if m < 3:
        return 0.0
    from scipy.special import gammaln  # deferred, as scipy.spatial below: ~0.3 s together

    return float(gammaln(m + 1) - gammaln(4) - gammaln(m - 2))


class ChanceModel:
    """Chance agreement of a transform under the nulls, from one neighbour search: the
    same-class target objects within the radius of each moved query object.

    prepared: the target's `PreparedGraph` when the caller keeps one (the localizer's, or a
    prepared map's): the search's grid at this radius and the class counts come from it,
    built once for every model of a call and every query of a kept map (a query then costs
    O(its objects x the map objects around them), not O(map)). Without it the model keeps its
    own for its searches."""

    def __init__(
        self,
        target: SemanticGraph,
        radius: float,
        n_classes: int,
        prepared: PreparedGraph | None = None,
    ) -> None:
        self.prepared = PreparedGraph(target) if prepared is None else prepared
        self.positions = self.prepared.positions
        self.labels = target.labels
        self.n_classes = n_classes
        self.radius = radius

    @cached_property
    def class_count(self) -> np.ndarray:
        """(at least n_classes,) float64: the target objects of each class."""
        return class_counts(self.labels, self.n_classes, self.prepared.class_counts)

    def near_counts(
        self, moved: np.ndarray, weights: tuple[np.ndarray | None, ...] = (None,)
    ) -> list[np.ndarray]:
        """For each entry of `weights`: (n, n_classes) number (None) or summed weights of the
        class-c target objects within the radius (distance <= radius) of each point of `moved`
        (n,3). `weights`: (None,) or (None, w) with w (n_target,) (one compiled search)."""
        if len(weights) > 2 or weights[0] is not None:
            raise ValueError("near_counts takes weights (None,) or (None, w)")
        if len(self.labels) == 0:  # an empty map: nothing near (integer zeros, as np.bincount)
            n, k = len(moved), self.n_classes
            return [np.zeros((n, k), np.int64 if n else np.float64) for _ in weights]
        from sgloc.maps.neighbor_kernels import near_class_counts

        w = weights[1] if len(weights) == 2 else None
        counts, summed = near_class_counts(
            np.ascontiguousarray(moved, dtype=np.float64),
            self.positions,
            np.asarray(self.labels, dtype=np.int64),
            self.n_classes,
            float(self.radius),
            np.zeros(0) if w is None else np.asarray(w, dtype=np.float64),
            self.prepared.grid(self.radius),
        )
        return [counts, summed][: len(weights)]

    def near_targets(self, moved: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """(n, n_classes): per point of `moved` (n,3) and class c, how many entries of
        `targets` (target indices, repeats counted) are class-c objects within the radius:
        `near_counts` weighted by each object's count in `targets`, searched among those
        objects only (the same integers, without a pass over the whole map)."""
        targets = np.asarray(targets, dtype=np.int64)
        if len(self.labels) == 0:
            return self.near_counts(moved)[0]
        from sgloc.maps.neighbor_kernels import near_class_counts

        return near_class_counts(
            np.ascontiguousarray(moved, dtype=np.float64),
            np.ascontiguousarray(self.positions[targets]),
            np.asarray(self.labels[targets], dtype=np.int64),
            self.n_classes,
            float(self.radius),
            np.zeros(0),
        )[0]

    def near_counts_and_targets(
        self, moved: np.ndarray, targets: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(`near_counts(moved)`, `near_targets(moved, targets)`): from one search weighted by
        each object's count in `targets` when the map is small next to them (the same
        integers), else from two searches (no pass over a large map per query)."""
        targets = np.asarray(targets, dtype=np.int64)
        if len(self.labels) > _ONE_SEARCH * max(len(targets), len(moved)):
            return self.near_counts(moved)[0], self.near_targets(moved, targets)
        usage = np.bincount(targets, minlength=len(self.labels)).astype(np.float64)
        counts, used = self.near_counts(moved, (None, usage))
        return counts, used

    def expected_inliers(self, counts: np.ndarray, qi: np.ndarray, tlab: np.ndarray) -> float:
        """lambda = sum over candidates (query qi, target class tlab) of N_c / n_c, with
        `counts` = near_counts of the moved query objects."""
        return float(np.sum(counts[qi, tlab] / self.class_count[tlab]))


def class_counts(
    labels: np.ndarray, n_classes: int, counts: np.ndarray | None = None
) -> np.ndarray:
    """(max(n_classes, labels.max() + 1),) float64: the number of `labels` (n,) of each class
    (`counts`: np.bincount(labels) as float64 when the caller keeps it, a prepared graph's)."""
    if counts is None:
        counts = np.bincount(labels).astype(np.float64)
    if len(counts) >= n_classes:
        return counts
    return np.concatenate([counts, np.zeros(n_classes - len(counts))])


def _log10_poisson_tail(k: int, lam: float) -> float:
    """log10 P(Poisson(lam) >= k)."""
    if k <= 0:
        return 0.0
    from scipy.special import pdtrc

    p = pdtrc(k - 1, max(lam, 1e-12))
    if p > 1e-280:
        return float(np.log10(p))
    # scipy.stats.poisson.logsf's own formula, log(pdtrc(floor(k), mu)) (the same bits),
    # without importing scipy.stats (~0.3 s)
    with np.errstate(divide="ignore"):
        return float(np.log(pdtrc(np.floor(np.float64(k - 1)), max(lam, 1e-12))) / _LN10)


def per_object_min(res2: np.ndarray, query_index: np.ndarray) -> np.ndarray:
    """The smallest squared residual per query object of candidates (`query_index` per row): an
    object with several candidate targets is one piece of evidence, inlier when any is."""
    if res2.size == 0 or np.all(query_index[1:] > query_index[:-1]):
        return res2  # one candidate per object (the usual top-1 candidates, sorted by query)
    objects, row_object = np.unique(query_index, return_inverse=True)
    best = np.full(objects.size, np.inf)
    np.minimum.at(best, row_object, res2)
    return best


def log10_colocation_p(
    query: SemanticGraph, presence: np.ndarray, exclude: np.ndarray
) -> tuple[float, int, float]:
    """Independent confirmation beyond the inliers: among the query objects not in `exclude`
    (the inliers' query objects), C = those with a same-class target object within the radius
    after alignment. Under a label-permutation null (a query object's class drawn from the query's
    class frequencies f, independent of where it lies) C is Poisson-binomial with mean
    mu = sum_i sum_c presence[i, c] f_c. Returns (log10 P(X >= C), C, mu)."""
    C, mu = _colocation_counts(query.labels, presence, exclude)
    return colocation_tail(C, mu), C, mu


def colocation_tail(C: int, mu: float) -> float:
    """log10 P(X >= C) of `log10_colocation_p`'s count C with mean mu (0 when C = 0)."""
    return _log10_poisson_tail(C, mu) if C else 0.0


def _colocation_counts(
    labels: np.ndarray, presence: np.ndarray, exclude: np.ndarray
) -> tuple[int, float]:
    """(C, mu) of `log10_colocation_p` (query classes `labels` (n,))."""
    n_classes = presence.shape[1]
    f = np.bincount(labels, minlength=n_classes)[:n_classes] / max(len(labels), 1)
    keep = np.ones(len(labels), dtype=bool)
    keep[exclude] = False
    mu = float((presence[keep] @ f).sum())
    return int(presence[np.flatnonzero(keep), labels[keep]].sum()), mu


def chance_terms(
    labels: np.ndarray,
    counts: np.ndarray,
    used: np.ndarray,
    qi: np.ndarray,
    tlab: np.ndarray,
    inlier: np.ndarray,
    chance: ChanceModel,
) -> tuple[int, float, float, int, float]:
    """(k, lambda, lambda_p, C, mu) of the candidates (query objects `qi`, target classes
    `tlab`, `inlier` (m,) bool; int64, contiguous) under one transform: the distinct inlier
    query objects, `expected_inliers`, `permutation_lambda` and `log10_colocation_p`'s count
    and mean (the query's classes `labels`; `counts`, `used`: `near_counts_and_targets`).
    Compiled in one pass (sums in candidate order)."""
    if len(qi) == 0:  # no candidate: no inlier, no chance inlier; every object co-located
        C, mu = _colocation_counts(labels, counts > 0, qi)
        return 0, 0.0, 0.0, C, mu
    from sgloc.acceptance.evidence_kernels import chance_sums

    k, lam, lam_p, C, mu = chance_sums(qi, tlab, inlier, counts, used, chance.class_count,
                                       labels)  # fmt: skip
    return int(k), float(lam), float(lam_p), int(C), float(mu)


def log10_nfa(k: int, m: int, lam: float, n_tests: float | None = None, sample: int = 3) -> float:
    """log10 of the number of false alarms n_tests * P(Poisson(lam) >= k - sample); n_tests
    defaults to C(m, 3), every triple of the m candidates; `sample` matches fix a hypothesis
    (3 for 6 dof, 2 for 4 dof) and are not evidence for it."""
    return _log10_nfa_of(_log_tests(m, n_tests), k, lam, sample)


def _log_tests(m: int, n_tests: float | None) -> float:
    """ln of the number of tests of `log10_nfa`."""
    return _log_comb3(m) if n_tests is None else float(np.log(max(n_tests, 1.0)))


def _log10_nfa_of(log_tests: float, k: int, lam: float, sample: int) -> float:
    """`log10_nfa` given ln of its number of tests."""
    excess = k - sample
    if excess <= 0:
        return log_tests / _LN10
    return float(log_tests / _LN10 + _log10_poisson_tail(excess, lam))


#: Inlier radii, as fractions of the acceptance radius, at which the NFA is evaluated (the
#: smallest NFA counts, times their number: the tests multiply).
RADIUS_FRACTIONS = (0.25, 0.5, 1.0)
_LOG10_RADII = np.log10(len(RADIUS_FRACTIONS))


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
    return nfa_over_radii_each(res2, radius, (lam,), m, n_tests, sample)[0]


def nfa_over_radii_each(
    res2: np.ndarray, radius: float, lams: tuple[float, ...], m: int, n_tests: float,
    sample: int = 3,
) -> list[tuple[float, int, float]]:  # fmt: skip
    """`nfa_over_radii` of the same residuals for each chance level of `lams` (the fits at
    the radii found once)."""
    ordered = np.sort(res2)
    limits = [(f * radius) ** 2 for f in RADIUS_FRACTIONS]
    within = np.searchsorted(ordered, limits, side="left")  # how many res2 < each limit
    tops = [float(ordered[k - 1]) if k else -1.0 for k in within.tolist()]
    return _nfa_of_fits(_fits(within.tolist(), tops, radius), radius, lams, m, n_tests, sample)


def object_nfa_over_radii(
    res2: np.ndarray, qi: np.ndarray, rows: np.ndarray, n_objects: int, radius: float,
    lams: tuple[float, ...], m: int, n_tests: float, sample: int = 3,
) -> list[tuple[float, int, float]]:  # fmt: skip
    """`nfa_over_radii_each` of the smallest squared residual per query object (`qi` (m,)
    int64, of `n_objects`) of the candidates in `rows` (m,) bool (`per_object_min`): compiled
    in one pass without a sort (the same bits as sorting)."""
    if len(res2) == 0:
        return nfa_over_radii_each(res2, radius, lams, m, n_tests, sample)
    from sgloc.acceptance.evidence_kernels import object_fits

    limits = np.array([(f * radius) ** 2 for f in RADIUS_FRACTIONS])
    k, top = object_fits(res2, qi, rows, n_objects, limits)
    return _nfa_of_fits(_fits(k.tolist(), top.tolist(), radius), radius, lams, m, n_tests, sample)


def _fits(within: list[int], tops: list[float], radius: float) -> list[tuple[int, float, float]]:
    """Per radius of RADIUS_FRACTIONS: (inliers k within it, r_fit, chance shrink) from k and
    the largest squared residual below it (`tops`)."""
    fits = []
    for f, k, top in zip(RADIUS_FRACTIONS, within, tops, strict=True):
        r_fit = float(np.sqrt(top)) if k else f * radius
        r_fit = max(r_fit, MIN_RADIUS_FRACTION * radius)
        fits.append((k, r_fit, min(r_fit / radius, 1.0) ** 2))
    return fits


def _nfa_of_fits(
    fits: list[tuple[int, float, float]], radius: float, lams: tuple[float, ...], m: int,
    n_tests: float, sample: int,
) -> list[tuple[float, int, float]]:  # fmt: skip
    """The best (log10 NFA, k, r_fit) over `fits` (`_fits`) for each chance level of `lams`."""
    log_tests = _log_tests(m, n_tests)
    out = []
    for lam in lams:
        best = (np.inf, 0, radius)
        for k, r_fit, shrink in fits:
            lg = _log10_nfa_of(log_tests, k, lam * shrink, sample) + _LOG10_RADII
            if lg < best[0]:
                best = (lg, k, r_fit)
        out.append(best)
    return out


def pair_consistency(src: np.ndarray, dst: np.ndarray, radius: float) -> tuple[np.ndarray, ...]:
    """Bit-packed rows and degrees (`sgloc.consistency.pairwise.consistency_bits`) of the pairs of
    candidates (src, dst (m,3)) whose distances agree within 2 * radius in both graphs (no
    diagonal): the pairs that can both be inliers of one transform."""
    return consistency_bits(src, dst, 2.0 * radius, "distance")


def triangle_count(bits: np.ndarray, edges: ConsistentPairs) -> float:
    """Number of triangles of the consistency graph (packed rows `bits`) with edges (ii, jj),
    ii < jj: the sum over edges of their common neighbours / 3. Only log10 of the count
    matters, so beyond _TRIANGLE_EDGES edges an evenly spaced subset is scaled up."""
    if edges.size > _TRIANGLE_EDGES:
        pick = np.linspace(0, edges.size - 1, _TRIANGLE_EDGES).astype(np.int64)
        scale, (ii, jj) = edges.size / _TRIANGLE_EDGES, edges.at(pick)
    else:
        scale, (ii, jj) = 1.0, edges.all()
    return float(scale * common_partner_count(bits, ii, jj) / 3.0)


def permutation_lambda(
    used_near: np.ndarray,
    inlier: np.ndarray,
    tlab: np.ndarray,
    near: np.ndarray,
    chance: ChanceModel,
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


def confidence_terms(lg_best: float, lg_rival: float = np.inf) -> tuple[float, float]:
    """(NFA_best, NFA_best / NFA_rival) from their log10 (each capped at 10^300; the ratio 0
    without a rival: lg_rival infinite)."""
    nfa = 10.0 ** min(lg_best, _MAX_LOG10)
    ratio = 0.0 if not np.isfinite(lg_rival) else 10.0 ** min(lg_best - lg_rival, _MAX_LOG10)
    return nfa, ratio


def confidence(lg_best: float, lg_rival: float = np.inf) -> float:
    """The weight of the best hypothesis when it, its best distinct rival and chance are
    weighed by their a-contrario evidence 1 / NFA (chance weighing 1):
    1 / (1 + NFA_best + NFA_best / NFA_rival), in [0, 1]; without a rival 1 / (1 + NFA_best)."""
    nfa, ratio = confidence_terms(lg_best, lg_rival)
    return float(np.clip(1.0 / (1.0 + nfa + ratio), 0.0, 1.0))
