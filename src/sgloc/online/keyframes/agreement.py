"""Links whose maps disagree where they put them side by side (`OnlineConfig.link_agreement`).

An attempt aligns the query robot's recent submap with the target's map. On a repeating layout
(a street grid: the same curb lines, poles and crossings every block) the submap can fit a copy
of its place a block or two away as well as the place itself, and a link at the copy is rigid
and agrees with the other links made there, so neither the pairwise consistency nor the bend
check (`keyframes.consistency`) sees it until a third robot closes a cycle. What the copy does
not repeat shows it: the objects around the link (each robot's objects seen within
`window` metres of travel of its end of the link, longer than the attempt's submap), put side
by side by the link, land on an object of their class where the maps overlap when the link is
true, and mostly not when it is at a copy.

`overlap` measures that once per link, on the maps as they stand when the link is made:
of the query objects the link puts within `cover` metres of a target object (`covered`),
those within `land` metres of a target object of their class (`landed`); the radii are the
localizer's (`AcceptanceConfig.repetition_radii`). `disagrees` holds a link whose fraction
landed is below the threshold over at least `min_covered` covered objects."""

from __future__ import annotations

import numpy as np

from sgloc import lie
from sgloc.acceptance.chance import ChanceModel
from sgloc.acceptance.repetition import landing
from sgloc.online.records import Link
from sgloc.online.robot_map import RobotMap


def window_objects(m: RobotMap, keyframe: int, window: float) -> np.ndarray:
    """(n,) bool over `m`'s association objects: sighted from a keyframe within `window`
    metres of travel of `keyframe`."""
    d = m.travelled()
    lo = int(np.searchsorted(d, d[keyframe] - window, side="left"))
    hi = int(np.searchsorted(d, d[keyframe] + window, side="right"))
    return m.seen_between(lo, hi)


def overlap(target: RobotMap, query: RobotMap, link: Link, window: float,
            radii: tuple[float, float]) -> tuple[int, int]:
    """(landed, covered) query objects of the link's overlap (module docstring): the query's
    confirmed objects around link.keyframe_b moved by the link into the target's odometry
    frame, against the target's around link.keyframe_a (for a loop closure, target == query,
    the objects around keyframe_b are left out of the target's); `repetition.landing` at
    radii = (land, cover) metres."""
    ka, kb = int(link.keyframe_a), int(link.keyframe_b)
    sel_q = window_objects(query, kb, window)
    sel_t = window_objects(target, ka, window)
    if target is query:
        sel_t &= ~sel_q
    q, t = query.subgraph(sel_q), target.subgraph(sel_t)
    if len(q) == 0 or len(t) == 0:
        return 0, 0
    # p_target = A_t[ka] @ T_kk @ inv(A_q[kb]) @ p_query (each map's current keyframe poses)
    T = target.anchors()[ka] @ link.T_a_b @ lie.between(query.anchors()[kb], np.eye(4))
    moved = q.positions @ T[:3, :3].T + T[:3, 3]
    n_classes = max(q.n_classes, t.n_classes)
    land, cover = (ChanceModel(t, r, n_classes) for r in radii)
    landed, covered = landing(moved, q.labels, land, cover)
    return int((landed & covered).sum()), int(covered.sum())


def disagrees(link: Link, threshold: float, min_covered: int) -> bool:
    """Whether `link`'s measured overlap lands fewer than `threshold` of at least
    `min_covered` covered objects (threshold 0: never)."""
    return (threshold > 0 and link.covered >= min_covered
            and link.landed < threshold * link.covered)


def disagreement_reason(link: Link, threshold: float) -> str:
    """The `link_held` reason of a link `disagrees` holds."""
    return (f"the maps disagree where the link puts them side by side: {link.landed} of "
            f"{link.covered} objects land on one of their class "
            f"({100 * link.landed / link.covered:.0f} % < link_agreement {100 * threshold:g} %)")
