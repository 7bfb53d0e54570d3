"""Structured coincidences: an alignment that a repeating layout explains as well as the maps.

The chance model of the test (`chance`, `assessment`) asks whether the inliers could be chance
when each candidate's target is a random object of its class. A repeating layout (a street
grid, poles at a fixed spacing, rooms or blocks built from one template) breaks that: once
one object lines up with its look-alike, its whole row or block does, and many inliers are one
coincidence. Two checks of the estimate T_target_query against the layout, on the whole query
(every object, not only the matched ones):

1. Repetition (`structured_rival`): the shifts d under which the target maps onto itself near
   the estimate are found from the same-class offsets between the target objects the inliers
   landed on and the other target objects (a vote on an xy grid of cells `cell` metres wide:
   a lattice period collects one vote per anchor; a random layout spreads its votes). The query
   is moved by each of the `rivals` best-voted shifts d (d composed with T) and scored by its
   objects that land within `land` metres of a same-class target object. Over the query
   objects that T puts within `cover` metres of a target object (the overlap T claims), a =
   the objects only T lands, b = those only d o T lands (a shift that moves the query off the
   target explains none of them: no rival). Were T itself an alignment of the repetition
   like the shifted ones, its extra landings a would be no more than a shift's: with mu =
   (sum of b over the shifts + 1) / (shifts + 1), the weight of the rival d o T against T is
   p = P(Poisson(mu) >= a) / P(Poisson(mu) >= b) (at most 1: 1 for a tie, tiny when T lands
   many objects no shift does). The largest p over the shifts joins the test's rival term:
   confidence = 1 / (1 / confidence + p); a tie gives about 1/2 ("ambiguous").
2. Agreement (`overlap_agreement`): where the alignment puts query objects next to target
   objects (within `cover` metres), two maps of one place land most of them on an object of
   their class (within `land` metres); an alignment at the wrong copy of a repeating layout
   lands only the objects the layout repeats (the street furniture at the curb lines, not the
   rest). Refused when fewer than `min_agreement` of at least `min_covered` such objects land.
3. The layout's own chance (`layout_chance`; `layout_shifts` > 0, off by default): how often
   would a copy of this repeating layout land the objects the estimate lands? Each map is
   measured against itself: the objects of its part of the claimed overlap are moved by its
   own self-similar shifts (found as in 1., anchored on those objects) and, per class c, the
   fraction p_c of those that come to lie next to an object of the map (within `cover`) and
   land on one of class c (within `land`) is what a copy of the layout lands, chance
   coincidences included (both maps' shifts pooled; a class no shift carries takes the rate
   of all classes). Poles on a street grid repeat with the grid (p near 1), trees and
   buildings of random widths do not (p near the chance of their density). The objects that
   voted for a shift are counted too: in a repeating layout they are the repeating objects;
   on a layout that barely repeats they make p_c higher than a copy would land (the check
   then refuses more than it must: a cautious estimate). Under the null "T is one of the
   layout's copies", a covered query object of class c lands with probability p_c, so the
   landed count L of the N covered objects is a sum of binomials, and NFA_layout = n_tests *
   P(sum_c Binomial(N_c, p_c) >= L) (n_tests: the test's hypotheses; RANSAC picks the best
   of the layout's copies). NFA_layout joins the test's rival term, confidence = 1 / (1 /
   confidence + NFA_layout): about 1/2 or lower when a copy of the layout explains the
   landings ("ambiguous"). A true alignment also lands what the layout does not repeat; on
   a layout that does not repeat no shift is found and nothing changes. The model measures
   only the maps' own repetition, so it serves any repeating scene (street grids, rooms or
   blocks built from one template).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.acceptance.chance import ChanceModel, colocation_tail
from sgloc.maps.graph import SemanticGraph

#: At most this many anchors vote for the shifts (evenly spaced among the inliers' targets).
MAX_ANCHORS = 32


@dataclass
class LayoutChance:
    """Outcome of `layout_chance`: per class (arrays of n_classes), the covered query objects
    (`covered`), those that land under the estimate (`landed`), and the probability `p` that
    one lands under a copy of the repeating layout; `shifts`: the self-similar shifts measured
    (both maps); `log10_tail`: log10 P(sum_c Binomial(covered_c, p_c) >= landed.sum()) (0 when
    nothing is covered); `rate`: the pooled landing fraction of the shifted copies (0 without
    shifts)."""

    covered: np.ndarray
    landed: np.ndarray
    p: np.ndarray
    shifts: int
    log10_tail: float
    rate: float = 0.0


@dataclass
class Repetition:
    """Outcome of `check_repetition` (lengths in metres, counts of query objects).

    landed, covered: the estimate's query objects within `land` of a same-class target object
        and within `cover` of any target object (landed counts only covered objects).
    shift: (3,) the most ambiguous self-similar shift d (target frame), None when none found;
    rival_only, estimate_only: the covered objects only d o T lands / only T lands;
    log10_p: log10 of the rival's weight p (`log10_rival_weight`; -inf without a rival);
    shifts_tried: how many shifts were scored.
    radii: (land, cover) metres used.
    """

    landed: int
    covered: int
    radii: tuple[float, float] = (0.0, 0.0)
    shift: np.ndarray | None = None
    rival_only: int = 0
    estimate_only: int = 0
    log10_p: float = -np.inf
    shifts_tried: int = 0
    layout: LayoutChance | None = None

    @property
    def agreement(self) -> float:
        """Fraction of the covered query objects that land (1 with none covered)."""
        return self.landed / self.covered if self.covered else 1.0


def log10_rival_weight(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """log10 of each shift's weight against the estimate, from a (k,) = objects only the
    estimate lands and b (k,) = objects only the shifted query lands: P(Poisson(mu) >= a) /
    P(Poisson(mu) >= b), at most 1, mu = (sum b + 1) / (k + 1) the objects a shifted (chance)
    alignment lands beyond the estimate's. A tie weighs 1; an estimate that lands many objects
    no shift does weighs its rivals down."""
    a, b = np.asarray(a, np.int64), np.asarray(b, np.int64)
    mu = (float(b.sum()) + 1.0) / (len(b) + 1.0)
    lg = [colocation_tail(int(x), mu) - colocation_tail(int(y), mu) for x, y in zip(a, b,
                                                                                   strict=True)]
    return np.minimum(np.array(lg, dtype=np.float64), 0.0)


def self_similar_shifts(
    target: SemanticGraph,
    anchors: np.ndarray,
    cell: float,
    min_shift: float,
    max_shift: float,
    count: int,
) -> np.ndarray:
    """(<= count, 3) shifts d (target frame, metres) under which the target objects `anchors`
    (indices) land on same-class target objects again, best voted first: same-class offsets
    t - a between `min_shift` and `max_shift` metres long in xy, voted on xy cells `cell`
    metres wide (each anchor votes once per cell); each shift is the mean offset of its cell.
    Cells with fewer than 3 votes are no repetition."""
    anchors = np.unique(np.asarray(anchors, dtype=np.int64))
    if len(anchors) < 3 or count <= 0 or len(target) < 2:
        return np.zeros((0, 3))
    if len(anchors) > MAX_ANCHORS:  # evenly spaced: the vote needs a few dozen anchors
        anchors = anchors[np.linspace(0, len(anchors) - 1, MAX_ANCHORS).astype(np.int64)]
    pos, labels = target.positions, target.labels
    near = _within_box(pos, pos[anchors], max_shift)
    # the anchor-object offsets at once (at most MAX_ANCHORS x the objects near the anchors)
    off_xy = pos[None, near, :2] - pos[anchors, None, :2]
    dist2 = np.einsum("ijk,ijk->ij", off_xy, off_xy)
    keep = (labels[None, near] == labels[anchors, None]) & (dist2 >= min_shift**2) \
        & (dist2 <= max_shift**2)
    a_row, j = np.nonzero(keep)
    if len(j) == 0:
        return np.zeros((0, 3))
    i, j = anchors[a_row], near[j]
    off = pos[j] - pos[i]
    cx = np.floor(off[:, 0] / cell).astype(np.int64)
    cy = np.floor(off[:, 1] / cell).astype(np.int64)
    span = int(np.ceil(2 * max_shift / cell)) + 3
    key = (cx - cx.min()) * span + (cy - cy.min())
    # one vote per (anchor, cell)
    _, first = np.unique(key * (len(pos) + 1) + i, return_index=True)
    cells, inverse, votes = np.unique(key[first], return_inverse=True, return_counts=True)
    order = np.argsort(-votes, kind="stable")[:count]
    order = order[votes[order] >= 3]
    sums = np.zeros((len(cells), 3))
    np.add.at(sums, inverse, off[first])
    return sums[order] / votes[order, None]


def _within_box(pos: np.ndarray, anchors: np.ndarray, margin: float) -> np.ndarray:
    """Indices of `pos` (n,3) inside the xy box of `anchors` (k,3) grown by `margin` metres."""
    lo = anchors[:, :2].min(axis=0) - margin
    hi = anchors[:, :2].max(axis=0) + margin
    xy = pos[:, :2]
    return np.flatnonzero((xy[:, 0] >= lo[0]) & (xy[:, 0] <= hi[0]) & (xy[:, 1] >= lo[1])
                          & (xy[:, 1] <= hi[1]))  # fmt: skip


def landing(
    moved: np.ndarray, labels: np.ndarray, land: ChanceModel, cover: ChanceModel
) -> tuple[np.ndarray, np.ndarray]:
    """(landed, covered) (n,) bool of points `moved` (n,3) with classes `labels`: a same-class
    target object within land.radius, any target object within cover.radius."""
    (near,) = land.near_counts(moved)
    (around,) = cover.near_counts(moved)
    return near[np.arange(len(moved)), labels] > 0, around.sum(axis=1) > 0


def self_landing(
    graph: SemanticGraph,
    idx: np.ndarray,
    models: tuple[ChanceModel, ChanceModel],
    shifts: tuple[float, float, int],
) -> tuple[np.ndarray, np.ndarray, int]:
    """The objects `idx` of `graph` moved by the graph's own self-similar shifts (anchored on
    them; shifts = (min, max metres, how many)), per class (n_classes,): how many come to lie
    next to an object of the graph (`models` = (land, cover) models of the graph: within
    cover.radius) and how many of those land on one of their class (within land.radius),
    summed over the shifts: (landed, covered, number of shifts)."""
    land, cover = models
    n_classes = land.n_classes
    zero = np.zeros(n_classes, np.int64)
    d = self_similar_shifts(graph, idx, land.radius, *shifts)
    if len(d) == 0:
        return zero, zero, 0
    every = (graph.positions[idx][None] + d[:, None, :]).reshape(-1, 3)
    lab = np.tile(graph.labels[idx], len(d))
    lands, near = landing(every, lab, land, cover)
    return (np.bincount(lab[lands & near], minlength=n_classes)[:n_classes],
            np.bincount(lab[near], minlength=n_classes)[:n_classes], len(d))  # fmt: skip


def log10_binomial_sum_tail(landed: int, n: np.ndarray, p: np.ndarray) -> float:
    """log10 P(sum_c Binomial(n_c, p_c) >= landed) (n, p: (k,) arrays); 0 for landed <= 0."""
    if landed <= 0:
        return 0.0
    if landed > int(n.sum()):
        return -np.inf
    from scipy.stats import binom  # deferred, as in chance: scipy's import is slow

    pmf = np.ones(1)
    for nc, pc in zip(n.tolist(), p.tolist(), strict=True):
        if nc > 0:
            pmf = np.convolve(pmf, binom.pmf(np.arange(nc + 1), nc, min(max(pc, 0.0), 1.0)))
    tail = float(pmf[landed:].sum())
    return float(np.log10(tail)) if tail > 0 else -np.inf


def layout_chance(
    query: SemanticGraph,
    target: SemanticGraph,
    moved: np.ndarray,
    hits: tuple[np.ndarray, np.ndarray],
    models: tuple[ChanceModel, ChanceModel],
    shifts: tuple[float, float, int],
) -> LayoutChance:
    """Check 3 of the module docstring for the query moved by the estimate (`moved` (n,3),
    target frame). hits = (landed, covered): (n,) bool of `_landing`; models: the target's
    (land, cover) models; shifts = (min, max metres, how many per map)."""
    land, cover = models
    n_classes = land.n_classes
    landed, covered = hits
    cov_c = np.bincount(query.labels[covered], minlength=n_classes)[:n_classes]
    land_c = np.bincount(query.labels[covered & landed], minlength=n_classes)[:n_classes]
    hit, seen, k = np.zeros(n_classes), np.zeros(n_classes), 0
    if covered.any():
        own = (ChanceModel(query, land.radius, n_classes), ChanceModel(query, cover.radius,
                                                                        n_classes))  # fmt: skip
        mine = np.flatnonzero(covered)
        theirs = _near_points(target.positions, moved[mine], cover.radius)
        for graph, idx, pair in ((query, mine, own), (target, theirs, models)):
            h, s, n = self_landing(graph, idx, pair, shifts)
            hit, seen, k = hit + h, seen + s, k + n
    rate = float(hit.sum() / seen.sum()) if seen.sum() else 0.0
    p = np.where(seen > 0, hit / np.maximum(seen, 1), rate)
    tail = log10_binomial_sum_tail(int(land_c.sum()), cov_c, p)
    return LayoutChance(cov_c, land_c, p, k, tail, rate)


def _near_points(pos: np.ndarray, points: np.ndarray, radius: float) -> np.ndarray:
    """Indices of `pos` (n,3) within `radius` metres of any of `points` (k,3)."""
    from scipy.spatial import cKDTree  # deferred, as in chance

    box = _within_box(pos, points, radius)
    if len(box) == 0:
        return box
    d, _ = cKDTree(points).query(pos[box], distance_upper_bound=radius)
    return box[np.isfinite(d)]


def check_repetition(
    query: SemanticGraph,
    target: SemanticGraph,
    moved: np.ndarray,
    anchors: np.ndarray,
    radii: tuple[float, float],
    shifts: tuple[float, float, int],
    layout: int = 0,
) -> Repetition:
    """The checks of the module docstring for the query moved by the estimate (`moved` (n,3),
    target frame). anchors: target indices the estimate's inliers landed on; radii = (land,
    cover) metres; shifts = (min_shift, max_shift metres, how many shifts to try; 0: none);
    layout: how many self-similar shifts of each map measure the layout's chance (0: check 3
    is not run; `Repetition.layout` None)."""
    land_r, cover_r = radii
    n_classes = max(query.n_classes, target.n_classes)
    land = ChanceModel(target, land_r, n_classes)
    cover = ChanceModel(target, cover_r, n_classes)
    min_shift, max_shift, count = shifts
    d = self_similar_shifts(target, anchors, land_r, min_shift, max_shift, count)
    landed, covered = landing(moved, query.labels, land, cover)
    out = Repetition(int((landed & covered).sum()), int(covered.sum()), radii,
                     shifts_tried=len(d))  # fmt: skip
    if layout > 0:
        out.layout = layout_chance(query, target, moved, (landed, covered),
                                   (land, cover), (min_shift, max_shift, layout))  # fmt: skip
    if len(d) == 0 or not covered.any():
        return out
    # only the overlap T claims is compared: the shifted copies of its objects, one search
    idx = np.flatnonzero(covered)
    k, n = len(d), len(idx)
    every = (moved[idx][None] + d[:, None, :]).reshape(-1, 3)
    (near,) = land.near_counts(every)
    lab = np.tile(query.labels[idx], k)
    rival = (near[np.arange(k * n), lab] > 0).reshape(k, n)
    mine = landed[idx]
    a = (mine[None] & ~rival).sum(axis=1)
    b = (rival & ~mine[None]).sum(axis=1)
    lg = log10_rival_weight(a, b)
    s = int(np.argmax(lg))  # the most ambiguous shift (the first of ties)
    out.shift, out.estimate_only, out.rival_only = d[s], int(a[s]), int(b[s])
    out.log10_p = float(lg[s])
    return out
