"""Joint refinement of the fleet frame on co-located objects.

The pose graph places each robot through its links, each fitted where two robots met. A small
rotation error of a link is carried to the far end of the robot's map, and down a chain of
links it adds up. Once placed, two robots' maps often share objects in places where no link
was fitted (a robot passes where another robot, not the one it is linked to, drove). Here every
pair of placed robots, linked or not, contributes the object pairs the current fleet frame
puts on top of each other (mutual nearest same-class neighbours within a radius), and the
robots' frames are refined together on all of them (robust Gauss-Newton; the root stays fixed),
until the pairing stops changing.
"""

from __future__ import annotations

import numpy as np

from sgloc.geometry import apply, invert
from sgloc.kernels import one_blas_thread
from sgloc.lie import skew, so3_exp
from sgloc.maps.spatial import mutual_nearest_pairs
from sgloc.online.loops import loop_error

#: A robot pair takes part from this many co-located object pairs (3 fix a rigid motion).
MIN_PAIRS = 3
#: Gauss-Newton stops once no update exceeds this (radians, metres).
CONVERGED = 1e-6


def co_located_pairs(
    moved: np.ndarray, labels: np.ndarray, robot_of: np.ndarray, radius: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(i, j): objects i and j (rows of the stacked `moved` (n,3), fleet frame, metres) of two
    robots robot_of[i] < robot_of[j] that are mutual nearest same-class neighbours between
    those two robots, closer than `radius`; robot pairs with fewer than MIN_PAIRS dropped."""
    i, j = mutual_nearest_pairs(moved, labels, robot_of, radius)
    pair = robot_of[i] * (robot_of.max(initial=0) + 1) + robot_of[j]
    _, inverse, counts = np.unique(pair, return_inverse=True, return_counts=True)
    keep = counts[inverse] >= MIN_PAIRS
    return i[keep], j[keep]


def _reached(n: int, root: int, ra: np.ndarray, rb: np.ndarray) -> np.ndarray:
    """Mask (n,) of the robots the co-location graph (edges ra-rb) connects to `root`,
    root excluded."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    adj = coo_matrix((np.ones(len(ra)), (ra, rb)), shape=(n, n))
    _, comp = connected_components(adj, directed=False)
    mask = comp == comp[root]
    mask[root] = False
    return mask


def _jacobian(points: np.ndarray, centres: np.ndarray, cols: list[int]) -> np.ndarray:
    """(n,3,len(cols)): d(point)/d[rx ry rz tx ty tz] for a rotation about its robot's centre
    (centres (n,3)) followed by a translation, both in the fleet frame."""
    J = np.zeros((len(points), 3, 6))
    J[:, :, :3] = -skew(points - centres)  # d(w x d)/dw = -[d]x
    J[:, :, 3:] = np.eye(3)
    return J[:, :, cols]


def _add_by(out: np.ndarray, rows: np.ndarray, values: np.ndarray) -> None:
    """out[rows[k]] += values[k] for every k, summed per row in a fixed order."""
    if len(rows) == 0:
        return
    order = np.argsort(rows, kind="stable")
    rows = rows[order]
    starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
    out[rows[starts]] += np.add.reduceat(values[order], starts, axis=0)


def _step(
    moved: np.ndarray, robot_of: np.ndarray, i: np.ndarray, j: np.ndarray, slot: np.ndarray,
    centres: np.ndarray, cols: list[int], huber: float,
) -> np.ndarray:
    """One robust Gauss-Newton step: (free robots, len(cols)) updates [r t] (slot[r]: the row
    of robot r, -1 for a fixed robot)."""
    m, n_free = len(cols), int(slot.max()) + 1
    res = moved[i] - moved[j]
    w = np.minimum(1.0, huber / np.maximum(np.linalg.norm(res, axis=1), 1e-12))
    sides = [(slot[robot_of[k]], sign * _jacobian(moved[k], centres[robot_of[k]], cols))
             for k, sign in ((i, 1.0), (j, -1.0))]
    H = np.zeros((n_free * n_free, m, m))
    g = np.zeros((n_free, m))
    for sx, Jx in sides:
        fx = sx >= 0
        WJ = (Jx[fx] * w[fx, None, None]).transpose(0, 2, 1)
        _add_by(g, sx[fx], np.matmul(WJ, res[fx, :, None])[:, :, 0])
        for sy, Jy in sides:
            f = sy[fx] >= 0
            _add_by(H, sx[fx][f] * n_free + sy[fx][f], np.matmul(WJ[f], Jy[fx][f]))
    H = H.reshape(n_free, n_free, m, m)
    H = H.transpose(0, 2, 1, 3).reshape(n_free * m, n_free * m)
    # A little damping keeps a robot with nearly collinear pairs where it is about that axis.
    H[np.diag_indices_from(H)] += 1e-9 * (np.trace(H) / len(H)) + 1e-12
    return -np.linalg.solve(H, g.ravel()).reshape(n_free, m)


def _moved(T: np.ndarray, xi: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """T moved by the rotation xi[:3] (rotation vector, rad) about `centre` and then by
    xi[3:] (metres), both in the fleet frame (not Exp(xi): the rotation is about `centre`)."""
    M = np.eye(4)
    M[:3, :3] = so3_exp(xi[:3])
    M[:3, 3] = centre - M[:3, :3] @ centre + xi[3:]
    return M @ T


def _in_fleet(T: np.ndarray, points: np.ndarray, robot_of: np.ndarray) -> np.ndarray:
    """points (n,3) of robots robot_of (n,) moved by their frames T (R,4,4)."""
    return np.einsum("nij,nj->ni", T[robot_of, :3, :3], points) + T[robot_of, :3, 3]


def refine_fleet(
    frames: dict[int, np.ndarray], objects: dict[int, tuple[np.ndarray, np.ndarray]],
    root: int, radius: float, dof: int = 6, rounds: int = 5, steps: int = 5,
) -> tuple[dict[int, np.ndarray], int]:
    """(refined T_fleet_robot of every robot in `frames`, object pairs used). objects[r]:
    positions (n,3) in r's odometry frame (metres) and labels (n,). dof 4: yaw about the fleet
    frame's z and translation (roll and pitch kept), 6: any motion. Residuals are weighted by
    Huber's function with k = radius / 2. Robots the co-location graph does not connect to
    the root keep their frames. Deterministic."""
    with one_blas_thread():  # small solves: a second BLAS thread on a busy machine only waits
        return _refine(frames, objects, root, radius, dof, rounds, steps)


def _refine(
    frames: dict[int, np.ndarray], objects: dict[int, tuple[np.ndarray, np.ndarray]],
    root: int, radius: float, dof: int, rounds: int, steps: int,
) -> tuple[dict[int, np.ndarray], int]:
    """`refine_fleet`'s work."""
    cols = [2, 3, 4, 5] if dof == 4 else [0, 1, 2, 3, 4, 5]
    robots = sorted(frames)
    T = np.stack([np.asarray(frames[r], np.float64) for r in robots])
    points = np.concatenate([np.asarray(objects[r][0], np.float64).reshape(-1, 3)
                             for r in robots])
    labels = np.concatenate([np.asarray(objects[r][1]).reshape(-1) for r in robots])
    robot_of = np.repeat(np.arange(len(robots)), [len(objects[r][1]) for r in robots])
    previous, n_pairs, r0 = None, 0, robots.index(root)
    for _ in range(rounds):
        moved = _in_fleet(T, points, robot_of)
        i, j = co_located_pairs(moved, labels, robot_of, radius)
        free = _reached(len(robots), r0, robot_of[i], robot_of[j])
        n_pairs = int(np.sum(free[robot_of[i]] | free[robot_of[j]]))
        unchanged = previous is not None and np.array_equal(i, previous[0]) \
            and np.array_equal(j, previous[1])
        if unchanged or not free.any():
            break
        previous = i, j
        slot = np.where(free, np.cumsum(free) - 1, -1)
        centres = np.zeros((len(robots), 3))
        for r in np.flatnonzero(free):
            centres[r] = moved[robot_of == r].mean(axis=0)
        for _ in range(steps):
            dx = _step(moved, robot_of, i, j, slot, centres, cols, radius / 2.0)
            for r in np.flatnonzero(free):
                xi = np.zeros(6)
                xi[cols] = dx[slot[r]]
                T[r] = _moved(T[r], xi, centres[r])
            moved = _in_fleet(T, points, robot_of)
            if np.abs(dx).max() < CONVERGED:
                break
    return {r: T[k] for k, r in enumerate(robots)}, n_pairs


def largest_shift(
    before: dict[int, np.ndarray], after: dict[int, np.ndarray],
    points: dict[int, np.ndarray],
) -> tuple[float, float]:
    """(metres, degrees): the largest move of a robot's frame from `before` to `after`, at the
    centroid of its objects (points[r], its odometry frame) and in rotation."""
    worst = (0.0, 0.0)
    for r, T in after.items():
        m, d = loop_error(T @ invert(before[r]), apply(before[r], points[r]))
        worst = (max(worst[0], m), max(worst[1], d))
    return worst
