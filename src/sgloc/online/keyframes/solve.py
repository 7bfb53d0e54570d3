"""Incremental solvers of a pose graph over keyframes: Pose3 nodes with integer keys, between
factors (T_a_b measured, (6,6) covariance in gtsam Pose3's tangent order [rx ry rz tx ty tz],
right perturbation), one node held fixed. `IsamSolver` runs gtsam's ISAM2; `SparseSolver`
solves the same least-squares problem with Levenberg-Marquardt on scipy.sparse normal
equations, residuals and Jacobians batched over the factors (`sgloc.lie`). Both take changes
with `update(new_poses, new_factors, removed)` and keep the current estimate."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sgloc import lie
from sgloc.geometry import regularized_covariance
from sgloc.optional import require

#: Sigma (rad, m) of the prior that holds the fixed node in ISAM2 (a hard constraint there
#: would need a constrained noise model that its Cholesky factorisation refuses).
FIXED_SIGMA = 1e-6


@dataclass(frozen=True)
class Factor:
    """A between factor: T_a_b ~ inv(X_a) @ X_b, covariance (6,6) of T_a_b ([rx ry rz tx ty
    tz], right perturbation); fid: the caller's id of the factor."""

    fid: int
    a: int
    b: int
    T_a_b: np.ndarray
    covariance: np.ndarray


def make_solver(kind: str, fixed: int, fixed_pose: np.ndarray):
    """A solver of kind "gtsam" (ISAM2), "scipy" (SparseSolver) or "auto" (gtsam when
    installed), holding node `fixed` at `fixed_pose` (4,4)."""
    if kind == "auto":
        kind = "gtsam" if gtsam_available() else "scipy"
    if kind == "gtsam":
        return IsamSolver(fixed, fixed_pose)
    return SparseSolver(fixed, fixed_pose)


class SparseSolver:
    """Levenberg-Marquardt over the whole graph on every update, warm-started from the current
    estimate (a few iterations when little changed); node `fixed` is held at its pose exactly.

    Residual of a factor: r = U @ Log(inv(Z) @ inv(X_a) @ X_b) with U.T @ U = inv(covariance);
    Jacobians for right perturbations of X_a and X_b: -Jr^-1(e) Ad(inv(X_b) X_a) and Jr^-1(e).
    """

    def __init__(self, fixed: int, fixed_pose: np.ndarray, tolerance: float = 1e-10,
                 max_iterations: int = 100) -> None:
        self.fixed = int(fixed)
        self.tolerance, self.max_iterations = float(tolerance), int(max_iterations)
        # Nodes sorted by key and factors by fid, whatever the order they came in: the
        # solution is a function of the graph and the estimate only (a resumed solver continues
        # exactly as the original).
        self._keys = np.array([self.fixed], np.int64)
        self._X = np.asarray(fixed_pose, np.float64).reshape(1, 4, 4).copy()
        self._fid = np.zeros(0, np.int64)
        self._abk = np.zeros((0, 2), np.int64)  # node keys
        self._Zinv = np.zeros((0, 4, 4))
        self._U = np.zeros((0, 6, 6))

    def update(self, new_poses: dict[int, np.ndarray], new_factors: Sequence[Factor] = (),
               removed: Sequence[int] = ()) -> None:
        """Add nodes (initial poses), add factors, remove factors (by fid), re-optimise."""
        self._add_nodes(new_poses)
        if len(removed):
            keep = ~np.isin(self._fid, np.asarray(removed, np.int64))
            self._fid, self._abk = self._fid[keep], self._abk[keep]
            self._Zinv, self._U = self._Zinv[keep], self._U[keep]
        self._add_factors(new_factors)
        self._optimize()

    def _add_nodes(self, poses: dict[int, np.ndarray]) -> None:
        if not poses:
            return
        keys = np.concatenate([self._keys, np.array(sorted(poses), np.int64)])
        X = np.concatenate([self._X, np.stack([np.asarray(poses[k], np.float64)
                                               for k in sorted(poses)])])
        order = np.argsort(keys, kind="stable")
        self._keys, self._X = keys[order], X[order]

    def _add_factors(self, new_factors: Sequence[Factor]) -> None:
        if not len(new_factors):
            return
        f = list(new_factors)
        cov = np.stack([regularized_covariance(x.covariance) for x in f])
        U = np.swapaxes(np.linalg.cholesky(np.linalg.inv(cov)), -1, -2)
        Z = np.stack([np.asarray(x.T_a_b, np.float64) for x in f])
        fid = np.concatenate([self._fid, [x.fid for x in f]]).astype(np.int64)
        order = np.argsort(fid, kind="stable")
        self._fid = fid[order]
        self._abk = np.concatenate([self._abk, [[x.a, x.b] for x in f]])[order]
        self._Zinv = np.concatenate([self._Zinv, lie.between(Z, np.eye(4))])[order]
        self._U = np.concatenate([self._U, U])[order]

    def estimate(self) -> dict[int, np.ndarray]:
        """{key: (4,4) pose} of every node."""
        return {int(k): self._X[i].copy() for i, k in enumerate(self._keys)}

    def restore(self, poses: dict[int, np.ndarray], factors: Sequence[Factor]) -> None:
        """Hold these nodes at exactly these poses and these factors, without optimising (a
        saved solution resumed; the next `update` continues from it as the original would)."""
        self._add_nodes(poses)
        self._add_factors(factors)

    def _linearize(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Whitened residuals (m,6) and Jacobians (m,6,6) w.r.t. X_a and X_b."""
        ab = np.searchsorted(self._keys, self._abk)
        Xa, Xb = X[ab[:, 0]], X[ab[:, 1]]
        e = lie.se3_log(self._Zinv @ lie.between(Xa, Xb))
        Jr = lie.se3_right_jacobian_inv(e)
        Ja = -Jr @ lie.adjoint(lie.between(Xb, Xa))
        r = np.einsum("mij,mj->mi", self._U, e)
        return r, self._U @ Ja, self._U @ Jr

    def _normal_equations(self, r, Ja, Jb):
        """(H, g) over the free nodes' variables (the fixed node's rows and columns left out)."""
        from scipy import sparse

        n = len(self._keys)
        free = self._keys != self.fixed
        var = np.where(free, np.cumsum(free) - 1, -1)  # the fixed node has no variables
        J = np.stack([Ja, Jb], axis=1)  # (m, 2, 6, 6)
        blocks = np.einsum("mpki,mqkj->mpqij", J, J)  # J_p^T J_q
        slots = var[np.searchsorted(self._keys, self._abk)]  # (m, 2)
        base = 6 * slots
        i6 = np.arange(6)
        rows = base[:, :, None, None, None] + i6[None, None, None, :, None]
        cols = base[:, None, :, None, None] + i6[None, None, None, None, :]
        rows, cols = np.broadcast_to(rows, blocks.shape), np.broadcast_to(cols, blocks.shape)
        ok = (slots[:, :, None, None, None] >= 0) & (slots[:, None, :, None, None] >= 0)
        ok = np.broadcast_to(ok, blocks.shape)
        size = 6 * (n - 1)
        H = sparse.coo_array((blocks[ok], (rows[ok], cols[ok])), shape=(size, size)).tocsc()
        gb = np.einsum("mpki,mk->mpi", J, r)  # (m, 2, 6)
        gidx = base[:, :, None] + i6
        gok = np.broadcast_to((slots >= 0)[:, :, None], gb.shape)
        g = np.bincount(gidx[gok], weights=gb[gok], minlength=size)
        return H, g

    def _step(self, X: np.ndarray, dx: np.ndarray) -> np.ndarray:
        out = X.copy()
        free = self._keys != self.fixed
        out[free] = X[free] @ lie.se3_exp(dx.reshape(-1, 6))
        return out

    def _optimize(self) -> None:
        from scipy import sparse
        from scipy.sparse.linalg import spsolve

        if len(self._keys) < 2 or not len(self._fid):
            return
        lam = 1e-6
        r, Ja, Jb = self._linearize(self._X)
        cost = float(np.sum(r * r))
        for _ in range(self.max_iterations):
            H, g = self._normal_equations(r, Ja, Jb)
            d = H.diagonal()
            A = (H + sparse.diags_array(lam * np.maximum(d, 1e-9))).tocsc()
            dx = spsolve(A, -g)
            X_new = self._step(self._X, dx)
            r_new, Ja_new, Jb_new = self._linearize(X_new)
            cost_new = float(np.sum(r_new * r_new))
            if abs(cost_new - cost) <= 1e-12 * cost and np.max(np.abs(dx)) < 1e-6:
                if cost_new <= cost:  # at the optimum: what is left is rounding
                    self._X = X_new
                return
            if cost_new <= cost:
                self._X, r, Ja, Jb = X_new, r_new, Ja_new, Jb_new
                done = np.max(np.abs(dx)) < self.tolerance
                cost, lam = cost_new, max(lam / 10, 1e-12)
                if done:
                    return
            else:
                lam *= 10
                if lam > 1e8:
                    return


class IsamSolver:
    """gtsam's ISAM2: new nodes and factors go in with `update`, removed factors leave by their
    ISAM2 index; after each update ISAM2 is stepped again until the estimate moves by less than
    `tolerance` (at most `max_steps` times), so that it ends at the optimum of the graph."""

    def __init__(self, fixed: int, fixed_pose: np.ndarray, relinearize_threshold: float = 1e-5,
                 tolerance: float = 1e-9, max_steps: int = 20) -> None:
        gtsam = require("gtsam", "gtsam", "the ISAM2 solver")
        self._gtsam = gtsam
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(relinearize_threshold)
        params.relinearizeSkip = 1
        self._isam = gtsam.ISAM2(params)
        self.tolerance, self.max_steps = float(tolerance), int(max_steps)
        self._index: dict[int, int] = {}
        self._pending = gtsam.NonlinearFactorGraph()
        self._pending_values = gtsam.Values()
        pose = gtsam.Pose3(np.asarray(fixed_pose, np.float64))
        self._pending.add(gtsam.PriorFactorPose3(
            int(fixed), pose, gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA)))
        self._pending_values.insert(int(fixed), pose)
        self._prior_pending = True
        self._estimate: dict[int, np.ndarray] = {int(fixed): np.asarray(fixed_pose, float)}

    def update(self, new_poses: dict[int, np.ndarray], new_factors: Sequence[Factor] = (),
               removed: Sequence[int] = ()) -> None:
        """Add nodes (initial poses), add factors, remove factors (by fid), re-optimise."""
        gtsam = self._gtsam
        graph, values = self._pending, self._pending_values
        fids = [-1] if self._prior_pending else []
        for k in sorted(new_poses):
            values.insert(int(k), gtsam.Pose3(np.asarray(new_poses[k], np.float64)))
        for f in new_factors:
            noise = gtsam.noiseModel.Gaussian.Covariance(regularized_covariance(f.covariance))
            graph.add(gtsam.BetweenFactorPose3(int(f.a), int(f.b),
                                               gtsam.Pose3(np.asarray(f.T_a_b, float)), noise))
            fids.append(f.fid)
        gone = [self._index.pop(int(f)) for f in removed]
        result = self._isam.update(graph, values, gone)
        for fid, idx in zip(fids, result.getNewFactorsIndices(), strict=True):
            if fid >= 0:
                self._index[fid] = int(idx)
        self._pending, self._pending_values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self._prior_pending = False
        self._converge()

    def restore(self, poses: dict[int, np.ndarray], factors: Sequence[Factor]) -> None:
        """Start from a saved solution: these nodes at these poses with these factors. ISAM2
        relinearizes from them; `estimate` gives the saved poses until the next `update`."""
        saved = {k: np.asarray(T, np.float64).copy() for k, T in poses.items()}
        fixed = dict(self._estimate)
        self.update(poses, factors)
        self._estimate = {**fixed, **saved}

    def _converge(self) -> None:
        keys, est = self._read()
        for _ in range(self.max_steps):
            self._isam.update()
            keys, new = self._read()
            moved = float(np.abs(new - est).max()) if new.shape == est.shape else np.inf
            est = new
            if moved < self.tolerance:
                break
        self._estimate = dict(zip(keys.tolist(), est, strict=True))

    def _read(self) -> tuple[np.ndarray, np.ndarray]:
        """(keys (n,), poses (n,4,4)) of ISAM2's current estimate, by key."""
        values = self._isam.calculateEstimate()
        rows = self._gtsam.utilities.extractPose3(values)  # (n,12): R row-major, t
        T = np.zeros((len(rows), 4, 4))
        T[:, :3, :3] = rows[:, :9].reshape(-1, 3, 3)
        T[:, :3, 3] = rows[:, 9:]
        T[:, 3, 3] = 1.0
        return np.array(values.keys(), np.int64), T

    def estimate(self) -> dict[int, np.ndarray]:
        """{key: (4,4) pose} of every node."""
        return {k: T.copy() for k, T in self._estimate.items()}


def gtsam_available() -> bool:
    """True when gtsam can be imported."""
    try:
        import gtsam  # noqa: F401
    except ImportError:
        return False
    return True
