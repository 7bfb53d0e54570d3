"""A pose graph over the robots' keyframes: a node per keyframe (robot, k) with an integer key,
an odometry factor between each robot's consecutive keyframes (`OdometryNoise`), link factors
between keyframes of two robots (or two keyframes of one robot: a loop closure), the root
robot's first keyframe fixed at its odometry pose (the fleet frame is the root's odometry
frame). Solved incrementally (`sgloc.online.keyframes.solve`): only the robots connected to the
root by links are in the solver; a robot enters it when a link first connects it, its
keyframes placed through that link; a link whose removal disconnects robots rebuilds it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sgloc import lie
from sgloc.errors import SglocError
from sgloc.online.config import OdometryNoise
from sgloc.online.keyframes.solve import Factor, make_solver

#: Factor kinds: odometry, accepted links, co-location factors (`keyframes.colocation`; they
#: never connect robots: only links place a robot).
ODOMETRY, LINK, COLOCATION = "odometry", "link", "colocation"


@dataclass(frozen=True)
class GraphFactor:
    """A factor of the graph: kind (ODOMETRY, LINK or COLOCATION), its robots and keyframe indices,
    T_a_b (4,4) the pose of keyframe (robot_b, k_b) in keyframe (robot_a, k_a)'s sensor frame,
    covariance (6,6) [rx ry rz tx ty tz], right perturbation (in (robot_b, k_b)'s frame)."""

    kind: str
    robot_a: int
    k_a: int
    robot_b: int
    k_b: int
    T_a_b: np.ndarray
    covariance: np.ndarray


def keyframe_link(
    T_odom_a: np.ndarray, T_a_b: np.ndarray, covariance: np.ndarray, T_odom_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A robot-level link (T_a_b (4,4): robot b's odometry frame into robot a's, covariance
    (6,6) right perturbation in b's odometry frame) as a relation between two keyframes with
    odometry poses T_odom_a and T_odom_b: (T_ka_kb = inv(T_odom_a) T_a_b T_odom_b, its
    covariance Ad(inv(T_odom_b)) C Ad(inv(T_odom_b))^T)."""
    T = lie.between(T_odom_a, np.asarray(T_a_b, np.float64) @ T_odom_b)
    Ad = lie.adjoint(lie.between(T_odom_b, np.eye(4)))
    C = Ad @ np.asarray(covariance, np.float64) @ Ad.T
    return T, 0.5 * (C + C.T)


def odometry_link(
    T_odom_a: np.ndarray, T_ka_kb: np.ndarray, covariance: np.ndarray, T_odom_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of `keyframe_link`: a keyframe link (T_ka_kb, covariance in keyframe b's
    frame) between keyframes with odometry poses T_odom_a and T_odom_b as a robot-level link
    (T_a_b = T_odom_a T_ka_kb inv(T_odom_b), covariance in b's odometry frame)."""
    T = np.asarray(T_odom_a, np.float64) @ T_ka_kb @ lie.between(T_odom_b, np.eye(4))
    Ad = lie.adjoint(np.asarray(T_odom_b, np.float64))
    C = Ad @ np.asarray(covariance, np.float64) @ Ad.T
    return T, 0.5 * (C + C.T)


class KeyframeGraph:
    """Keyframes of robots (integer ids) and the factors between them; see the module doc.

    noise: the odometry's noise model; solver: "auto", "gtsam" (ISAM2) or "scipy" (the
    sparse Levenberg-Marquardt fallback); root: the robot whose odometry frame is the fleet
    frame. """

    def __init__(self, noise: OdometryNoise | None = None, solver: str = "auto",
                 root: int = 0) -> None:
        self.noise = noise or OdometryNoise()
        self.solver_kind = solver
        self.root = int(root)
        self._odom: dict[int, list[np.ndarray]] = {}
        self._keys: dict[int, list[int]] = {}
        self._n_nodes = 0
        self._factors: dict[int, GraphFactor] = {}
        self._next_fid = 0
        self._reset()

    def _reset(self) -> None:
        self._solver = None
        self._in: list[int] = []  # robots in the solver, in the order they entered
        self._sent: set[int] = set()
        self._est: dict[int, np.ndarray] = {}

    # -- building ------------------------------------------------------------------------------
    def add_keyframe(self, robot: int, T_odom_sensor: np.ndarray) -> int:
        """Add the next keyframe of `robot` (its pose (4,4) in the robot's odometry frame);
        returns its index k. From the second keyframe on, an odometry factor joins it to the
        previous one."""
        T = np.asarray(T_odom_sensor, np.float64).reshape(4, 4).copy()
        odom = self._odom.setdefault(int(robot), [])
        keys = self._keys.setdefault(int(robot), [])
        odom.append(T)
        keys.append(self._n_nodes)
        self._n_nodes += 1
        k = len(odom) - 1
        if k:
            Z = lie.between(odom[k - 1], T)
            self._add(GraphFactor(ODOMETRY, int(robot), k - 1, int(robot), k, Z,
                                  self.noise.covariance(Z)))
        return k

    def add_link(self, robot_a: int, k_a: int, robot_b: int, k_b: int, T_a_b: np.ndarray,
                 covariance: np.ndarray, kind: str = LINK) -> int:
        """Add a link factor: T_a_b (4,4) the pose of keyframe k_b of robot_b in keyframe k_a
        of robot_a, covariance (6,6) ([rx ry rz tx ty tz], right perturbation); kind LINK or
        COLOCATION. Returns the factor's id (for `remove`)."""
        for r, k in ((robot_a, k_a), (robot_b, k_b)):
            if not 0 <= k < len(self._odom.get(int(r), [])):
                raise SglocError(f"link: robot {r} has no keyframe {k}.")
        if int(robot_a) == int(robot_b) and int(k_a) == int(k_b):
            raise SglocError("link: a keyframe cannot be linked to itself.")
        T = np.asarray(T_a_b, np.float64)
        C = np.asarray(covariance, np.float64)
        if T.shape != (4, 4) or C.shape != (6, 6) or not (np.isfinite(T).all()
                                                         and np.isfinite(C).all()):
            raise SglocError("link: T_a_b must be a finite (4,4) and covariance a finite (6,6).")
        if kind not in (LINK, COLOCATION):
            raise SglocError(f"link: kind {kind!r}; use {LINK!r} or {COLOCATION!r}.")
        return self._add(GraphFactor(kind, int(robot_a), int(k_a), int(robot_b), int(k_b),
                                     T.copy(), C.copy()))

    def _add(self, f: GraphFactor) -> int:
        fid = self._next_fid
        self._next_fid += 1
        self._factors[fid] = f
        return fid

    def remove(self, fid: int) -> None:
        """Remove the link or co-location factor `fid` (it leaves the solver at the next
        `solve`)."""
        f = self._factors.get(int(fid))
        if f is None or f.kind not in (LINK, COLOCATION):
            raise SglocError(f"no link factor {fid} in the graph.")
        del self._factors[int(fid)]

    def set_noise(self, noise: OdometryNoise) -> None:
        """Use `noise` for every odometry factor, those in the graph included (the solver
        restarts at `solve`)."""
        self.noise = noise
        odo = [fid for fid, f in self._factors.items() if f.kind == ODOMETRY]
        if odo:  # one batched covariance for every step
            C = noise.covariance(np.stack([self._factors[fid].T_a_b for fid in odo]))
            for fid, c in zip(odo, C, strict=True):
                self._factors[fid] = dataclasses.replace(self._factors[fid], covariance=c)
        self._reset()

    def set_root(self, robot: int) -> None:
        """Make `robot`'s odometry frame the fleet frame (the solver restarts at `solve`)."""
        self.root = int(robot)
        self._reset()

    # -- reading -------------------------------------------------------------------------------
    def node(self, robot: int, k: int) -> int:
        """The integer key of keyframe k of `robot`."""
        return self._keys[int(robot)][int(k)]

    def nodes(self) -> list[tuple[int, int, int]]:
        """(key, robot, k) of every keyframe, by key."""
        out = [(key, r, k) for r, keys in self._keys.items() for k, key in enumerate(keys)]
        return sorted(out)

    def factors(self) -> dict[int, GraphFactor]:
        """{factor id: GraphFactor} of every factor in the graph."""
        return dict(self._factors)

    def keyframes(self, robot: int) -> np.ndarray:
        """(k,4,4) `robot`'s keyframe poses in its odometry frame."""
        return np.array(self._odom.get(int(robot), [])).reshape(-1, 4, 4)

    @property
    def placed(self) -> list[int]:
        """Robots connected to the root by links at the last `solve` (the root first)."""
        return list(self._in)

    def poses(self, robot: int) -> np.ndarray | None:
        """(k,4,4) `robot`'s keyframe poses in the fleet frame as last solved (T_fleet_sensor);
        None when the robot is not placed."""
        if int(robot) not in self._in:
            return None
        new: dict[int, np.ndarray] = {}
        self._chain(int(robot), new)  # keyframes added since: chained by odometry
        return np.stack([self._est.get(key, new.get(key)) for key in self._keys[int(robot)]])

    def T_fleet_odom(self, robot: int) -> np.ndarray | None:
        """(4,4) `robot`'s odometry frame in the fleet frame at its latest solved keyframe
        (X_k @ inv(T_odom_k), map -> odom); None when the robot is not placed."""
        if int(robot) not in self._in:
            return None
        keys = self._keys[int(robot)]
        k = max(i for i, key in enumerate(keys) if key in self._est)
        return self._est[keys[k]] @ lie.between(self._odom[int(robot)][k], np.eye(4))

    # -- state ---------------------------------------------------------------------------------
    def state(self) -> tuple[dict, dict[str, np.ndarray]]:
        """(JSON-ready dict, arrays) that `from_state` restores exactly: keyframes, factors,
        the solved estimate and which robots and factors the solver holds."""
        robots = sorted(self._odom)
        fids = sorted(self._factors)
        f = [self._factors[i] for i in fids]
        est = sorted(self._est)
        meta = {"root": self.root, "solver": self.solver_kind, "next_fid": self._next_fid,
                "robots": robots, "in": self._in, "sent": sorted(self._sent),
                "kinds": [x.kind for x in f]}
        arrays = {
            "kg_odom": np.concatenate([self.keyframes(r) for r in robots]).reshape(-1, 4, 4)
            if robots else np.zeros((0, 4, 4)),
            "kg_count": np.array([len(self._odom[r]) for r in robots], np.int64),
            "kg_keys": np.concatenate([self._keys[r] for r in robots]).astype(np.int64)
            if robots else np.zeros(0, np.int64),
            "kg_fid": np.array(fids, np.int64),
            "kg_ends": np.array([[x.robot_a, x.k_a, x.robot_b, x.k_b] for x in f],
                                np.int64).reshape(-1, 4),
            "kg_T": np.array([x.T_a_b for x in f]).reshape(-1, 4, 4),
            "kg_cov": np.array([x.covariance for x in f]).reshape(-1, 6, 6),
            "kg_est_keys": np.array(est, np.int64),
            "kg_est": np.array([self._est[k] for k in est]).reshape(-1, 4, 4),
        }
        return meta, arrays

    @classmethod
    def from_state(cls, noise: OdometryNoise, meta: dict, arrays: dict[str, np.ndarray]
                   ) -> KeyframeGraph:
        """The graph `state` described, its solver holding the saved estimate."""
        g = cls(noise, meta["solver"], meta["root"])
        start = 0
        for r, n in zip(meta["robots"], arrays["kg_count"], strict=True):
            g._odom[int(r)] = [T.copy() for T in arrays["kg_odom"][start:start + n]]
            g._keys[int(r)] = [int(k) for k in arrays["kg_keys"][start:start + n]]
            start += int(n)
        g._n_nodes = start
        for fid, kind, e, T, C in zip(arrays["kg_fid"], meta["kinds"], arrays["kg_ends"],
                                      arrays["kg_T"], arrays["kg_cov"], strict=True):
            g._factors[int(fid)] = GraphFactor(kind, *(int(x) for x in e), T.copy(), C.copy())
        g._next_fid = int(meta["next_fid"])
        g._in = [int(r) for r in meta["in"]]
        g._est = {int(k): T.copy() for k, T in zip(arrays["kg_est_keys"], arrays["kg_est"],
                                                    strict=True)}
        if g._in:
            g._sent = {int(i) for i in meta["sent"]}
            key0 = g.node(g.root, 0)
            g._solver = make_solver(g.solver_kind, key0, g._est[key0])
            g._solver.restore({k: T for k, T in g._est.items() if k != key0},
                              [g._factor(i) for i in sorted(g._sent)])
        return g

    def _factor(self, fid: int) -> Factor:
        f = self._factors[fid]
        return Factor(fid, self.node(f.robot_a, f.k_a), self.node(f.robot_b, f.k_b), f.T_a_b,
                      f.covariance)

    # -- solving -------------------------------------------------------------------------------
    def _component(self) -> list[int]:
        """Robots connected to the root by link factors, in breadth-first order (links by id)."""
        if self.root not in self._odom:
            return []
        adj: dict[int, list[int]] = {}
        for f in self._factors.values():
            if f.kind == LINK and f.robot_a != f.robot_b:
                adj.setdefault(f.robot_a, []).append(f.robot_b)
                adj.setdefault(f.robot_b, []).append(f.robot_a)
        seen, order = {self.root}, [self.root]
        for r in order:
            for s in adj.get(r, []):
                if s not in seen:
                    seen.add(s)
                    order.append(s)
        return order

    def solve(self) -> None:
        """Bring the solver up to date (new keyframes, links added and removed) and
        re-optimise."""
        comp = self._component()
        if not comp:
            self._reset()
            return
        if self._solver is None or not set(self._in) <= set(comp):
            self._reset()
            T0 = self._odom[self.root][0]
            self._solver = make_solver(self.solver_kind, self.node(self.root, 0), T0)
            self._est = {self.node(self.root, 0): T0.copy()}
            self._in = [self.root]
        new = self._new_poses(comp)
        placed = set(self._in)
        add = [self._factor(fid) for fid, f in sorted(self._factors.items())
               if fid not in self._sent and f.robot_a in placed and f.robot_b in placed]
        gone = sorted(self._sent - set(self._factors))
        if not new and not add and not gone:
            return
        self._solver.update(new, add, gone)
        self._sent = (self._sent - set(gone)) | {f.fid for f in add}
        self._est = self._solver.estimate()

    def _new_poses(self, comp: list[int]) -> dict[int, np.ndarray]:
        """Initial poses of the keyframes new to the solver: a placed robot's new keyframes
        chained by odometry from its last estimate; a newly connected robot's keyframes placed
        through the first link (by id) to a robot placed before it. Extends `self._in`."""
        new: dict[int, np.ndarray] = {}
        for r in self._in:
            self._chain(r, new)
        todo = [r for r in comp if r not in self._in]
        links = [f for _, f in sorted(self._factors.items())
                 if f.kind == LINK and f.robot_a != f.robot_b]
        while todo:
            for f in links:
                for p, kp, q, kq, T in ((f.robot_a, f.k_a, f.robot_b, f.k_b, f.T_a_b),
                                        (f.robot_b, f.k_b, f.robot_a, f.k_a, None)):
                    if p in self._in and q in todo:
                        X_p = new.get(self.node(p, kp), self._est.get(self.node(p, kp)))
                        T_pq = T if T is not None else lie.between(f.T_a_b, np.eye(4))
                        T_fleet_odom = X_p @ T_pq @ lie.between(self._odom[q][kq], np.eye(4))
                        for key, T_o in zip(self._keys[q], self._odom[q], strict=True):
                            new[key] = T_fleet_odom @ T_o
                        self._in.append(q)
                        todo.remove(q)
        return new

    def _chain(self, robot: int, new: dict[int, np.ndarray]) -> None:
        """Initial poses of `robot`'s keyframes that the solver lacks, by odometry from the
        last one it has."""
        keys, odom = self._keys[robot], self._odom[robot]
        for k in range(1, len(keys)):
            if keys[k] not in self._est and keys[k] not in new:
                X = new.get(keys[k - 1], self._est.get(keys[k - 1]))
                new[keys[k]] = X @ lie.between(odom[k - 1], odom[k])


def write_keyframe_g2o(graph: KeyframeGraph, path) -> tuple:
    """Write the placed robots' part of `graph` as a g2o file (`sgloc.io.g2o.write_g2o`): a
    VERTEX_SE3:QUAT per keyframe (id = its key, pose = its corrected T_fleet_sensor), an
    EDGE_SE3:QUAT per odometry factor and per link factor among them. Returns (path, ids)
    with ids = [(key, robot, k)] of the vertices written, to name them."""
    from sgloc.io.g2o import write_g2o

    vertices, ids = {}, []
    for r in graph.placed:
        for k, X in enumerate(graph.poses(r)):
            key = graph.node(r, k)
            vertices[key] = X
            ids.append((key, r, k))
    edges = [(graph.node(f.robot_a, f.k_a), graph.node(f.robot_b, f.k_b), f.T_a_b,
              f.covariance) for _, f in sorted(graph.factors().items())
             if f.robot_a in graph.placed and f.robot_b in graph.placed]
    return write_g2o(path, vertices, edges), sorted(ids)
