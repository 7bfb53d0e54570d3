"""Links that cannot bend odometry: every link is checked against the robots' odometry under
its noise model (`OdometryNoise`) before it enters the keyframe pose graph and after each solve.

*Pairwise consistency* (PCM, Mangelson et al. 2018): two links between robots A and B are
consistent when the loop link_i . odom_B(kb_i -> kb_j) . inv(link_j) . inv(odom_A(ka_i ->
ka_j)) is the identity within its covariance (the two links' and the odometry's over the
metres each robot travelled between the two ends, `OdometryNoise.sigmas`): its squared
Mahalanobis distance is within the chi-square 6-dof 99 % quantile (`CHI2_6DOF_99`). Of each
pair's links only a maximum consistent set, weighed by the links' matches, goes on: the exact
maximum-weight clique for up to `EXACT_CLIQUE` links, a greedy one beyond. A loop closure
within one robot is checked the same way against the robot's own odometry between its ends.

*Bend check*: after each solve, every placed robot's solved trajectory is compared with its
odometry over every stretch between the keyframes where links and co-location factors hold it
(and its first and last keyframe): the solved relative pose against the odometry's, its
squared Mahalanobis distance under the odometry's covariance over the stretch. A stretch
beyond `CHI2_6DOF_99` is bent beyond what the odometry allows: of the links on that robot, the
one with the least evidence among those that absorb the bend (`bent_link`) leaves, the links
are chosen again without it and the graph solved again, until no robot is bent.

`check_links` runs both around the caller's selection and solve."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from sgloc import lie
from sgloc.online.config import OdometryNoise
from sgloc.online.keyframes.links import evidence_order
from sgloc.online.records import Link

#: The chi-square 99 % quantile with 6 degrees of freedom: a 6-dof pose error within it is
#: consistent with its covariance.
CHI2_6DOF_99 = 16.81
#: Up to this many links of one robot pair, the maximum consistent set is found exactly.
EXACT_CLIQUE = 16


@dataclass(frozen=True)
class Chains:
    """The robots' keyframe chains: per robot index its keyframe odometry poses (k,4,4) and
    metres travelled (k,); index: robot name -> index; noise: the odometry's noise model."""

    index: dict[str, int]
    odom: dict[int, np.ndarray]
    travelled: dict[int, np.ndarray]
    noise: OdometryNoise

    def stretch(self, robot: int, k0: np.ndarray, k1: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """(T (m,4,4) keyframe k1 in keyframe k0 by odometry, covariance (m,6,6) of it in k1's
        frame under the noise model over the metres travelled between them)."""
        P = self.odom[robot]
        T = lie.between(P[k0], P[k1])
        d = self.travelled[robot]
        return T, stretch_covariance(self.noise, np.abs(d[k1] - d[k0]))


@dataclass(frozen=True)
class Checked:
    """What `check_links` decided: taken (link ids in the graph, solved), dropped ({id: why}
    by the selection), held ({id: why} by the checks), bent (ids of `held` that the bend
    check took out: they do not come back)."""

    taken: list[int]
    dropped: dict[int, str]
    held: dict[int, str]
    bent: list[int]


def stretch_covariance(noise: OdometryNoise, distance: np.ndarray) -> np.ndarray:
    """(..., 6, 6) diagonal covariance [rx ry rz tx ty tz] of the odometry over stretches of
    `distance` metres (`OdometryNoise.sigmas`)."""
    st, sr = noise.sigmas(distance)
    v = np.stack([sr**2] * 3 + [st**2] * 3, axis=-1)
    return v[..., None] * np.eye(6)


def loop_chi2(Z: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(m,) squared Mahalanobis distances of m loops of n relative poses each, Z (m,n,4,4)
    composed in order (Z_0 Z_1 ... ~ identity), C (m,n,6,6) their covariances (right
    perturbation): Log(loop) under sum_k Ad(inv(Z_k+1 ... Z_n-1)) C_k Ad(...)^T."""
    n = Z.shape[1]
    loop, suffix, S = Z[:, 0], Z[:, n - 1], C[:, n - 1].copy()
    for k in range(1, n):
        loop = loop @ Z[:, k]
    for k in range(n - 2, -1, -1):
        A = lie.adjoint(lie.between(suffix, np.eye(4)))
        S += A @ C[:, k] @ np.swapaxes(A, -1, -2)
        suffix = Z[:, k] @ suffix
    e = lie.se3_log(loop)
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    return np.einsum("mi,mi->m", e, np.linalg.solve(S, e[..., None])[..., 0])


def _inverse(Z: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(inv(Z), its covariance Ad(Z) C Ad(Z)^T), batched."""
    A = lie.adjoint(Z)
    return lie.between(Z, np.eye(4)), A @ C @ np.swapaxes(A, -1, -2)


def link_ends(links: Sequence[Link], ids: Sequence[int], chains: Chains):
    """Per link id (a, ka, b, kb, Z, C), oriented so that a <= b (Z: kb's pose in ka's)."""
    a = np.array([chains.index[links[i].robot_a] for i in ids], np.int64)
    b = np.array([chains.index[links[i].robot_b] for i in ids], np.int64)
    ka = np.array([links[i].keyframe_a for i in ids], np.int64)
    kb = np.array([links[i].keyframe_b for i in ids], np.int64)
    Z = np.array([links[i].T_a_b for i in ids], np.float64).reshape(-1, 4, 4)
    C = np.array([links[i].covariance for i in ids], np.float64).reshape(-1, 6, 6)
    flip = a > b
    if flip.any():
        Zi, Ci = _inverse(Z[flip], C[flip])
        Z[flip], C[flip] = Zi, Ci
        a[flip], b[flip], ka[flip], kb[flip] = b[flip], a[flip], kb[flip], ka[flip]
    return a, ka, b, kb, Z, C


def pair_chi2(a: int, ka_i, kb_i, Z_i, C_i, b: int, ka_j, kb_j, Z_j, C_j, chains: Chains
              ) -> np.ndarray:
    """(m,) the PCM loop statistic of m pairs of links i, j between robots a and b (each its
    keyframes, kb's pose in ka's and its covariance, batched)."""
    O_b, C_ob = chains.stretch(b, kb_i, kb_j)
    O_a, C_oa = chains.stretch(a, ka_i, ka_j)
    Zj_inv, Cj_inv = _inverse(Z_j, C_j)
    Oa_inv, Coa_inv = _inverse(O_a, C_oa)
    Z = np.stack([Z_i, O_b, Zj_inv, Oa_inv], axis=1)
    C = np.stack([C_i, C_ob, Cj_inv, Coa_inv], axis=1)
    return loop_chi2(Z, C)


def max_clique(consistent: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(n,) bool: a maximum-weight set of mutually consistent items (consistent (n,n) bool,
    symmetric; weight (n,) > 0; items in order of preference, the first preferred on ties):
    exact for n <= EXACT_CLIQUE (every subset at once), greedy beyond (heaviest consistent
    neighbourhood first)."""
    n = len(weight)
    ok = consistent | np.eye(n, dtype=bool)
    if ok.all():
        return np.ones(n, bool)
    if n <= EXACT_CLIQUE:
        masks = np.arange(1 << n, dtype=np.int64)
        bits = ((masks[:, None] >> np.arange(n)) & 1).astype(bool)  # (2^n, n)
        adj = (ok * (1 << np.arange(n))).sum(axis=1)  # each item's consistent set, a mask
        clique = np.all(~bits | ((masks[:, None] & ~adj[None, :]) == 0), axis=1)
        w = np.where(clique, bits @ weight, -1.0)
        best = np.flatnonzero(w == w.max())
        # ties: the set holding the most preferred items (lexicographic on the items' order)
        rank = (bits[best] * (1 << np.arange(n)[::-1])).sum(axis=1)
        return bits[best[int(np.argmax(rank))]]
    chosen = np.zeros(n, bool)
    score = ok @ weight
    for i in sorted(range(n), key=lambda i: (-score[i], i)):
        if ok[i, chosen].all():
            chosen[i] = True
    return chosen


def consistent_sets(links: Sequence[Link], ids: Sequence[int], chains: Chains,
                    threshold: float = CHI2_6DOF_99) -> tuple[list[int], dict[int, str]]:
    """(ids kept, {id: why held}): each robot pair's maximum consistent set of its links
    (weighed by matches), loop closures checked against their robot's odometry."""
    ids = sorted(ids)
    if not ids:
        return [], {}
    a, ka, b, kb, Z, C = link_ends(links, ids, chains)
    held: dict[int, str] = {}
    loops = np.flatnonzero(a == b)
    if len(loops):
        Oi, Coi = _inverse(*_stretches(chains, a[loops], ka[loops], kb[loops]))
        chi = loop_chi2(np.stack([Z[loops], Oi], 1), np.stack([C[loops], Coi], 1))
        for k, x in zip(loops, chi, strict=True):
            if not x <= threshold:
                held[ids[k]] = (f"held: the loop closure disagrees with its robot's odometry "
                                f"(chi-square {x:.1f} > {threshold:g})")
    for p, q in sorted({(int(x), int(y)) for x, y in zip(a, b, strict=True) if x != y}):
        m = np.array(sorted(np.flatnonzero((a == p) & (b == q)),
                            key=lambda k: (-links[ids[k]].n_matches, ids[k])), np.int64)
        if len(m) < 2:
            continue
        i, j = np.triu_indices(len(m), 1)
        chi = np.full((len(m), len(m)), np.inf)
        chi[i, j] = chi[j, i] = pair_chi2(p, ka[m[i]], kb[m[i]], Z[m[i]], C[m[i]],
                                          q, ka[m[j]], kb[m[j]], Z[m[j]], C[m[j]], chains)
        w = np.array([max(links[ids[k]].n_matches, 1) for k in m], np.float64)
        keep = max_clique(chi <= threshold, w)
        for r in np.flatnonzero(~keep):
            held[ids[m[r]]] = (
                f"held: inconsistent with {int(keep.sum())} link(s) between its robots with "
                f"{w[keep].sum():.0f} matches (pairwise chi-square {chi[r, keep].min():.1f} > "
                f"{threshold:g} under the links' and the odometry's covariances)")
    return [i for i in ids if i not in held], held


def _stretches(chains: Chains, robots, k0, k1) -> tuple[np.ndarray, np.ndarray]:
    """`Chains.stretch` over several robots, in the order given."""
    T = np.zeros((len(robots), 4, 4))
    C = np.zeros((len(robots), 6, 6))
    for r in sorted(set(robots.tolist())):
        sel = robots == r
        T[sel], C[sel] = chains.stretch(int(r), k0[sel], k1[sel])
    return T, C


def _anchors(graph, placed: list[int]) -> dict[int, np.ndarray]:
    """Per placed robot, the sorted keyframes where link or co-location factors hold it, with
    its first and last keyframe; at most `ANCHORS` of them evenly chosen besides the
    neighbours of each (see `bend_chi2`)."""
    from sgloc.online.keyframes.graph import ODOMETRY

    ends: dict[int, set[int]] = {r: set() for r in placed}
    for f in graph.factors().values():
        if f.kind != ODOMETRY:
            for r, k in ((f.robot_a, f.k_a), (f.robot_b, f.k_b)):
                if r in ends:
                    ends[r].add(k)
    out = {}
    for r in placed:
        n = len(graph.keyframes(r))
        out[r] = np.array(sorted(ends[r] | {0, n - 1}), np.int64)
    return out


#: A link absorbs a bend when its residual chi-square is at least this fraction of the
#: largest of the links on the bent robots (a factor 2 in sigma).
STRAIN = 0.25
#: Stretches checked per robot: between consecutive anchors, and between every two of at most
#: this many anchors evenly spread along the robot's keyframes.
ANCHORS = 16


def bend_chi2(graph, chains: Chains) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(robot, k0, k1, chi-square) of the stretches of the placed robots' solved trajectories
    checked against their odometry: Log(inv(odometry k0->k1) @ solved k0->k1) under the
    odometry's covariance over the stretch (`stretch_covariance`)."""
    rows = []
    for r, ks in _anchors(graph, graph.placed).items():
        if len(ks) < 2:
            continue
        pick = ks[np.unique(np.linspace(0, len(ks) - 1, min(len(ks), ANCHORS)).round()
                            .astype(np.int64))]
        i, j = np.triu_indices(len(pick), 1)
        k0 = np.concatenate([ks[:-1], pick[i]])
        k1 = np.concatenate([ks[1:], pick[j]])
        pairs = np.unique(np.stack([k0, k1], 1), axis=0)
        X = graph.poses(r)
        odo, Co = chains.stretch(r, pairs[:, 0], pairs[:, 1])
        e = lie.se3_log(lie.between(odo, lie.between(X[pairs[:, 0]], X[pairs[:, 1]])))
        chi = np.einsum("mi,mi->m", e, np.linalg.solve(Co, e[..., None])[..., 0])
        rows.append((np.full(len(pairs), r), pairs[:, 0], pairs[:, 1], chi))
    if not rows:
        z = np.zeros(0, np.int64)
        return z, z, z, np.zeros(0)
    return tuple(np.concatenate(c) for c in zip(*rows, strict=True))


def link_chi2(graph, links: Sequence[Link], ids: Sequence[int], chains: Chains) -> np.ndarray:
    """(m,) each link's whitened squared residual in the solved graph."""
    poses = {r: graph.poses(r) for r in graph.placed}
    Xa = np.array([poses[chains.index[links[i].robot_a]][links[i].keyframe_a] for i in ids])
    Xb = np.array([poses[chains.index[links[i].robot_b]][links[i].keyframe_b] for i in ids])
    Z = np.array([links[i].T_a_b for i in ids])
    C = np.array([links[i].covariance for i in ids])
    e = lie.se3_log(lie.between(Z, lie.between(Xa, Xb)))
    return np.einsum("mi,mi->m", e, np.linalg.solve(C, e[..., None])[..., 0])


def bent_link(graph, links: Sequence[Link], taken: Sequence[int], chains: Chains,
              threshold: float = CHI2_6DOF_99) -> tuple[int, str] | None:
    """(link id, why) of the link to take out when the solved `graph` bends a robot's
    odometry beyond `threshold` (`bend_chi2`): of the taken links with an end on a bent
    robot, those that absorb the bend (whitened residual within `STRAIN` of the largest),
    the one with the least evidence (`keyframes.links.evidence_order`): where one loop alone
    disagrees, every link on it absorbs a like share and only the evidence tells them apart;
    where more loops hold the robot, a false link's residual stands out alone. None when no
    robot is bent."""
    robot, k0, k1, chi = bend_chi2(graph, chains)
    bad = chi > threshold
    if not bad.any():
        return None
    bent = set(robot[bad].tolist())
    on = [i for i in taken if chains.index[links[i].robot_a] in bent
          or chains.index[links[i].robot_b] in bent]
    if not on:
        return None
    res = link_chi2(graph, links, on, chains)
    strained = [i for i, x in zip(on, res, strict=True) if x >= STRAIN * res.max()]
    lid = evidence_order(links, strained)[-1]
    k = on.index(lid)
    names = {v: n for n, v in chains.index.items()}
    w = int(np.argmax(np.where(bad, chi, -np.inf)))
    d = chains.travelled[int(robot[w])]
    return lid, (f"bent odometry: with it the solution bends robot {names[int(robot[w])]!r}'s "
                 f"odometry between its keyframes {int(k0[w])} and {int(k1[w])} "
                 f"({abs(d[k1[w]] - d[k0[w]]):.0f} m) beyond its noise (chi-square "
                 f"{chi[w]:.1f} > {threshold:g}); of the links that absorb it (residual "
                 f"chi-square {res[k]:.1f}, the most {res.max():.1f}) it has the least "
                 "evidence")


def check_links(links: Sequence[Link], candidates: Sequence[int], chains: Chains,
                select: Callable[[list[int]], tuple[list[int], dict[int, str]]],
                solve: Callable[[list[int]], object],
                threshold: float = CHI2_6DOF_99, enabled: bool = True) -> Checked:
    """The links that enter the pose graph: `candidates` (ids into `links`) through the
    pairwise consistency check (`consistent_sets`), then `select` (ids -> (taken, {id: why
    not})), then `solve` (taken ids -> the graph holding exactly them, solved) and the bend
    check (`bent_link`), a bending link out and the selection and solve again, until no
    robot is bent. Returns the `Checked` verdicts; the graph is left solved on `taken`.
    enabled False: the selection and solve alone (`OnlineConfig.link_checks` off)."""
    if not enabled:
        taken, dropped = select(list(candidates))
        solve(taken)
        return Checked(taken, dropped, {}, [])
    kept, held = consistent_sets(links, candidates, chains, threshold)
    bent: list[int] = []
    while True:
        taken, dropped = select([i for i in kept if i not in bent])
        hit = bent_link(solve(taken), links, taken, chains, threshold)
        if hit is None:
            return Checked(taken, dropped, held, bent)
        bent.append(hit[0])
        held[hit[0]] = hit[1]
