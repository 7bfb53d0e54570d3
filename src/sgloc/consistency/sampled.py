"""The pairwise consistency graph of many candidates, known through a random sample of pairs.

The acceptance test needs two things of the consistency graph of its candidates (form
"distance", `sgloc.consistency.pairwise`): how many hypotheses it holds (consistent pairs for 4 dof,
consistent triples for 6 dof; only their log10 matters) and random consistent pairs to seed the
search for a rival alignment. Above `sgloc.consistency.pairwise.ALL_PAIRS_LIMIT` candidates the
packed rows (m^2 / 8 bytes) are replaced by a uniform sample of pairs: counts are estimated with an
upper confidence margin (more tests make the test stricter, never looser) and the consistent
sampled pairs are drawn in sample order. Memory and time are linear in the sample and in m.
"""

from __future__ import annotations

import numpy as np

#: Random pairs tested per batch (16 bytes of indices each).
PAIR_SAMPLES = 1 << 18
#: Batches tried at most when drawing consistent pairs among a subset.
MAX_BATCHES = 8
#: Consistent pairs whose common partners are counted for the triangle estimate (each costs m).
EDGE_SAMPLES = 256
#: Pairs whose common partners are scanned at once (EDGE_CHUNK x m float64 temporaries).
EDGE_CHUNK = 16


def random_pairs(index: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """(i, j) int64 (n,): uniform random pairs of distinct entries of `index` (k >= 2,)."""
    k = len(index)
    a = rng.integers(0, k, n)
    b = rng.integers(0, k - 1, n)
    b += b >= a
    return index[np.minimum(a, b)], index[np.maximum(a, b)]


def distance_consistent(
    src: np.ndarray, dst: np.ndarray, i: np.ndarray, j: np.ndarray, tau: float
) -> np.ndarray:
    """(n,) bool: |D(src_i, src_j) - D(dst_i, dst_j)| < tau, float64 distances as cdist's."""

    def dist(p: np.ndarray) -> np.ndarray:
        d = p[i] - p[j]
        return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])

    return np.abs(dist(src) - dist(dst)) < tau


def upper_count(hits: int, samples: int, total: float) -> float:
    """An upper estimate of how many of `total` items have a property that `hits` of
    `samples` uniform draws had: the rate plus two Poisson standard deviations (+2)."""
    rate = min(1.0, (hits + 2.0 * np.sqrt(hits) + 2.0) / max(samples, 1))
    return float(total * rate)


class SampledConsistency:
    """Consistency of m candidate matches (src, dst (m,3) metres; pairs whose distances differ
    by less than `tau` metres) through PAIR_SAMPLES uniform random pairs.

    n_pairs: upper estimate of the consistent pairs i < j; `n_triangles()`: of the consistent
    triples; `draw(free, n, rng)`: up to n consistent pairs with both ends in the mask `free`;
    `third(i, j, free, rng)`: for each pair a random candidate in `free` consistent with both
    (-1: none)."""

    def __init__(
        self, src: np.ndarray, dst: np.ndarray, tau: float, rng: np.random.Generator
    ) -> None:
        self.src = np.asarray(src, dtype=np.float64)
        self.dst = np.asarray(dst, dtype=np.float64)
        self.tau = float(tau)
        m = len(self.src)
        i, j = random_pairs(np.arange(m), PAIR_SAMPLES, rng)
        ok = distance_consistent(self.src, self.dst, i, j, self.tau)
        self.i, self.j = i[ok], j[ok]  # the consistent sampled pairs, in draw order
        self.n_pairs = upper_count(int(ok.sum()), PAIR_SAMPLES, m * (m - 1) / 2.0)

    def draw(
        self, free: np.ndarray, n: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Up to n consistent pairs (i, j) with both in `free` (m,) bool: uniform among them
        (the sample's first, then new batches among the free candidates)."""
        both = free[self.i] & free[self.j]
        i, j = self.i[both][:n], self.j[both][:n]
        index = np.flatnonzero(free)
        for _ in range(MAX_BATCHES):
            if len(i) >= n or len(index) < 2:
                break
            a, b = random_pairs(index, PAIR_SAMPLES, rng)
            ok = distance_consistent(self.src, self.dst, a, b, self.tau)
            i = np.concatenate([i, a[ok]])[:n]
            j = np.concatenate([j, b[ok]])[:n]
        return i, j

    def _common(self, i: np.ndarray, j: np.ndarray, free: np.ndarray | None):
        """Per chunk of pairs: (rows of the chunk, (chunk, m) bool consistent with both)."""
        for s in range(0, len(i), EDGE_CHUNK):
            a, b = i[s : s + EDGE_CHUNK], j[s : s + EDGE_CHUNK]
            both = self._row(a) & self._row(b)
            both[np.arange(len(a)), a] = False
            both[np.arange(len(a)), b] = False
            if free is not None:
                both &= free[None, :]
            yield slice(s, s + len(a)), both

    def _row(self, a: np.ndarray) -> np.ndarray:
        """(len(a), m) bool: candidates consistent with each candidate of `a`."""

        def dist(p: np.ndarray) -> np.ndarray:
            d = p[a][:, None, :] - p[None, :, :]
            return np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2])

        return np.abs(dist(self.src) - dist(self.dst)) < self.tau

    def n_triangles(self) -> float:
        """Estimate of the consistent triples: consistent pairs x the mean number of partners
        consistent with both (over up to EDGE_SAMPLES sampled pairs) / 3."""
        i, j = self.i[:EDGE_SAMPLES], self.j[:EDGE_SAMPLES]
        if len(i) == 0:
            return 0.0
        common = sum(int(both.sum()) for _, both in self._common(i, j, None))
        return self.n_pairs * common / len(i) / 3.0

    def third(
        self, i: np.ndarray, j: np.ndarray, free: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """(n,) int64: per pair (i, j) a random candidate in `free` consistent with both,
        -1 where there is none."""
        out = np.full(len(i), -1, dtype=np.int64)
        for rows, both in self._common(i, j, free):
            keys = np.where(both, rng.random(both.shape, dtype=np.float32), -1.0)
            pick = np.argmax(keys, axis=1)
            out[rows] = np.where(both.any(axis=1), pick, -1)
        return out
