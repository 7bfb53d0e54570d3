"""g2o pose-graph files: VERTEX_SE3:QUAT and EDGE_SE3:QUAT lines (as read by g2o, gtsam's
readG2o and evo's tools)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sgloc.errors import SglocError
from sgloc.geometry import regularized_covariance

#: gtsam tangent order [rx ry rz tx ty tz] -> g2o order [tx ty tz rx ry rz].
_TO_G2O = np.array([3, 4, 5, 0, 1, 2])


def _pose_text(T: np.ndarray) -> str:
    from scipy.spatial.transform import Rotation  # deferred: scipy.spatial loads in ~0.2 s

    q = Rotation.from_matrix(T[:3, :3]).as_quat()  # x y z w
    return " ".join(f"{v:.9f}" for v in (*T[:3, 3], *q))


def write_g2o(
    path: str | Path,
    vertices: dict[int, np.ndarray],
    edges: Sequence[tuple[int, int, np.ndarray, np.ndarray]],
) -> Path:
    """Write vertices {id: T_world_node (4,4)} and edges (a, b, T_a_b (4,4), covariance (6,6)
    in [rx ry rz tx ty tz] order). Each edge's information matrix (inverse covariance) is
    written in g2o's [tx ty tz rx ry rz] order, upper triangle row by row (21 values), the
    rotation block for rotation-vector errors as gtsam's readG2o reads it."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"VERTEX_SE3:QUAT {k} {_pose_text(np.asarray(T))}"
             for k, T in sorted(vertices.items())]
    iu = np.triu_indices(6)
    for a, b, T, cov in edges:
        info = np.linalg.inv(regularized_covariance(cov))[np.ix_(_TO_G2O, _TO_G2O)]
        info = 0.5 * (info + info.T)
        vals = " ".join(f"{v:.9g}" for v in info[iu])
        lines.append(f"EDGE_SE3:QUAT {a} {b} {_pose_text(np.asarray(T))} {vals}")
    p.write_text("\n".join(lines) + "\n")
    return p


def read_g2o(
    path: str | Path,
) -> tuple[dict[int, np.ndarray], list[tuple[int, int, np.ndarray, np.ndarray]]]:
    """(vertices, edges) of a g2o file written by `write_g2o` (covariances back in
    [rx ry rz tx ty tz] order)."""
    from scipy.spatial.transform import Rotation

    def pose(vals: list[str]) -> np.ndarray:
        v = np.array(vals, dtype=np.float64)
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(v[3:7] / np.linalg.norm(v[3:7])).as_matrix()
        T[:3, 3] = v[:3]
        return T

    vertices, edges = {}, []
    p = Path(path)
    for n, line in enumerate(p.read_text().splitlines(), 1):
        f = line.split()
        try:
            if f and f[0] == "VERTEX_SE3:QUAT":
                vertices[int(f[1])] = pose(f[2:9])
            elif f and f[0] == "EDGE_SE3:QUAT":
                info = np.zeros((6, 6))
                info[np.triu_indices(6)] = np.array(f[10:31], dtype=np.float64)
                info = info + np.triu(info, 1).T
                back = np.argsort(_TO_G2O)
                cov = np.linalg.inv(info[np.ix_(back, back)])
                edges.append((int(f[1]), int(f[2]), pose(f[3:10]), cov))
        except (ValueError, IndexError, np.linalg.LinAlgError) as e:
            raise SglocError(f"{p}:{n}: not a g2o SE3 line ({e}).") from None
    return vertices, edges
