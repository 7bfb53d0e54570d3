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
    return error_at(T_loop, centroid(points))


def centroid(points: np.ndarray) -> np.ndarray:
    """(1,3) the mean of `points` (n,3) (the origin when there are none), as `loop_error`
    takes it."""
    return np.asarray(points, np.float64).reshape(-1, 3).mean(axis=0, keepdims=True) if len(
        points) else np.zeros((1, 3))


def error_at(T_loop: np.ndarray, c: np.ndarray) -> tuple[float, float]:
    """`loop_error` at a given centroid c (1,3)."""
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


class _Loops:
    """The loops `select_consistent` votes with, each loop's error computed once per call:
    the links do not change while links are dropped, only which of them take part."""

    def __init__(self, n: int, edges: Sequence[Edge], points: Callable[[int], np.ndarray],
                 tol: tuple[float, float]) -> None:
        self.n, self.edges, self.points, self.tol = n, edges, points, tol
        self._centres: dict[int, np.ndarray] = {}
        self._bad: dict[tuple, bool] = {}
        self._rel: dict[tuple[int, int], np.ndarray] = {}

    def rel(self, k: int, frm: int) -> np.ndarray:
        """`relative(edges[k], frm)`, computed once."""
        key = (k, frm)
        if key not in self._rel:
            self._rel[key] = relative(self.edges[k], frm)
        return self._rel[key]

    def bad(self, key: tuple, compose: Callable[[], np.ndarray], robot: int, links: int) -> bool:
        """Whether the loop `key` (its composition `compose()`, at `robot`'s centroid, of
        `links` links) disagrees beyond the tolerance; memoised by key."""
        out = self._bad.get(key)
        if out is None:
            if robot not in self._centres:
                self._centres[robot] = centroid(self.points(robot))
            err = error_at(compose(), self._centres[robot])
            lim = loop_tolerance(self.tol[0], self.tol[1], links)
            out = self._bad[key] = err[0] > lim[0] or err[1] > lim[1]
        return out


def _triangle_votes(loops: _Loops, ids):
    """Votes (bad, good) per edge id from every triangle of edges in `ids`."""
    edges = loops.edges
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
            wrong = loops.bad(
                ("t", a, kab, kbc, kac),
                lambda a=a, b=b, c=c, kab=kab, kbc=kbc, kac=kac:
                loops.rel(kab, a) @ loops.rel(kbc, b) @ loops.rel(kac, c), a, 3)
            _vote(wrong, (kab, kbc, kac), bad, good)
    return bad, good


def _cycle_votes(loops: _Loops, ids):
    """Votes from the fundamental cycles of the maximum-confidence spanning forest."""
    edges = loops.edges
    tree = spanning_forest(loops.n, edges, ids)
    in_tree = set(tree)
    parent, depth = _rooted(edges, tree)
    bad: dict[int, int] = {}
    good: dict[int, int] = {}
    for k in ids:
        if k in in_tree:
            continue
        e = edges[k]
        path = _tree_path(edges, parent, depth, e.a, e.b)
        wrong = loops.bad(("c", k, *path), lambda e=e, k=k, path=path: _closing(
            loops, k, e, path), e.a, 1 + len(path))
        _vote(wrong, (k, *path), bad, good)
    return bad, good


def _closing(loops: _Loops, k: int, e: Edge, path: list[int]) -> np.ndarray:
    """T_a_b of edge k composed with the tree's T_b_a (along `path`, from a to b), the
    products taken in the order `tree_poses` from a takes them."""
    P, x = np.eye(4), e.a
    for t in path:
        P = P @ loops.rel(t, x)
        x = loops.edges[t].b if loops.edges[t].a == x else loops.edges[t].a
    return loops.rel(k, e.a) @ invert(P)


def _rooted(edges: Sequence[Edge], tree: Sequence[int]):
    """Parent (node -> (parent node, edge id)) and depth of every node of the forest `tree`."""
    adj: dict[int, list[int]] = {}
    for k in tree:
        adj.setdefault(edges[k].a, []).append(k)
        adj.setdefault(edges[k].b, []).append(k)
    parent: dict[int, tuple[int, int] | None] = {}
    depth: dict[int, int] = {}
    for r in adj:
        if r in parent:
            continue
        parent[r], depth[r] = None, 0
        stack = [r]
        while stack:
            x = stack.pop()
            for k in adj[x]:
                y = edges[k].b if edges[k].a == x else edges[k].a
                if y not in parent:
                    parent[y], depth[y] = (x, k), depth[x] + 1
                    stack.append(y)
    return parent, depth


def _tree_path(edges, parent, depth, a: int, b: int) -> list[int]:
    """Edge ids of the forest's path from a to b (a and b in one tree)."""
    up, down = [], []
    while depth[a] > depth[b]:
        a, k = parent[a]
        up.append(k)
    while depth[b] > depth[a]:
        b, k = parent[b]
        down.append(k)
    while a != b:
        a, ka = parent[a]
        b, kb = parent[b]
        up.append(ka)
        down.append(kb)
    return up + down[::-1]


def loop_tolerance(tol_m: float, tol_deg: float, n_links: int) -> tuple[float, float]:
    """What a loop of `n_links` links, each within tol_m / tol_deg of the truth, may disagree
    by: the links' independent errors add in quadrature, so tol * sqrt(n_links)."""
    f = float(np.sqrt(n_links))
    return tol_m * f, tol_deg * f


def _vote(wrong: bool, loop, bad, good):
    votes = bad if wrong else good
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
    loops = _Loops(n, edges, points, (tol_m, tol_deg))
    while ids:
        bad, good = _triangle_votes(loops, ids)
        if not bad:
            bad, good = _cycle_votes(loops, ids)
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
