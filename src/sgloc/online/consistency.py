"""Outlier-robust selection of inter-robot links: links that close a loop must compose to the
identity (the fleet-level analogue of the neighbour constraint: two trusted links that share
robots must agree about them). Greedy: drop the link in the most disagreeing loops until every
loop agrees."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from sgloc.geometry import apply, invert, rotation_angle_deg
from sgloc.lie import adjoint


@dataclass(frozen=True)
class Edge:
    """A link between robot indices a and b: T_a_b maps b's frame into a's."""

    a: int
    b: int
    T_a_b: np.ndarray
    confidence: float
    stamp: float


def relative(edge: Edge, frm: int) -> np.ndarray:
    """T_frm_other along `edge`, seen from its end `frm`."""
    return edge.T_a_b if frm == edge.a else invert(edge.T_a_b)


def invert_with_covariance(T_a_b: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T_b_a, its covariance) from T_a_b and its covariance ([rx ry rz tx ty tz], right
    perturbation): T_a_b Exp(xi) inverted is T_b_a Exp(-Ad(T_a_b) xi) (`sgloc.lie.adjoint`)."""
    ad = adjoint(T_a_b)
    return invert(T_a_b), ad @ cov @ ad.T


def loop_error(T_loop: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """(displacement of the centroid of `points` by T_loop in metres, T_loop's rotation angle
    in degrees). At the centroid, not RMS over the points: over a map hundreds of metres long a
    rotation within the angle tolerance alone would move the far objects by metres."""
    c = np.asarray(points, np.float64).reshape(-1, 3).mean(axis=0, keepdims=True) if len(
        points) else np.zeros((1, 3))
    return float(np.linalg.norm(apply(T_loop, c) - c)), rotation_angle_deg(T_loop[:3, :3])


def spanning_forest(n: int, edges: Sequence[Edge], ids: Sequence[int]) -> list[int]:
    """Kruskal on descending confidence (to 1e-6; ties: older, then lower index): the ids of a
    maximum-confidence spanning forest."""
    parent = list(range(n))

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    tree = []
    for k in sorted(ids, key=lambda k: (-round(edges[k].confidence, 6), edges[k].stamp, k)):
        ra, rb = find(edges[k].a), find(edges[k].b)
        if ra != rb:
            parent[ra] = rb
            tree.append(k)
    return tree


def tree_poses(
    n: int, edges: Sequence[Edge], tree: Sequence[int], root: int
) -> tuple[dict[int, np.ndarray], dict[int, list[int]]]:
    """T_root_robot for the tree component of `root`, and each robot's path (edge ids)."""
    adj: dict[int, list[int]] = {}
    for k in tree:
        adj.setdefault(edges[k].a, []).append(k)
        adj.setdefault(edges[k].b, []).append(k)
    poses, paths = {root: np.eye(4)}, {root: []}
    stack = [root]
    while stack:
        x = stack.pop()
        for k in adj.get(x, []):
            y = edges[k].b if edges[k].a == x else edges[k].a
            if y not in poses:
                poses[y] = poses[x] @ relative(edges[k], x)
                paths[y] = paths[x] + [k]
                stack.append(y)
    return poses, paths


def _triangle_votes(edges, ids, points, tol):
    """Votes (bad, good) per edge id from every triangle of edges in `ids`."""
    by_pair = {(min(edges[k].a, edges[k].b), max(edges[k].a, edges[k].b)): k for k in ids}
    nbrs: dict[int, set[int]] = {}
    for a, b in by_pair:
        nbrs.setdefault(a, set()).add(b)
        nbrs.setdefault(b, set()).add(a)
    bad: dict[int, int] = {}
    good: dict[int, int] = {}
    for (a, b), kab in by_pair.items():
        for c in sorted(nbrs[a] & nbrs[b]):
            if c <= b:  # each triangle once: a < b < c
                continue
            kbc, kac = by_pair[(b, c)], by_pair[(a, c)]
            T = relative(edges[kab], a) @ relative(edges[kbc], b) @ relative(edges[kac], c)
            _vote(loop_error(T, points(a)), tol, (kab, kbc, kac), bad, good)
    return bad, good


def _cycle_votes(n, edges, ids, points, tol):
    """Votes from the fundamental cycles of the maximum-confidence spanning forest."""
    tree = spanning_forest(n, edges, ids)
    in_tree = set(tree)
    bad: dict[int, int] = {}
    good: dict[int, int] = {}
    done: dict[int, tuple] = {}
    for k in ids:
        if k in in_tree:
            continue
        e = edges[k]
        if e.a not in done:
            done[e.a] = tree_poses(n, edges, tree, e.a)
        poses, paths = done[e.a]
        T = relative(e, e.a) @ invert(poses[e.b])  # T_a_b composed with the tree's T_b_a
        _vote(loop_error(T, points(e.a)), tol, (k, *paths[e.b]), bad, good)
    return bad, good


def loop_tolerance(tol_m: float, tol_deg: float, n_links: int) -> tuple[float, float]:
    """What a loop of `n_links` links, each within tol_m / tol_deg of the truth, may disagree
    by: the links' independent errors add in quadrature, so tol * sqrt(n_links)."""
    f = float(np.sqrt(n_links))
    return tol_m * f, tol_deg * f


def _vote(err, tol, loop, bad, good):
    lim = loop_tolerance(tol[0], tol[1], len(loop))
    votes = bad if err[0] > lim[0] or err[1] > lim[1] else good
    for k in loop:
        votes[k] = votes.get(k, 0) + 1


def select_consistent(
    n: int,
    edges: Sequence[Edge],
    points: Callable[[int], np.ndarray],
    tol_m: float,
    tol_deg: float,
) -> tuple[list[int], dict[int, str]]:
    """Ids of a set of edges whose loops all compose to the identity (at the centroid of the
    loop's first robot's objects, `points(robot)`) within tol_m metres / tol_deg degrees per
    link (`loop_tolerance`), and the reason each dropped id was dropped. Triangles vote first,
    then longer loops of the spanning forest; the edge in the most disagreeing loops is dropped
    (ties: fewest agreeing loops, lowest confidence, newest), until no loop disagrees."""
    ids = list(range(len(edges)))
    dropped: dict[int, str] = {}
    tol = (tol_m, tol_deg)
    while ids:
        bad, good = _triangle_votes(edges, ids, points, tol)
        if not bad:
            bad, good = _cycle_votes(n, edges, ids, points, tol)
        if not bad:
            break
        worst = max(bad, key=lambda k: (bad[k], -good.get(k, 0), -edges[k].confidence,
                                        edges[k].stamp, k))
        dropped[worst] = (
            f"contradicted: disagrees around {bad[worst]} loop(s) of links by more than "
            f"{tol_m:g} m / {tol_deg:g} deg per link (agrees around {good.get(worst, 0)})"
        )
        ids.remove(worst)
    return ids, dropped
