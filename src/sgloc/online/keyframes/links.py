"""Which keyframe links the pose graph trusts: a maximum consistent set weighed by evidence.

Links are taken strongest evidence first (most matches, then highest confidence, then oldest).
A link between two robots not yet joined by taken links is taken (it starts no loop); a link
that closes a loop (two robots already joined, or a loop closure within one robot) is taken
only when the loop composes to the identity within what the links and the odometry allow: each
link `tol_m` metres / `tol_deg` degrees (sqrt(n) of that for a loop of n links, as
`consistency.loop_tolerance`), plus 3 standard deviations of the odometry's error
(`OdometryNoise`) over the metres the loop runs along the robots' trajectories. So a cluster of
mutually consistent false links cannot push out a link that more evidence supports: the
better-supported link is taken first and the cluster's links that contradict it are not.
Links once in the set and then out of it are revoked by the caller and stay out (hysteresis).

A link that would join two groups of robots alone must also hold its evidence against the
attempts made between them (`Link.tests`): every attempt between two groups that do not
overlap is a chance for a false alignment, and a fleet of many robots makes thousands. The
acceptance test's NFA (1 / confidence - 1) times the tests must stay within the NFA the
localizer accepts at (`max_nfa`); a weaker link is held: it is taken only to close a loop,
once other links have joined its robots."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sgloc import lie
from sgloc.geometry import rotation_angle_deg
from sgloc.online.config import OdometryNoise
from sgloc.online.loops import loop_tolerance
from sgloc.online.records import Link


def rigid(link: Link, odom_a: np.ndarray, odom_b: np.ndarray) -> np.ndarray:
    """(4,4) robot_b's odometry frame in robot_a's as the keyframe link implies with exact
    odometry: T_odom_a[ka] @ T_a_b @ inv(T_odom_b[kb]) (odom_a, odom_b: (k,4,4) poses)."""
    return odom_a[link.keyframe_a] @ link.T_a_b @ lie.between(odom_b[link.keyframe_b], np.eye(4))


def evidence_order(links: Sequence[Link], ids: Sequence[int]) -> list[int]:
    """`ids` strongest evidence first: most matches, highest confidence, oldest, lowest id."""
    return sorted(ids, key=lambda i: (-links[i].n_matches, -round(links[i].confidence, 6),
                                      links[i].stamp, i))


def join_chance(link: Link) -> float:
    """The NFA of `link` as a join of two groups: (1 / confidence - 1) x its tests."""
    if link.confidence <= 0.0:
        return float("inf")
    return (1.0 / link.confidence - 1.0) * max(link.tests, 1)


class _Forest:
    """Robots joined by taken links: per robot its component and T_component_robot."""

    def __init__(self) -> None:
        self.T: dict[int, np.ndarray] = {}
        self.comp: dict[int, int] = {}
        self.adj: dict[int, list[tuple[int, int]]] = {}  # robot -> (link id, other robot)

    def join(self, a: int, b: int, T_ab: np.ndarray, lid: int) -> None:
        for r in (a, b):
            if r not in self.comp:
                self.comp[r], self.T[r] = r, np.eye(4)
        moved = [r for r, c in self.comp.items() if c == self.comp[b]]
        M = self.T[a] @ T_ab @ lie.between(self.T[b], np.eye(4))
        for r in moved:
            self.comp[r], self.T[r] = self.comp[a], M @ self.T[r]
        self.adj.setdefault(a, []).append((lid, b))
        self.adj.setdefault(b, []).append((lid, a))

    def joined(self, a: int, b: int) -> bool:
        return a == b or (a in self.comp and b in self.comp and self.comp[a] == self.comp[b])

    def path(self, a: int, b: int) -> list[tuple[int, int, int]]:
        """(link id, from robot, to robot) along the forest from a to b."""
        prev: dict[int, tuple[int, int]] = {a: (-1, -1)}
        todo = [a]
        for r in todo:
            for lid, s in self.adj.get(r, []):
                if s not in prev:
                    prev[s] = (lid, r)
                    todo.append(s)
        out, r = [], b
        while r != a:
            lid, p = prev[r]
            out.append((lid, p, r))
            r = p
        return out[::-1]


def _keyframe_on(link: Link, robot: int, index: dict[str, int]) -> int:
    return link.keyframe_a if index[link.robot_a] == robot else link.keyframe_b


def loop_distance(links: Sequence[Link], lid: int, path: list[tuple[int, int, int]],
                  index: dict[str, int], travelled: dict[int, np.ndarray]) -> float:
    """Metres travelled along the robots' trajectories around the loop that link `lid` closes
    with the forest `path` (from its robot_a to its robot_b)."""
    lk = links[lid]
    cur, k = index[lk.robot_a], lk.keyframe_a
    d = 0.0
    for pid, _, to in path:
        k_out = _keyframe_on(links[pid], cur, index)
        d += abs(travelled[cur][k] - travelled[cur][k_out])
        cur, k = to, _keyframe_on(links[pid], to, index)
    return d + abs(travelled[cur][k] - travelled[cur][lk.keyframe_b])


def select_links(
    links: Sequence[Link],
    candidates: Sequence[int],
    index: dict[str, int],
    odom: dict[int, np.ndarray],
    travelled: dict[int, np.ndarray],
    noise: OdometryNoise,
    tol_m: float,
    tol_deg: float,
    max_nfa: float | None = None,
) -> tuple[list[int], dict[int, str]]:
    """(ids taken, {id: why not} for the others) among `candidates` (ids into `links`, each
    with keyframe_a/keyframe_b set); see the module doc. index: robot name -> index; odom,
    travelled: per robot index, its keyframe poses (k,4,4) and metres travelled (k,);
    max_nfa: the NFA a link joining two groups may have, its tests counted (None: no hold)."""
    forest, taken, dropped, held = _Forest(), [], {}, []
    for lid in evidence_order(links, candidates):
        lk = links[lid]
        a, b = index[lk.robot_a], index[lk.robot_b]
        if forest.joined(a, b):
            why = _loop_miss(links, lid, forest, index, odom, travelled, noise, tol_m, tol_deg)
        elif max_nfa is not None and join_chance(lk) > max_nfa:
            held.append(lid)
            continue
        else:
            forest.join(a, b, rigid(lk, odom[a], odom[b]), lid)
            why = None
        if why is None:
            taken.append(lid)
        else:
            dropped[lid] = why
    for lid in held:  # a held link closes a loop once stronger links have joined its robots
        lk = links[lid]
        if forest.joined(index[lk.robot_a], index[lk.robot_b]):
            why = _loop_miss(links, lid, forest, index, odom, travelled, noise, tol_m, tol_deg)
        else:
            why = (f"held: its confidence {lk.confidence:.6f} over the {lk.tests} attempts "
                   f"between its robots' groups could be chance (NFA {join_chance(lk):.2g} > "
                   f"{max_nfa:.2g}); it is taken once other links join its robots")
        if why is None:
            taken.append(lid)
        else:
            dropped[lid] = why
    return sorted(taken), dropped


def _loop_miss(links: Sequence[Link], lid: int, forest: _Forest, index: dict[str, int],
               odom: dict[int, np.ndarray], travelled: dict[int, np.ndarray],
               noise: OdometryNoise, tol_m: float, tol_deg: float) -> str | None:
    """None when link `lid` closes its loop through `forest` within what the links and the
    odometry allow (see the module doc), else why not."""
    lk = links[lid]
    a, b = index[lk.robot_a], index[lk.robot_b]
    path = forest.path(a, b) if a != b else []
    T_pred = lie.between(forest.T[a], forest.T[b]) if a != b else np.eye(4)
    E = lie.between(T_pred, rigid(lk, odom[a], odom[b]))
    p = odom[b][lk.keyframe_b][:3, 3]
    err_m = float(np.linalg.norm(E[:3, :3] @ p + E[:3, 3] - p))
    err_deg = rotation_angle_deg(E[:3, :3])
    dist = loop_distance(links, lid, path, index, travelled)
    st, sr = noise.sigmas(dist)
    lim_m, lim_deg = loop_tolerance(tol_m, tol_deg, len(path) + 1)
    lim_m += 3.0 * float(np.hypot(st, sr * dist / 2))
    lim_deg += 3.0 * float(np.degrees(sr))
    if err_m <= lim_m and err_deg <= lim_deg:
        return None
    return (f"contradicted by better-supported links: its loop of {len(path) + 1} link(s) "
            f"over {dist:.0f} m of travel misses by {err_m:.2f} m / {err_deg:.2f} deg "
            f"(allowed {lim_m:.2f} m / {lim_deg:.2f} deg)")
