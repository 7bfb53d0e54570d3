"""SO(3) and SE(3): the one place for skew matrices, exponential and logarithm maps (also the
SO(3) x R^3 chart and rotations about one axis), adjoints.

Conventions (gtsam's `Pose3`): a tangent vector is xi = [rx, ry, rz, tx, ty, tz] (rad, m),
rotation first; a perturbation is on the right, T_true = T @ Exp(xi), xi in T's source frame.
Transforms are (4,4) float64 arrays, T_to_from, p_to = R @ p_from + t. Every function takes
a single element or a stack (leading axes) and returns the same leading shape.
"""

from __future__ import annotations

import numpy as np

#: Below this rotation angle (rad) the closed forms switch to their Taylor series.
SMALL_ANGLE = 1e-8


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices [v]x of vectors v (..., 3): [v]x @ u = v x u."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _series(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """a = sin(t)/t, b = (1 - cos t)/t^2, c = (t - sin t)/t^3, Taylor-expanded near 0."""
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(t) / t)
    b = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - np.cos(t)) / t**2)
    c = np.where(small, 1 / 6 - t2 / 120 + t2 * t2 / 5040, (t - np.sin(t)) / t**3)
    return a, b, c


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation Exp(omega) of rotation vectors omega (..., 3), rad (Rodrigues)."""
    omega = np.asarray(omega, dtype=np.float64)
    theta = np.linalg.norm(omega, axis=-1)
    a, b, _ = _series(theta)
    K = skew(omega)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def axis_rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations by `angle` (...,) rad about one `axis` (3,), normalised here:
    Rodrigues, I + sin(a) [u]x + (1 - cos a) [u]x^2 (no small-angle series: a = 0 is exact)."""
    u = np.asarray(axis, dtype=np.float64)
    K = skew(u / np.linalg.norm(u))
    angle = np.asarray(angle, dtype=np.float64)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors (rad) of rotation matrices R (..., 3, 3); angle in [0, pi]."""
    from scipy.spatial.transform import Rotation  # robust near pi

    R = np.asarray(R, dtype=np.float64)
    flat = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec()
    return flat.reshape(*R.shape[:-2], 3)


def left_jacobian(omega: np.ndarray) -> np.ndarray:
    """(..., 3, 3) SO(3) left Jacobian V(omega): the translation of Exp([omega, v]) is V @ v."""
    omega = np.asarray(omega, dtype=np.float64)
    _, b, c = _series(np.linalg.norm(omega, axis=-1))
    K = skew(omega)
    return np.eye(3) + b[..., None, None] * K + c[..., None, None] * (K @ K)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """(..., 4, 4) Exp(xi) of xi (..., 6) = [rx ry rz tx ty tz] (as gtsam.Pose3.Expmap)."""
    xi = np.asarray(xi, dtype=np.float64)
    T = np.zeros((*xi.shape[:-1], 4, 4))
    T[..., :3, :3] = so3_exp(xi[..., :3])
    T[..., :3, 3] = np.einsum("...ij,...j->...i", left_jacobian(xi[..., :3]), xi[..., 3:])
    T[..., 3, 3] = 1.0
    return T


def se3_log(T: np.ndarray) -> np.ndarray:
    """(..., 6) xi = Log(T) of transforms T (..., 4, 4) (as gtsam.Pose3.Logmap)."""
    T = np.asarray(T, dtype=np.float64)
    omega = so3_log(T[..., :3, :3])
    v = np.linalg.solve(left_jacobian(omega), T[..., :3, 3][..., None])[..., 0]
    return np.concatenate([omega, v], axis=-1)


def product_exp(delta: np.ndarray) -> np.ndarray:
    """(..., 4, 4) the SO(3) x R^3 chart of delta (..., 6) = [rx ry rz tx ty tz]: rotation
    Exp(r) and translation t apart (not SE(3)'s Exp, whose translation is V(r) t)."""
    delta = np.asarray(delta, dtype=np.float64)
    T = np.zeros((*delta.shape[:-1], 4, 4))
    T[..., :3, :3] = so3_exp(delta[..., :3])
    T[..., :3, 3] = delta[..., 3:]
    T[..., 3, 3] = 1.0
    return T


def product_log(T: np.ndarray) -> np.ndarray:
    """(..., 6) the inverse of `product_exp`: [Log(R), t] of transforms T (..., 4, 4)."""
    T = np.asarray(T, dtype=np.float64)
    return np.concatenate([so3_log(T[..., :3, :3]), T[..., :3, 3]], axis=-1)


def retract(T: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(..., 4, 4) T moved by delta (..., 6) on its right: T @ Exp(delta), gtsam Pose3.retract."""
    return np.asarray(T, dtype=np.float64) @ se3_exp(delta)


def adjoint(T: np.ndarray) -> np.ndarray:
    """(..., 6, 6) adjoint of T in [rotation, translation] order: T Exp(xi) = Exp(Ad_T xi) T."""
    T = np.asarray(T, dtype=np.float64)
    R, t = T[..., :3, :3], T[..., :3, 3]
    A = np.zeros((*T.shape[:-2], 6, 6))
    A[..., :3, :3] = R
    A[..., 3:, 3:] = R
    A[..., 3:, :3] = skew(t) @ R
    return A


def compose(*transforms: np.ndarray) -> np.ndarray:
    """The product T1 @ T2 @ ... of (..., 4, 4) transforms (broadcast over leading axes)."""
    out = np.asarray(transforms[0], dtype=np.float64)
    for T in transforms[1:]:
        out = out @ np.asarray(T, dtype=np.float64)
    return out


def between(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """(..., 4, 4) inv(T_a) @ T_b without a general inverse (the relative pose of b in a)."""
    T_a = np.asarray(T_a, dtype=np.float64)
    T_b = np.asarray(T_b, dtype=np.float64)
    Rt = np.swapaxes(T_a[..., :3, :3], -1, -2)
    out = np.zeros(np.broadcast_shapes(T_a.shape, T_b.shape))
    out[..., :3, :3] = Rt @ T_b[..., :3, :3]
    out[..., :3, 3] = np.einsum("...ij,...j->...i", Rt, T_b[..., :3, 3] - T_a[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def se3_ad(xi: np.ndarray) -> np.ndarray:
    """(..., 6, 6) small adjoint ad(xi) of xi (..., 6) = [rx ry rz tx ty tz]: the matrix of the
    Lie bracket, ad(xi) @ eta = [xi, eta] ([[w]x, 0], [[v]x, [w]x] in this order)."""
    xi = np.asarray(xi, dtype=np.float64)
    W, V = skew(xi[..., :3]), skew(xi[..., 3:])
    out = np.zeros((*xi.shape[:-1], 6, 6))
    out[..., :3, :3] = W
    out[..., 3:, 3:] = W
    out[..., 3:, :3] = V
    return out


def se3_right_jacobian_inv(xi: np.ndarray) -> np.ndarray:
    """(..., 6, 6) inverse right Jacobian of SE(3) at xi (..., 6), by its series
    I + ad/2 + ad^2/12 - ad^4/720 + ad^6/30240 (Bernoulli numbers; relative error ~|xi|^8 /
    1.2e6): Log(Exp(xi) Exp(d)) ~= xi + J d. Meant for the small residuals of a pose graph's
    between factors (rotations well below pi)."""
    ad = se3_ad(xi)
    ad2 = ad @ ad
    ad4 = ad2 @ ad2
    return np.eye(6) + 0.5 * ad + ad2 / 12.0 - ad4 / 720.0 + (ad4 @ ad2) / 30240.0
