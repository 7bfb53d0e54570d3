"""Maximum-clique outlier rejection, as TEASER++ and CLIPPER do.

Matches are vertices of a consistency graph (an edge when the two matches agree on their pair's
distance within tau, `sgloc.consistency.pairwise`); correct matches agree with each other, so they
form a clique, and the largest clique is kept. Finding it is NP-hard, so:
1. a fast heuristic (greedy growth from the best-connected seeds, in core-number order) gives a
   clique of size LB;
2. only vertices of core number >= LB - 1 can lie in a larger clique (k-core pruning);
3. when at most `exact_limit` of them remain, an exact branch and bound (bitsets, greedy
   colouring bound, as Tomita's MCQ) searches for the maximum, within `max_nodes` expansions;
   past either limit, the best clique found so far is returned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.consistency.pairwise import consistency_bits, unpack_rows
from sgloc.rejection.base import Rejector
from sgloc.validation import MAX_COORDINATE, MAX_ITERATIONS, MAX_VERTICES, integer, real, setting


def _bitsets(M: np.ndarray) -> list[int]:
    """Row i of bool M as a Python int with bit j set when M[i, j]."""
    packed = np.packbits(M, axis=1, bitorder="little")
    return [int.from_bytes(row.tobytes(), "little") for row in packed]


def exact_clique(
    M: np.ndarray, lower_bound: int = 0, max_nodes: int = 50_000
) -> tuple[list[int], bool]:
    """Maximum clique of a small graph (bool M (n,n), diagonal False) larger than
    `lower_bound`, by branch and bound with a greedy-colouring bound (Tomita's MCQ).

    Returns (vertices, complete): vertices of the best clique found with more than
    `lower_bound` vertices ([] if none), complete=False if `max_nodes` expansions ran out.
    """
    n = len(M)
    order = np.argsort(-M.sum(axis=1), kind="stable")  # high degree first
    nbr = _bitsets(M[np.ix_(order, order)])
    best: list[int] = []
    best_size = lower_bound
    nodes = 0

    def colour_sort(P: int) -> list[tuple[int, int]]:
        """Vertices of P with their colour, in increasing colour (greedy sequential colouring
        in vertex order); the colour bounds the clique within the vertex and those before."""
        out: list[tuple[int, int]] = []
        uncoloured = P
        colour = 0
        while uncoloured:
            colour += 1
            Q = uncoloured
            while Q:
                low = Q & -Q
                v = low.bit_length() - 1
                Q &= ~nbr[v] & ~low
                uncoloured &= ~low
                out.append((v, colour))
        return out

    def expand(R: list[int], P: int) -> bool:
        nonlocal best, best_size, nodes
        nodes += 1
        if nodes > max_nodes:
            return False
        for v, colour in reversed(colour_sort(P)):
            if len(R) + colour <= best_size:
                return True
            newP = P & nbr[v]
            R.append(v)
            if newP:
                if not expand(R, newP):
                    R.pop()
                    return False
            elif len(R) > best_size:
                best, best_size = list(R), len(R)
            R.pop()
            P &= ~(1 << v)
        return True

    complete = expand([], (1 << n) - 1) if n else True
    return sorted(int(order[v]) for v in best), complete


@dataclass
class CliqueRejector(Rejector):
    """Keep the largest set of mutually consistent matches (maximum clique).

    tau: metres; two matches are consistent when their pair's distances in the two graphs
        differ by less than tau (the neighbor rejector's form="distance" consistency).
    exact_limit: run the exact search only when at most this many vertices survive the
        k-core pruning; otherwise return the heuristic clique.
    max_nodes: expansions allowed to the exact search before it returns its best so far.
    n_seeds: seeds of the greedy heuristic (the vertices of highest core number, then degree).
    """

    tau: float = setting(5.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    exact_limit: int = setting(1000, check=integer(0, MAX_VERTICES))
    max_nodes: int = setting(50_000, check=integer(1, MAX_ITERATIONS))
    n_seeds: int = setting(16, check=integer(1, MAX_VERTICES))
    name = "clique"

    def __call__(self, src, dst, scores=None):
        """Compiled on packed rows (`sgloc.rejection.clique_kernels`: core numbers, greedy
        growth); the exact search unpacks only the k-core pool."""
        m = len(src)
        if m == 0:
            return np.zeros(0, dtype=np.int64)
        from sgloc.rejection import clique_kernels as kernels

        bits, degree = consistency_bits(src, dst, self.tau, "distance")
        core = kernels.core_numbers(bits, degree)
        rank = core * (m + 1) + degree
        seeds = np.argsort(-rank, kind="stable")[: self.n_seeds]
        best = kernels.greedy_clique(bits, rank, seeds)
        pool = np.flatnonzero(core >= len(best))
        if 0 < len(pool) <= self.exact_limit:
            sub = unpack_rows(bits[pool], m)[:, pool]
            found, _ = exact_clique(sub, len(best), self.max_nodes)
            if len(found) > len(best):
                best = np.sort(pool[found])
        return best
