"""Other places: does the query fit as well somewhere else of the target map?

A floor of identical offices, a row of identical shelves: the query (one office) fits every
copy of its layout in the target, and each copy differs from the others only by which few
objects its map missed. The chance model of the test cannot see that (each copy's matches look
like strong evidence), and a rival found from the candidates alone is often set aside with its
near-tied matches. This check fits the query at the other places where the target repeats
itself near the estimate and compares the fits, object by object:

1. The places: the shifts d under which the target maps onto itself near the estimate
   (`repetition.self_similar_shifts`), anchored on every target object the estimate lands a
   query object on (not only the inliers' targets: a few inliers vote too weakly), voted on
   cells of the test's radius; at most `count` of them, best voted first.
2. The fits: the estimate and each shifted estimate d o T are refitted the same way (each
   query object paired with its nearest same-class target object within the test's radius,
   the motion model's least-squares fit, REFIT_ROUNDS times), so that a rival is not handicapped
   by the error of its shift.
3. The comparison: each fit lands the query objects within `land` metres of a same-class
   target object; a = the objects only the estimate lands, b = those only the place lands.
   A place's weight p against the estimate (at most 1: about 1 for a tie) is its weight
   against chance (`repetition.log10_rival_weight`: tiny when the estimate lands many objects
   no place does) and, for a place landing at least COPY_FRACTION of what the estimate lands
   (a possible copy of its place), at least its weight as a copy (`log10_copy_weight`: two
   copies, each mapped with its own misses, land an object that only one of them lands
   equally often: a ~ Binomial(a + b, 1/2)). The chance weight alone calls a copy that
   lands every object the estimate lands but 4 significant; the copy weight alone cannot tell
   a small room from a rival landing 3 of its 16 objects. The largest p over the places.

The acceptance stage joins p to the confidence's rival term (confidence = 1 / (1 / confidence
+ p)) and refuses below `min_confidence`: the place cannot be told from its copies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sgloc.acceptance.config import AcceptanceConfig
from sgloc.acceptance.repetition import log10_rival_weight, self_similar_shifts
from sgloc.estimation import MotionModel, fit_rigid
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.spatial import ClassKDTree

#: Rounds of pairing and refitting of each fit.
REFIT_ROUNDS = 2
#: A place landing at least this fraction of the objects the estimate lands may be a copy of
#: the estimate's place (two maps of one layout, each missing up to half of its objects).
COPY_FRACTION = 0.5


@dataclass
class OtherPlaces:
    """Outcome of `check_other_places` (counts of query objects; lengths in metres).

    places: how many other places were fitted; landed: the query objects the refitted estimate
    lands; rival_landed, estimate_only, rival_only: of the most ambiguous place (the one of the
    largest weight); shift: its distance from the estimate (xy); log10_p: log10 of its weight
    (-inf without a place).
    """

    places: int
    landed: int
    rival_landed: int = 0
    estimate_only: int = 0
    rival_only: int = 0
    shift: float = 0.0
    log10_p: float = -np.inf

    def details(self) -> dict:
        """The figures for a verdict's details (`other_place_*`)."""
        return {
            "other_places": self.places,
            "other_place_landed": self.landed,
            "other_place_rival_landed": self.rival_landed,
            "other_place_estimate_only": self.estimate_only,
            "other_place_rival_only": self.rival_only,
            "other_place_shift_m": self.shift,
            "other_place_log10_p": self.log10_p,
        }


def log10_copy_weight(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """log10 of each place's weight against the estimate were it another copy of the
    estimate's place, from a (k,) = objects only the estimate lands and b (k,) = only the
    place lands. Two copies of one layout, each mapped with its own misses, land the query's
    objects alike, so an object landed at one of them only is as likely at either: a ~
    Binomial(a + b, 1/2) (the paired sign test); weight = P(X >= a) / P(X >= b), at most 1."""
    a, b = np.asarray(a, np.int64), np.asarray(b, np.int64)
    lg = [_log10_half_tail(int(x), int(x + y)) - _log10_half_tail(int(y), int(x + y))
          for x, y in zip(a, b, strict=True)]  # a few places  # fmt: skip
    return np.minimum(np.array(lg, dtype=np.float64), 0.0)


def _log10_half_tail(k: int, n: int) -> float:
    """log10 P(Binomial(n, 1/2) >= k), exactly (integer binomial sums; n is a count of
    objects)."""
    if k <= 0:
        return 0.0
    return math.log10(sum(math.comb(n, i) for i in range(k, n + 1))) - n * math.log10(2.0)


def place_weights(landed: int, a: np.ndarray, b: np.ndarray, rival_landed: np.ndarray
                  ) -> np.ndarray:  # fmt: skip
    """log10 weight of each other place against the estimate (module docstring, 3.): a place
    landing at least COPY_FRACTION of the objects the estimate lands (`landed`) may be a copy
    of its place and weighs at least its `log10_copy_weight`; every place weighs at least its
    weight against chance (`repetition.log10_rival_weight`)."""
    chance = log10_rival_weight(a, b)
    copy_like = np.asarray(rival_landed) >= COPY_FRACTION * landed
    return np.where(copy_like, np.maximum(chance, log10_copy_weight(a, b)), chance)


def _tree(target: SemanticGraph, margin: float) -> ClassKDTree:
    """Same-class nearest neighbours among the target objects, for points up to `margin`
    metres beyond the target's extent."""
    extent = float(np.abs(target.positions).max(initial=0.0)) + margin
    return ClassKDTree(target.positions, target.labels, margin, extent=extent)


def refit(
    query: SemanticGraph,
    target: SemanticGraph,
    tree: ClassKDTree,
    transforms: np.ndarray,
    radius: float,
    motion: MotionModel,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each of `transforms` (k,4,4) T_target_query refitted REFIT_ROUNDS times on the query
    objects' nearest same-class target objects within `radius` metres (one neighbour search
    for all k per round); (T (k,4,4), distance (k,n) of each moved query object to its
    nearest same-class target object (inf beyond the radius), its index (k,n))."""
    q = query.positions
    T = np.array(transforms, dtype=np.float64)
    for _ in range(REFIT_ROUNDS):
        d, j = tree.query(_moved(T, q), query.labels, radius)
        for i in range(len(T)):  # a few places: one least-squares fit each
            ok = np.isfinite(d[i])
            if ok.sum() >= 3:
                T[i] = fit_rigid(q[ok], target.positions[j[i, ok]], None, motion.dof,
                                 motion.max_tilt)  # fmt: skip
    d, j = tree.query(_moved(T, q), query.labels, radius)
    return T, d, j


def _moved(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """points (n,3) moved by each of T (k,4,4): (k,n,3)."""
    return np.einsum("kij,nj->kni", T[:, :3, :3], points) + T[:, None, :3, 3]


def check_other_places(
    query: SemanticGraph,
    target: SemanticGraph,
    transform: np.ndarray,
    radius: float,
    land: float,
    shifts: tuple[float, float, int],
    motion: MotionModel,
) -> OtherPlaces:
    """The check of the module docstring for the estimate `transform` (T_target_query).
    radius: the test's radius (metres; pairing for the refits, the vote's cells); land: metres
    within which a refitted query object lands; shifts = (shortest, longest shift in metres,
    how many places at most)."""
    min_shift, max_shift, count = shifts
    tree = _tree(target, max_shift + radius)
    T, d, j = refit(query, target, tree, np.asarray(transform, np.float64)[None], radius, motion)
    mine = d[0] <= land
    out = OtherPlaces(0, int(mine.sum()))
    anchors = np.unique(j[0][np.isfinite(d[0])])
    found = self_similar_shifts(target, anchors, radius, min_shift, max_shift, count)
    if len(found) == 0:
        return out
    places = np.repeat(T, len(found), axis=0)
    places[:, :3, 3] += found
    _, d_r, _ = refit(query, target, tree, places, radius, motion)
    rival = d_r <= land
    a = (mine[None] & ~rival).sum(axis=1)
    b = (rival & ~mine[None]).sum(axis=1)
    lg = place_weights(int(mine.sum()), a, b, rival.sum(axis=1))
    s = int(np.argmax(lg))
    out.places, out.rival_landed = len(found), int(rival[s].sum())
    out.estimate_only, out.rival_only = int(a[s]), int(b[s])
    out.shift, out.log10_p = float(np.hypot(*found[s][:2])), float(lg[s])
    return out


#: A refitted query object lands within this fraction of the test's radius of a same-class
#: target object.
LAND_FRACTION = 0.5


def elsewhere(
    query: SemanticGraph,
    target: SemanticGraph,
    transform: np.ndarray,
    confidence: float,
    radius: float,
    config: AcceptanceConfig,
    motion: MotionModel,
) -> tuple[float, str, OtherPlaces]:
    """The accepted estimate `transform` (confidence `confidence`, test radius `radius`
    metres) against its other places (`check_other_places`, `config.other_places` of them
    within `config.distinct_translation`..`config.repetition_search` metres): (the confidence
    with the most ambiguous place as a rival, the reason of a refusal (empty when it still
    reaches `config.min_confidence`), the check's outcome)."""
    shifts = (config.distinct_translation, config.repetition_search, config.other_places)
    check = check_other_places(query, target, transform, radius, LAND_FRACTION * radius,
                               shifts, motion)  # fmt: skip
    if not np.isfinite(check.log10_p) or confidence <= 0:
        return confidence, "", check
    conf = float(1.0 / (1.0 / confidence + 10.0**check.log10_p))
    if conf >= config.min_confidence:
        return conf, "", check
    return conf, (
        f"ambiguous: the query fits as well {check.shift:.1f} m away, where the target map "
        f"repeats itself: refitted there it lands {check.rival_landed} objects ("
        f"{check.rival_only} the alignment does not), the alignment {check.landed} "
        f"({check.estimate_only} the other place does not); confidence {conf:.6g} < "
        f"min_confidence {config.min_confidence:g}; the place cannot be told from its copies "
        "(--set other_places=0 turns this check off; Python: other_places=0)"
    ), check
