"""Refit a link on everything two grown maps share (`OnlineConfig.refine_links`): pair the
objects the link puts on top of each other (mutual nearest same-class neighbours within a
radius), refit by the robust fit of the motion model, repeat until the pairing stops changing,
and give the covariance of the fit over all those pairs (`sgloc.estimation.covariance`): the
more co-located objects, the smaller it is.

Words of the online package: a link is *refitted* here (one link, on its two maps); the fleet
frame is *refined* jointly in `sgloc.online.joint` (`OnlineConfig.refine_fleet`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.errors import SglocError
from sgloc.estimation import MotionModel, irls_refine
from sgloc.estimation.covariance import transform_covariance
from sgloc.maps.spatial import mutual_nearest_pairs


@dataclass(frozen=True)
class Refit:
    """A link refitted on co-located objects: T_a_b (4,4), covariance (6,6; `Link`'s
    convention), n_pairs the object pairs it was fitted on."""

    T_a_b: np.ndarray
    covariance: np.ndarray
    n_pairs: int


def co_located(
    src: np.ndarray, src_labels: np.ndarray, dst: np.ndarray, dst_labels: np.ndarray,
    T_dst_src: np.ndarray, radius: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(i, j): src[i] and dst[j] are mutual nearest same-class neighbours closer than `radius`
    metres once src is moved by T_dst_src (one-to-one; sorted by i)."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    moved = src @ T_dst_src[:3, :3].T + T_dst_src[:3, 3]
    i, j = mutual_nearest_pairs(
        np.concatenate([moved.reshape(-1, 3), dst.reshape(-1, 3)]),
        np.concatenate([np.asarray(src_labels).reshape(-1), np.asarray(dst_labels).reshape(-1)]),
        np.repeat([0, 1], [len(moved), len(dst)]), radius,
    )
    return i, j - len(moved)


def refit_link(
    pos_b: np.ndarray, lab_b: np.ndarray, pos_a: np.ndarray, lab_a: np.ndarray,
    T_a_b: np.ndarray, motion: MotionModel, radius: float, iterations: int = 10,
) -> Refit | None:
    """T_a_b refitted on every object pair it co-locates (robot b's objects pos_b (n,3) in b's
    odometry frame, robot a's pos_a (m,3) in a's, metres; labels class ids); None when fewer
    than 3 pairs. Deterministic: a pure function of its inputs."""
    T = np.asarray(T_a_b, np.float64)
    prev = None
    for _ in range(iterations):
        i, j = co_located(pos_b, lab_b, pos_a, lab_a, T, radius)
        if len(i) < 3:
            return None
        if prev is not None and np.array_equal(i, prev[0]) and np.array_equal(j, prev[1]):
            break
        try:
            T = irls_refine(pos_b[i], pos_a[j], T, None, 15, motion.dof, motion.max_tilt)
        except SglocError:  # degenerate geometry (collinear pairs)
            return None
        prev = i, j
    i, j = co_located(pos_b, lab_b, pos_a, lab_a, T, radius)
    if len(i) < 3:
        return None
    cov = transform_covariance(pos_b[i], pos_a[j], T, None, motion.dof, motion.max_tilt)
    return Refit(T, cov, int(len(i)))
