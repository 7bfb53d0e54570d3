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

from dataclasses import dataclass

import numpy as np

from sgloc.geometry import apply
from sgloc.online.consistency import loop_error
from sgloc.online.refine import co_located

#: A robot pair takes part from this many co-located object pairs (3 fix a rigid motion).
MIN_PAIRS = 3


@dataclass(frozen=True)
class Overlap:
    """Objects ia of robot a lie on top of objects ib of robot b (indices into their maps)."""

    a: int
    b: int
    ia: np.ndarray
    ib: np.ndarray


def overlaps(
    frames: dict[int, np.ndarray], objects: dict[int, tuple[np.ndarray, np.ndarray]],
    radius: float,
) -> list[Overlap]:
    """Every pair of robots in `frames` (T_fleet_robot, (4,4)) whose maps (objects[r]:
    positions (n,3) in r's odometry frame, metres; labels (n,)) co-locate at least MIN_PAIRS
    objects in the fleet frame; robots in ascending order."""
    robots = sorted(frames)
    moved = {r: apply(frames[r], objects[r][0]) for r in robots}
    boxes = {r: (p.min(axis=0) - radius, p.max(axis=0) + radius) if len(p) else None
             for r, p in moved.items()}
    out = []
    for k, a in enumerate(robots):
        for b in robots[k + 1:]:
            if boxes[a] is None or boxes[b] is None or np.any(boxes[a][0] > boxes[b][1]) \
                    or np.any(boxes[b][0] > boxes[a][1]):
                continue
            ib, ia = co_located(moved[b], objects[b][1], moved[a], objects[a][1], np.eye(4),
                                radius)
            if len(ia) >= MIN_PAIRS:
                out.append(Overlap(a, b, ia, ib))
    return out


def _reached(root: int, pairs: list[Overlap]) -> list[int]:
    """The robots the co-location graph connects to `root` (root excluded), ascending."""
    seen, todo = {root}, [root]
    while todo:
        r = todo.pop()
        for o in pairs:
            for x, y in ((o.a, o.b), (o.b, o.a)):
                if x == r and y not in seen:
                    seen.add(y)
                    todo.append(y)
    return sorted(seen - {root})


def _jacobian(points: np.ndarray, centre: np.ndarray, cols: list[int]) -> np.ndarray:
    """(n,3,len(cols)): d(point)/d[rx ry rz tx ty tz] for a rotation about `centre` followed
    by a translation, both in the fleet frame."""
    d = points - centre
    J = np.zeros((len(points), 3, 6))
    J[:, 0, 1], J[:, 0, 2] = d[:, 2], -d[:, 1]
    J[:, 1, 0], J[:, 1, 2] = -d[:, 2], d[:, 0]
    J[:, 2, 0], J[:, 2, 1] = d[:, 1], -d[:, 0]
    J[:, :, 3:] = np.eye(3)
    return J[:, :, cols]


def _step(
    frames: dict[int, np.ndarray], objects: dict, pairs: list[Overlap], free: list[int],
    centres: dict[int, np.ndarray], cols: list[int], huber: float,
) -> np.ndarray:
    """One robust Gauss-Newton step: the stacked [r t] updates of the free robots."""
    m = len(cols)
    slot = {r: k for k, r in enumerate(free)}
    H = np.zeros((m * len(free), m * len(free)))
    g = np.zeros(m * len(free))
    for o in pairs:
        pa = apply(frames[o.a], objects[o.a][0][o.ia])
        pb = apply(frames[o.b], objects[o.b][0][o.ib])
        res = pa - pb
        w = np.minimum(1.0, huber / np.maximum(np.linalg.norm(res, axis=1), 1e-12))
        blocks = [(slot[r], sign * _jacobian(p, centres[r], cols))
                  for r, p, sign in ((o.a, pa, 1.0), (o.b, pb, -1.0)) if r in slot]
        for s, J in blocks:
            g[s * m:(s + 1) * m] += np.einsum("n,nij,ni->j", w, J, res)
            for t, K in blocks:
                H[s * m:(s + 1) * m, t * m:(t + 1) * m] += np.einsum("n,nij,nik->jk", w, J, K)
    # A little damping keeps a robot with nearly collinear pairs where it is about that axis.
    H[np.diag_indices_from(H)] += 1e-9 * (np.trace(H) / len(H)) + 1e-12
    return -np.linalg.solve(H, g)


def _moved(T: np.ndarray, xi: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """T moved by the rotation xi[:3] (rotation vector, rad) about `centre` and then by
    xi[3:] (metres), both in the fleet frame."""
    from scipy.spatial.transform import Rotation

    M = np.eye(4)
    M[:3, :3] = Rotation.from_rotvec(xi[:3]).as_matrix()
    M[:3, 3] = centre - M[:3, :3] @ centre + xi[3:]
    return M @ T


def refine_fleet(
    frames: dict[int, np.ndarray], objects: dict[int, tuple[np.ndarray, np.ndarray]],
    root: int, radius: float, dof: int = 6, rounds: int = 5, steps: int = 5,
) -> tuple[dict[int, np.ndarray], int]:
    """(refined T_fleet_robot of every robot in `frames`, object pairs used). dof 4: yaw about
    the fleet frame's z and translation (roll and pitch kept), 6: any motion. Residuals are
    weighted by Huber's function with k = radius / 2. Robots the co-location graph does not
    connect to the root keep their frames. Deterministic."""
    cols = [2, 3, 4, 5] if dof == 4 else [0, 1, 2, 3, 4, 5]
    frames = {r: np.array(T, np.float64) for r, T in frames.items()}
    previous, n_pairs = None, 0
    for _ in range(rounds):
        pairs = overlaps(frames, objects, radius)
        key = [(o.a, o.b, o.ia.tobytes(), o.ib.tobytes()) for o in pairs]
        free = _reached(root, pairs)
        n_pairs = sum(len(o.ia) for o in pairs if o.a in free or o.b in free)
        if key == previous or not free:
            break
        previous = key
        centres = {r: apply(frames[r], objects[r][0]).mean(axis=0) for r in free}
        for _ in range(steps):
            dx = _step(frames, objects, pairs, free, centres, cols, radius / 2.0)
            for k, r in enumerate(free):
                xi = np.zeros(6)
                xi[cols] = dx[k * len(cols):(k + 1) * len(cols)]
                frames[r] = _moved(frames[r], xi, centres[r])
    return frames, n_pairs


def largest_shift(
    before: dict[int, np.ndarray], after: dict[int, np.ndarray],
    points: dict[int, np.ndarray],
) -> tuple[float, float]:
    """(metres, degrees): the largest move of a robot's frame from `before` to `after`, at the
    centroid of its objects (points[r], its odometry frame) and in rotation."""
    worst = (0.0, 0.0)
    for r, T in after.items():
        m, d = loop_error(T @ np.linalg.inv(before[r]), apply(before[r], points[r]))
        worst = (max(worst[0], m), max(worst[1], d))
    return worst
