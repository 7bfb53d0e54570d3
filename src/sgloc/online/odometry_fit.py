"""The odometry's noise fitted to what the links show (`OdometryNoise.fit`).

Two links between the same two robots, or a loop closure within one robot, close a loop
through the robots' odometry: its error e is the links' errors plus the odometry's drift over
the stretches between the links' ends. Its covariance is S(s) = S_links + S_floor + s S_drift,
where S_drift is the drift part of the noise model as given (the per-metre and per-sqrt-metre
terms) and s the factor the data sets on its variance. `variance_factor` picks, among the
factors of `FACTORS` (powers of two: a session changes its graph's noise rarely, and only by
steps that matter), the one of least negative log-likelihood of the loops of the links in the
graph, sum_loops [e' S(s)^-1 e + log det S(s)] / (links of the pair - 1), plus the prior
(log2 s)^2 / (2 PRIOR_LOG2^2) that keeps the model as given when few loops are seen.

With exact odometry every loop's error is the links' own and s falls to the smallest factor:
the graph keeps the odometry as it is; with drifting odometry s follows the drift the loops
show. The checks of `keyframe_consistency` keep the model as given, so that a fitted model
never makes the gate that chose the loops narrower.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from sgloc.online.config import OdometryNoise
from sgloc.online.keyframe_consistency import Chains, closure_loop, link_ends, pair_loop
from sgloc.online.records import Link

#: The variance factors a fit chooses among.
FACTORS = 2.0 ** np.arange(-8, 3)
#: The prior's spread, in powers of two of the variance factor.
PRIOR_LOG2 = 2.0
#: At most this many links of one robot pair take part (evenly spread over its links).
MAX_LINKS = 32


def scaled(noise: OdometryNoise, factor: float) -> OdometryNoise:
    """`noise` with its drift terms' variances times `factor` (the floors kept)."""
    r = float(np.sqrt(factor))
    return replace(noise, translation_per_metre=noise.translation_per_metre * r,
                   rotation_per_metre=noise.rotation_per_metre * r,
                   rotation_per_sqrt_metre=noise.rotation_per_sqrt_metre * r)


def variance_factor(links: Sequence[Link], ids: Sequence[int], chains: Chains) -> float:
    """The factor of `FACTORS` on the drift terms' variances of `chains.noise` that the loops
    of the links `ids` fit best (module doc); 1.0 when they close no loop."""
    e, S_fixed, S_drift, w = loops(links, ids, chains)
    if not len(e):
        return 1.0
    nll = np.array([_nll(e, S_fixed + s * S_drift, w) for s in FACTORS])
    nll += np.log2(FACTORS) ** 2 / (2 * PRIOR_LOG2**2)
    return float(FACTORS[int(np.argmin(nll))])


def _nll(e: np.ndarray, S: np.ndarray, w: np.ndarray) -> float:
    chi = np.einsum("mi,mi->m", e, np.linalg.solve(S, e[..., None])[..., 0])
    return float(w @ (chi + np.linalg.slogdet(S)[1]))


def loops(links: Sequence[Link], ids: Sequence[int], chains: Chains
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(e (m,6), S_fixed (m,6,6): the part of its covariance the links and the odometry's
    floors give, S_drift (m,6,6): the part the odometry's drift terms give, w (m,): each
    loop's weight) of the loops the links `ids` close: every two links of one robot pair (at
    most `MAX_LINKS` of them, each two weighing 1 / (links - 1) together: each link counts
    about once), every loop closure with its robot's odometry (weight 1)."""
    rows = []
    if ids:
        ids = sorted(ids)
        ends = link_ends(links, ids, chains)
        floor = replace(chains, noise=replace(
            chains.noise, translation_per_metre=0.0, rotation_per_metre=0.0,
            rotation_per_sqrt_metre=0.0))
        a, b = ends[0], ends[2]
        for p, q in sorted({(int(x), int(y)) for x, y in zip(a, b, strict=True)}):
            m = np.flatnonzero((a == p) & (b == q))
            if p != q and len(m) < 2:
                continue
            if p != q:
                m = m[np.unique(np.linspace(0, len(m) - 1, min(len(m), MAX_LINKS)).round()
                                .astype(np.int64))]
            (e, S_all), (_, S_fixed) = (_pair_loops(ends, m, p == q, c) for c in (chains, floor))
            w = np.full(len(e), 1.0 if p == q else 1.0 / (len(m) - 1))
            rows.append((e, S_fixed, S_all - S_fixed, w))
    if not rows:
        z = np.zeros((0, 6, 6))
        return np.zeros((0, 6)), z, z, np.zeros(0)
    return tuple(np.concatenate(c) for c in zip(*rows, strict=True))


def _pair_loops(ends, m: np.ndarray, closures: bool, chains: Chains
                ) -> tuple[np.ndarray, np.ndarray]:
    """(e, S) of the loops of the links m (indices into `ends` of `link_ends`): loop
    closures each on its own, or every two links of one robot pair."""
    a, ka, b, kb, Z, C = ends
    if closures:
        return closure_loop(a[m], ka[m], kb[m], Z[m], C[m], chains)
    i, j = (m[x] for x in np.triu_indices(len(m), 1))
    return pair_loop(int(a[m[0]]), ka[i], kb[i], Z[i], C[i], int(b[m[0]]), ka[j], kb[j], Z[j],
                     C[j], chains)
