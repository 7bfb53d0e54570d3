"""The odometry noise the links show (`OnlineConfig.odometry_scale`).

A user rarely knows how much their odometry drifts; the documented `OdometryNoise` defaults
are a good LiDAR odometry with a margin, which lets the pose graph bend exact odometry to
absorb the links' own errors. The links measure it: two links between the same robots (or a
loop closure and its robot's chain) close a loop whose heading error is the links' errors plus
the odometry's drift between their ends. With e_k the loop's heading error (radians), L_k the
links' heading variance (their covariances) and O_k the odometry's over the stretches (the
noise model as given), e_k ~ N(0, a L_k + s O_k): `fit_scale` finds the maximum-likelihood
(a, s) on a log grid, a the links' calibration and s the odometry's, each with a log-normal
prior at 1 (`PRIOR_SIGMA`); s stays within [MIN_SCALE, 1]: the model as given is the most
the odometry is taken to drift. The graph's odometry factors then use the model's variances
times s (`OdometryNoise.scaled`); the consistency checks keep the model as given.

Heading only: it is what odometry drift shows most plainly, it does not depend on the lever
arm from the loop's origin, and one number per loop keeps the fit cheap."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sgloc import lie
from sgloc.online.keyframes.consistency import Chains, link_ends
from sgloc.online.records import Link

#: The odometry's variance scale stays within [MIN_SCALE, 1] of the model as given.
MIN_SCALE = 0.01
#: Log-normal prior sigma (natural log) on each scale, centred on the model as given.
PRIOR_SIGMA = 2.0
#: Loops needed before the fit moves the scale off 1.
MIN_LOOPS = 5
#: The grid (natural log) the likelihood is evaluated on.
_LOG_GRID = np.linspace(np.log(MIN_SCALE), np.log(100.0), 81)


def heading_loops(links: Sequence[Link], ids: Sequence[int], chains: Chains
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(e, var_link, var_odo) per loop, (m,) each: heading error (rad), the links' heading
    variance and the odometry's (rad^2, the model as given). Loops: each robot pair's links in
    keyframe order, each with the next (a, b and the odometry of both between their ends),
    and each loop closure with its robot's odometry between its ends."""
    if not ids:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    ids = sorted(ids)
    a, ka, b, kb, Z, C = link_ends(links, ids, chains)
    e, var_link, var_odo = [], [], []
    for p, q in sorted({(int(x), int(y)) for x, y in zip(a, b, strict=True)}):
        m = np.flatnonzero((a == p) & (b == q))
        if p == q:
            T, Co = chains.stretch(p, ka[m], kb[m])
            loop = lie.between(Z[m], T)  # the link against the odometry between its ends
            e.append(_yaw(loop))
            var_link.append(C[m, 2, 2])
            var_odo.append(Co[:, 2, 2])
            continue
        m = m[np.lexsort((kb[m], ka[m]))]
        if len(m) < 2:
            continue
        i, j = m[:-1], m[1:]
        Ta, Ca = chains.stretch(p, ka[i], ka[j])
        Tb, Cb = chains.stretch(q, kb[i], kb[j])
        # Z_i . odom_b(kb_i -> kb_j) . inv(Z_j) . inv(odom_a(ka_i -> ka_j)) ~ identity
        loop = Z[i] @ Tb @ lie.between(Z[j], np.eye(4)) @ lie.between(Ta, np.eye(4))
        e.append(_yaw(loop))
        var_link.append(C[i, 2, 2] + C[j, 2, 2])
        var_odo.append(Ca[:, 2, 2] + Cb[:, 2, 2])
    if not e:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    return np.concatenate(e), np.concatenate(var_link), np.concatenate(var_odo)


def _yaw(T: np.ndarray) -> np.ndarray:
    """(m,) the heading (rotation about z, radians) of rotations T (m,4,4)."""
    return np.arctan2(T[:, 1, 0] - T[:, 0, 1], T[:, 0, 0] + T[:, 1, 1])


def fit_scale(e: np.ndarray, var_link: np.ndarray, var_odo: np.ndarray) -> float:
    """The odometry's variance scale s in [MIN_SCALE, 1] (module docstring: var_link = L,
    var_odo = O); 1 with fewer than MIN_LOOPS loops."""
    if len(e) < MIN_LOOPS:
        return 1.0
    g = np.exp(_LOG_GRID)
    s_ok = g <= 1.0 + 1e-12
    var = (g[:, None, None] * var_link[None, None, :]
           + g[None, s_ok, None] * var_odo[None, None, :])
    var = np.maximum(var, 1e-18)
    ll = -0.5 * (np.log(var) + e[None, None, :] ** 2 / var).sum(axis=2)
    prior = -0.5 * (_LOG_GRID[:, None] ** 2 + _LOG_GRID[None, s_ok] ** 2) / PRIOR_SIGMA**2
    _, js = np.unravel_index(int(np.argmax(ll + prior)), ll.shape)
    return min(float(g[s_ok][js]), 1.0)
