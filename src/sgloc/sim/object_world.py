"""A small synthetic object world generated in code: objects along a street grid, two robots
that each map a stretch of the main street, each in its own frame, with a known ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.geometry import apply, invert, random_rigid_transform
from sgloc.maps.graph import SemanticGraph

#: Relative frequency of the 8 object classes (building, tree, pole, car, sign, fence, bush,
#: bench): repeated enough to be ambiguous, as in real cities.
CLASS_WEIGHTS = np.array([0.18, 0.22, 0.15, 0.15, 0.08, 0.08, 0.09, 0.05])


def make_object_world(
    rng: np.random.Generator, length: float = 600.0, block: float = 60.0, spacing: float = 9.0
) -> tuple[np.ndarray, np.ndarray]:
    """Objects (positions (n,3) metres, labels (n,)) on both sides of a main street along x
    (from 0 to `length`) and of cross streets every `block` metres."""
    pts, labs = [], []

    def line(p0: np.ndarray, p1: np.ndarray) -> None:
        d = np.linalg.norm(p1 - p0)
        n = int(d / spacing)
        s = np.sort(rng.uniform(0, 1, n))[:, None]
        side = rng.choice([-1.0, 1.0], n)[:, None]
        normal = np.array([-(p1 - p0)[1], (p1 - p0)[0], 0.0]) / d
        xyz = p0 + s * (p1 - p0) + side * normal * rng.uniform(6, 14, (n, 1))
        xyz[:, 2] = rng.uniform(0, 4, n)
        pts.append(xyz)
        labs.append(rng.choice(len(CLASS_WEIGHTS), n, p=CLASS_WEIGHTS))

    line(np.array([0.0, 0, 0]), np.array([length, 0, 0]))
    for x in np.arange(block / 2, length, block):
        line(np.array([x, -120.0, 0]), np.array([x, 120.0, 0]))
    return np.concatenate(pts), np.concatenate(labs)


def observe_street(
    pos: np.ndarray,
    lab: np.ndarray,
    x0: float,
    x1: float,
    rng: np.random.Generator,
    view_radius: float = 40.0,
    keep_probability: float = 0.85,
    noise: float = 0.5,
    name: str = "",
) -> SemanticGraph:
    """The map of a robot driving the main street from x = x0 to x1 (metres) past the objects
    (pos, lab): those within `view_radius` of its path, each kept with probability
    `keep_probability`, positions with Gaussian `noise` (metres), in the world frame."""
    d = np.hypot(np.clip(pos[:, 0], x0, x1) - pos[:, 0], pos[:, 1])
    seen = (d < view_radius) & (rng.random(len(pos)) < keep_probability)
    p = pos[seen] + rng.normal(0, noise, (int(seen.sum()), 3))
    return SemanticGraph(p, lab[seen], name=name)


@dataclass
class TwoRobotScene:
    """Two robots' graphs, each in its own frame, and the ground truth T_target_query."""

    query: SemanticGraph
    target: SemanticGraph
    T_target_query: np.ndarray


def make_two_robot_scene(
    seed: int = 0,
    overlap: float = 0.5,
    stretch: float = 300.0,
    view_radius: float = 40.0,
    noise: float = 0.5,
    keep_probability: float = 0.85,
) -> TwoRobotScene:
    """Robot A (target) maps the main street over [0, stretch]; robot B (query) over a stretch
    sharing `overlap` of it; each sees objects within `view_radius` of its path, misses some
    (`keep_probability`), and measures positions with Gaussian `noise` (metres)."""
    rng = np.random.default_rng(seed)
    length = stretch * (2 - overlap) + 2 * view_radius
    pos, lab = make_object_world(rng, length=length)
    a0 = view_radius
    b0 = a0 + stretch * (1 - overlap)

    view = (view_radius, keep_probability, noise)
    world_target = observe_street(pos, lab, a0, a0 + stretch, rng, *view, name="robot_a")
    world_query = observe_street(pos, lab, b0, b0 + stretch, rng, *view, name="robot_b")
    # Each robot's map frame is a random rigid motion of the world frame.
    T_world_a = random_rigid_transform(rng, 100.0, 3.0)
    T_world_b = random_rigid_transform(rng, 100.0, 3.0)
    target = SemanticGraph(
        apply(invert(T_world_a), world_target.positions), world_target.labels, name="robot_a"
    )
    query = SemanticGraph(
        apply(invert(T_world_b), world_query.positions), world_query.labels, name="robot_b"
    )
    return TwoRobotScene(query, target, invert(T_world_a) @ T_world_b)
