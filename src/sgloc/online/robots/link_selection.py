"""Outlier-robust selection of inter-robot links: links that close a loop must compose to the
identity (the fleet-level analogue of the neighbour constraint: two trusted links that share
robots must agree about them). Greedy: drop the link in the most disagreeing loops until every
loop agrees."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from sgloc.geometry import invert
from sgloc.online.loops import centroid, error_at, loop_tolerance


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


class LoopMemo:
    """Loop verdicts `select_consistent` may reuse from one call to the next (held by its
    caller, e.g. an online session): a loop's verdict is keyed by the very arrays it was
    computed from (each link's T_a_b, the objects whose centroid it is measured at), which the
    memo keeps alive, so a changed link or map is a new key. Entries not used by the latest
    call are dropped."""

    def __init__(self) -> None:
        self._old: dict[tuple, tuple[bool, tuple]] = {}
        self._new: dict[tuple, tuple[bool, tuple]] = {}

    def get(self, key: tuple) -> bool | None:
        hit = self._new.get(key) or self._old.get(key)
        if hit is None:
            return None
        self._new[key] = hit
        return hit[0]

    def put(self, key: tuple, verdict: bool, refs: tuple) -> None:
        self._new[key] = (verdict, refs)

    def turn(self) -> None:
        """End of a call: keep what it used."""
        self._old, self._new = self._new, {}


class _Loops:
    """The loops `select_consistent` votes with, each loop's verdict computed once (and, with
    a `LoopMemo`, reused by later calls while its links and map are the same arrays)."""

    def __init__(self, n: int, edges: Sequence[Edge], points: Callable[[int], np.ndarray],
                 tol: tuple[float, float], memo: LoopMemo | None) -> None:
        self.n, self.edges, self.points, self.tol = n, edges, points, tol
        self.memo = memo if memo is not None else LoopMemo()
        self._pts: dict[int, np.ndarray] = {}
        self._centres: dict[int, np.ndarray] = {}
        self._rel: dict[tuple[int, int], np.ndarray] = {}
        self._tok = [(id(e.T_a_b), e.a, e.b) for e in edges]
        # the spanning tree of the last cycle votes and its cycles' (loop, verdict) by edge id
        self.cycles: tuple[list[int], dict[int, tuple]] = ([], {})

    def rel(self, k: int, frm: int) -> np.ndarray:
        """`relative(edges[k], frm)`, computed once."""
        key = (k, frm)
        if key not in self._rel:
            self._rel[key] = relative(self.edges[k], frm)
        return self._rel[key]

    def bad(self, loop: tuple[int, ...], starts: tuple[int, ...],
            compose: Callable[[], np.ndarray], robot: int) -> bool:
        """Whether the loop of edge ids `loop` (each traversed from robot `starts[i]`; its
        composition `compose()`), measured at `robot`'s centroid, disagrees beyond the
        tolerance."""
        if robot not in self._pts:
            self._pts[robot] = self.points(robot)
        pts = self._pts[robot]
        key = (self.tol, id(pts), robot, starts, tuple(map(self._tok.__getitem__, loop)))
        out = self.memo.get(key)
        if out is None:
            arrays = tuple(self.edges[k].T_a_b for k in loop)
            if robot not in self._centres:
                self._centres[robot] = centroid(pts)
            err = error_at(compose(), self._centres[robot])
            lim = loop_tolerance(self.tol[0], self.tol[1], len(loop))
            out = err[0] > lim[0] or err[1] > lim[1]
            self.memo.put(key, out, (pts, arrays))
        return out


def _triangles(loops: _Loops, ids) -> list[tuple[int, int, int, bool]]:
    """(kab, kbc, kac, disagrees) of every triangle of edges in `ids` (a < b < c)."""
    edges = loops.edges
    by_pair = {(min(edges[k].a, edges[k].b), max(edges[k].a, edges[k].b)): k for k in ids}
    nbrs: dict[int, set[int]] = {}
    for a, b in by_pair:
        nbrs.setdefault(a, set()).add(b)
        nbrs.setdefault(b, set()).add(a)
    out = []
    for (a, b), kab in by_pair.items():
        for c in sorted(nbrs[a] & nbrs[b]):
            if c <= b:  # each triangle once: a < b < c
                continue
            kbc, kac = by_pair[(b, c)], by_pair[(a, c)]
            wrong = loops.bad(
                (kab, kbc, kac), (a, b, c),
                lambda a=a, b=b, c=c, kab=kab, kbc=kbc, kac=kac:
                loops.rel(kab, a) @ loops.rel(kbc, b) @ loops.rel(kac, c), a)
            out.append((kab, kbc, kac, wrong))
    return out


def _triangle_votes(loops: _Loops, ids):
    """Votes (bad, good) per edge id from every triangle of edges in `ids`."""
    bad: dict[int, int] = {}
    good: dict[int, int] = {}
    for kab, kbc, kac, wrong in _triangles(loops, ids):
        _vote(wrong, (kab, kbc, kac), bad, good)
    return bad, good


def _cycle_votes(loops: _Loops, ids):
    """Votes from the fundamental cycles of the maximum-confidence spanning forest."""
    edges = loops.edges
    tree = spanning_forest(loops.n, edges, ids)
    if loops.cycles[0] != tree:  # the cycles of another tree (a tree edge was dropped)
        loops.cycles = (tree, {})
    cycles = loops.cycles[1]
    in_tree = set(tree)
    parent = depth = None
    bad: dict[int, int] = {}
    good: dict[int, int] = {}
    for k in ids:
        if k in in_tree:
            continue
        if k not in cycles:
            if parent is None:
                parent, depth = _rooted(edges, tree)
            e = edges[k]
            path = _tree_path(edges, parent, depth, e.a, e.b)
            starts = (e.a, *_starts(edges, path, e.a))
            cycles[k] = (k, *path), loops.bad((k, *path), starts, lambda e=e, k=k, path=path:
                                              _closing(loops, k, e, path), e.a)
        loop, wrong = cycles[k]
        _vote(wrong, loop, bad, good)
    return bad, good


def _closing(loops: _Loops, k: int, e: Edge, path: list[int]) -> np.ndarray:
    """T_a_b of edge k composed with the tree's T_b_a (along `path`, from a to b), the
    products taken in the order `tree_poses` from a takes them."""
    P, x = np.eye(4), e.a
    for t in path:
        P = P @ loops.rel(t, x)
        x = loops.edges[t].b if loops.edges[t].a == x else loops.edges[t].a
    return loops.rel(k, e.a) @ invert(P)


def _starts(edges: Sequence[Edge], path: list[int], x: int) -> list[int]:
    """The robot each edge of `path` (from robot x) is traversed from."""
    out = []
    for t in path:
        out.append(x)
        x = edges[t].b if edges[t].a == x else edges[t].a
    return out


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
    memo: LoopMemo | None = None,
) -> tuple[list[int], dict[int, str]]:
    """Ids of a set of edges whose loops all compose to the identity (at the centroid of the
    loop's first robot's objects, `points(robot)`) within tol_m metres / tol_deg degrees per
    link (`loop_tolerance`), and the reason each dropped id was dropped. Triangles vote first,
    then longer loops of the spanning forest; the edge in the most disagreeing loops is dropped
    (ties: fewest agreeing loops, lowest confidence, newest), until no loop disagrees.
    memo: loop verdicts kept from earlier calls (`LoopMemo`; the same answer without)."""
    ids = list(range(len(edges)))
    dropped: dict[int, str] = {}
    loops = _Loops(n, edges, points, (tol_m, tol_deg), memo)
    pairs = {(min(e.a, e.b), max(e.a, e.b)) for e in edges}
    # One edge per robot pair: a round's triangles are the first round's whose three edges
    # are all left, so they are listed once and counted with arrays.
    tri = _triangles(loops, ids) if len(pairs) == len(edges) else None
    if tri is not None:
        loop_ids = np.array([t[:3] for t in tri], np.int64).reshape(-1, 3)
        wrong = np.array([t[3] for t in tri], bool)
        alive = np.ones(len(edges), bool)
    while ids:
        if tri is not None:
            bad, good = _counted_votes(loop_ids, wrong, alive)
        else:
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
        if tri is not None:
            alive[worst] = False
    loops.memo.turn()
    return ids, dropped


def _counted_votes(loop_ids: np.ndarray, wrong: np.ndarray, alive: np.ndarray):
    """Votes (bad, good) per edge id from the triangles `loop_ids` (t,3) whose edges are all
    `alive`; wrong (t,): the triangle disagrees."""
    live = alive[loop_ids].all(axis=1)
    out = []
    for sel in (live & wrong, live & ~wrong):
        counts = np.bincount(loop_ids[sel].ravel(), minlength=len(alive))
        out.append({int(k): int(counts[k]) for k in np.flatnonzero(counts)})
    return out[0], out[1]
