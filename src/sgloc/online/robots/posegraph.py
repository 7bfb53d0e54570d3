"""The fleet frame as a robust pose graph: nodes = robots' odometry frames, factors = the
mutually consistent inter-robot links (`consistency.select_consistent`) weighted by their
covariance, the root robot's frame = the fleet frame."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from sgloc.online.robots.link_selection import (
    Edge,
    LoopMemo,
    select_consistent,
    spanning_forest,
    tree_poses,
)
from sgloc.online.robots.solve import solve_pose_graph


@dataclass
class FleetFrame:
    """active: ids of the links in the consistent set; dropped: {id: reason} for the others;
    T_fleet_robot: {robot index: (4,4)} for the robots connected to the root; paths: {robot
    index: its path of link ids from the root along the spanning tree}."""

    active: list[int]
    dropped: dict[int, str]
    T_fleet_robot: dict[int, np.ndarray]
    paths: dict[int, list[int]]


def fleet_frame(
    n: int,
    edges: Sequence[Edge],
    covariances: Sequence[np.ndarray],
    root: int,
    points: Callable[[int], np.ndarray],
    tol_m: float = 3.0,
    tol_deg: float = 3.0,
    solver: str = "auto",
    memo: LoopMemo | None = None,
) -> FleetFrame:
    """Select the consistent links, place the root's connected robots along the
    maximum-confidence spanning tree, then solve the least squares over every consistent link
    among them (points(robot): that robot's objects, for the loop tolerance in metres; memo:
    loop verdicts kept between calls, `consistency.LoopMemo`)."""
    active, dropped = select_consistent(n, edges, points, tol_m, tol_deg, memo)
    tree = spanning_forest(n, edges, active)
    initial, paths = tree_poses(n, edges, tree, root)
    inside = [k for k in active if edges[k].a in initial and edges[k].b in initial]
    poses = solve_pose_graph(
        initial, [edges[k] for k in inside], [covariances[k] for k in inside], root, solver
    )
    return FleetFrame(active, dropped, poses, paths)
