"""A refined KITTI 00 trajectory: the raw poses made consistent with the refined revisit
transforms (kitti_lc_test_*.txt), and how well object centroids agree at the revisits.

KITTI's raw poses are locally accurate but off by 1-2 m (and up to ~1 deg) between the two
passes of some revisits. The refined trajectory is a pose graph over every scan's LiDAR pose
(T_seq_lidar = P_i @ Tr, the sequence's first camera frame): a between factor per consecutive
scan pair equal to the raw relative motion (tight: the raw poses' local accuracy), one per
refined revisit pair (i, j) equal to inv(M) (p_j = M p_i in LiDAR frames, so
inv(T_i) @ T_j = inv(M)) under a robust kernel, and scan 0 fixed at its raw pose; solved with
gtsam's Levenberg-Marquardt. Deterministic; recomputed in about a second, never stored.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from sgloc.evaluation.pairs_kitti import kitti_sequence
from sgloc.geometry import invert
from sgloc.optional import require

#: Per consecutive scan (0.1 s, ~1 m driven): sigma of the raw relative motion, metres and
#: degrees. The raw poses (RTK GPS/INS) are accurate to a few cm over a step; their error at
#: revisits (1-2 m, ~1 deg over thousands of scans) is a slow drift of ~1 mm / 0.0005 deg per
#: scan, which these sigmas let the revisit factors remove.
ODOM_SIGMA_M, ODOM_SIGMA_DEG = 0.01, 0.01
#: Sigma of one refined revisit transform (metres, degrees): its object centroids align to a
#: median 0.29 m over tens of metres.
REVISIT_SIGMA_M, REVISIT_SIGMA_DEG = 0.1, 0.2
#: Huber threshold of the revisit factors (in sigmas): a bad pair pulls linearly, not squared.
REVISIT_HUBER = 1.345


@dataclass(frozen=True)
class RefineSigmas:
    """Sigmas of the refined trajectory's factors (metres, degrees; Huber threshold in
    sigmas)."""

    odom_m: float = ODOM_SIGMA_M
    odom_deg: float = ODOM_SIGMA_DEG
    revisit_m: float = REVISIT_SIGMA_M
    revisit_deg: float = REVISIT_SIGMA_DEG
    huber: float = REVISIT_HUBER


def _diag(gtsam, m: float, deg: float):
    r = np.radians(deg)
    return gtsam.noiseModel.Diagonal.Sigmas(np.array([r, r, r, m, m, m]))


def refine_trajectory(
    T_seq_lidar: np.ndarray,
    pairs: np.ndarray,
    M: np.ndarray,
    sigmas: RefineSigmas = RefineSigmas(),
) -> np.ndarray:
    """(N,4,4) poses consistent with the revisit transforms `M` (k,4,4; p_j = M p_i for
    pairs (k,2) = (i, j)) while keeping each consecutive relative motion of `T_seq_lidar`
    (N,4,4) up to `sigmas`; pose 0 stays as given. Needs gtsam (the `gtsam` extra)."""
    gtsam = require("gtsam", "gtsam", "the refined KITTI trajectory")
    n = len(T_seq_lidar)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k in range(n):
        values.insert(k, gtsam.Pose3(T_seq_lidar[k]))
    graph.add(gtsam.NonlinearEqualityPose3(0, gtsam.Pose3(T_seq_lidar[0])))
    steps = np.einsum("nij,njk->nik", invert_all(T_seq_lidar[:-1]), T_seq_lidar[1:])
    odom = _diag(gtsam, sigmas.odom_m, sigmas.odom_deg)
    for k in range(n - 1):
        graph.add(gtsam.BetweenFactorPose3(k, k + 1, gtsam.Pose3(steps[k]), odom))
    robust = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(sigmas.huber),
        _diag(gtsam, sigmas.revisit_m, sigmas.revisit_deg),
    )
    for (i, j), m in zip(np.asarray(pairs), M, strict=True):
        graph.add(gtsam.BetweenFactorPose3(int(i), int(j), gtsam.Pose3(invert(m)), robust))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    params.setMaxIterations(100)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    return np.stack([result.atPose3(k).matrix() for k in range(n)])


def invert_all(T: np.ndarray) -> np.ndarray:
    """Inverses of rigid transforms (n,4,4)."""
    R = np.swapaxes(T[:, :3, :3], 1, 2)
    out = np.tile(np.eye(4), (len(T), 1, 1))
    out[:, :3, :3] = R
    out[:, :3, 3] = -np.einsum("nij,nj->ni", R, T[:, :3, 3])
    return out


@functools.lru_cache(maxsize=2)
def kitti_refined_poses(root: str) -> np.ndarray:
    """(N,4,4) refined T_seq_lidar of every KITTI 00 scan under `root` (computed once per
    process; the sequence frame of the raw poses, scan 0 unchanged)."""
    L, ij, M = kitti_sequence(root)
    return refine_trajectory(L, ij, M)


def step_changes(T_a: np.ndarray, T_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per consecutive scan pair: how much the relative motion of trajectory b differs from
    a's (metres (N-1,), degrees (N-1,))."""
    da = np.einsum("nij,njk->nik", invert_all(T_a[:-1]), T_a[1:])
    db = np.einsum("nij,njk->nik", invert_all(T_b[:-1]), T_b[1:])
    D = np.einsum("nij,njk->nik", invert_all(da), db)
    return np.linalg.norm(D[:, :3, 3], axis=1), rotation_angles_deg(D[:, :3, :3])


def rotation_angles_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angles (degrees) of rotation matrices (n,3,3). atan2 of sine and cosine, not
    arccos of the trace: the raw KITTI rotations are orthonormal to ~3e-7 only, which arccos
    near 1 would turn into ~0.03 deg."""
    c = (np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0
    w = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    return np.degrees(np.arctan2(np.linalg.norm(w, axis=1) / 2.0, c))


def revisit_pair_distances(
    scans: list[tuple[np.ndarray, np.ndarray]],
    pairs: np.ndarray,
    M: np.ndarray,
    trajectories: list[np.ndarray | None],
    radius: float = 2.0,
) -> list[np.ndarray]:
    """Per trajectory (N,4,4 T_seq_lidar; None: M itself): the distances (metres) of the true
    same-class object pairs of every revisit, scan j's object against scan i's mapped by the
    trajectory. True pairs: mutual nearest same-class neighbours within `radius` m once scan
    i's objects are mapped with the refined transform M (p_j = M p_i); scans: (positions
    (n,3) LiDAR frame, labels (n,)) per scan."""
    from sgloc.online.refine import co_located

    dists: list[list[np.ndarray]] = [[] for _ in trajectories]
    for (i, j), m in zip(np.asarray(pairs), M, strict=True):
        (pi, li), (pj, lj) = scans[int(i)], scans[int(j)]
        a, b = co_located(pi, li, pj, lj, m, radius)
        if not len(a):
            continue
        for out, T in zip(dists, trajectories, strict=True):
            T_j_i = m if T is None else invert(T[j]) @ T[i]
            q = pi[a] @ T_j_i[:3, :3].T + T_j_i[:3, 3]
            out.append(np.linalg.norm(q - pj[b], axis=1))
    return [np.concatenate(d) if d else np.zeros(0) for d in dists]


def kitti_scan_objects(root: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """(positions (n,3) LiDAR frame, labels (n,)) of every KITTI 00 scan under `root`."""
    from sgloc.datasets import make_dataset

    n = len(kitti_sequence(root)[0])
    ds = make_dataset("kitti_objects", root, scans=(0, n - 1))
    return [ds[i].detections for i in range(n)]


def refinement_figures(root: str, held_out_every: int = 5) -> dict[str, float]:
    """How the refined KITTI 00 trajectory compares with the raw poses: medians (and 90th
    percentiles) of the true same-class object pair distances at the revisits (metres; raw,
    refined, and under the refined transforms M themselves), the same on every
    `held_out_every`-th revisit with a trajectory refined WITHOUT those revisits, and the
    change of the consecutive relative motions (metres, degrees: median and max)."""
    L, ij, M = kitti_sequence(root)
    R = kitti_refined_poses(root)
    scans = kitti_scan_objects(root)
    d_raw, d_ref, d_M = revisit_pair_distances(scans, ij, M, [L, R, None])
    held = np.arange(len(ij)) % held_out_every == 0
    R_fit = refine_trajectory(L, ij[~held], M[~held])
    h_raw, h_ref = revisit_pair_distances(scans, ij[held], M[held], [L, R_fit])
    dm, dd = step_changes(L, R)
    return {
        "revisits": len(ij), "object_pairs": len(d_raw),
        "raw_median_m": float(np.median(d_raw)), "refined_median_m": float(np.median(d_ref)),
        "raw_p90_m": float(np.percentile(d_raw, 90)),
        "refined_p90_m": float(np.percentile(d_ref, 90)),
        "M_median_m": float(np.median(d_M)),
        "held_out_revisits": int(held.sum()), "held_out_pairs": len(h_raw),
        "held_out_raw_median_m": float(np.median(h_raw)),
        "held_out_refined_median_m": float(np.median(h_ref)),
        "step_median_m": float(np.median(dm)), "step_max_m": float(dm.max()),
        "step_median_deg": float(np.median(dd)), "step_max_deg": float(dd.max()),
    }
