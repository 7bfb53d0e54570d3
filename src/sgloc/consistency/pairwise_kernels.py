"""Pairwise consistency of two match sets in one pass, as bit-packed rows (numba).

Each row is first decided in float32 on centred coordinates (16 lanes per vector); the few pairs
within a rigorous rounding band of the threshold are then decided again in float64 from the
original coordinates, so the result equals the dense float64 computation exactly.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sgloc.kernels import watch_compiles
from sgloc.kernels.bits import WORD
from sgloc.kernels.dispatch import kernel

#: Bound, relative to (R_src + R_dst + tau) with R the largest norm of a centred point set, on
#: the float32 error of a distance difference: each coordinate, difference, square, sum and
#: square root rounds once (a few units of 2^-24 times R per distance); 64 units for margin.
_BAND = 64.0 * float(np.finfo(np.float32).eps)


@njit(cache=True, nogil=True, inline="always")
def _exact(p: np.ndarray, i: int, j: int) -> float:
    """Float64 |p_i - p_j|, summed in scipy cdist's order."""
    dx, dy, dz = p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@kernel
def _columns32(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Centred float32 x, y, z columns and the largest centred norm (float64)."""
    m = p.shape[0]
    c = np.zeros(3)
    for i in range(m):
        c += p[i]
    c /= max(m, 1)
    x, y, z = np.empty(m, np.float32), np.empty(m, np.float32), np.empty(m, np.float32)
    R = 0.0
    for i in range(m):
        a, b, d = p[i, 0] - c[0], p[i, 1] - c[1], p[i, 2] - c[2]
        x[i], y[i], z[i] = a, b, d
        R = max(R, np.sqrt(a * a + b * b + d * d))
    return x, y, z, R


@kernel
def consistency_bits(
    src: np.ndarray, dst: np.ndarray, tau: float, neighbor: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Consistency of every pair of matches, src/dst (m,3) float64 in metres.

    Returns (bits, degree): bits (m, ceil(m/64)) uint64, bit j % 64 of word j // 64 of row i set
    when matches i != j are consistent (symmetric, diagonal clear); degree (m,) int64 row counts.
    Decisions equal those on float64 distances sqrt(dx*dx + dy*dy + dz*dz) (scipy's cdist).
    neighbor=False: |D(q_i,q_j) - D(t_i,t_j)| < tau (Alg. 1);
    neighbor=True: (D(q_i,q_j) < tau) == (D(t_i,t_j) < tau) (Eq. 2-3).
    """
    m = src.shape[0]
    n_words = (m + WORD - 1) // WORD
    sx, sy, sz, Rs = _columns32(src)
    tx, ty, tz, Rt = _columns32(dst)
    band = np.float32(_BAND * (Rs + Rt + tau) + 1e-6)
    tau32 = np.float32(tau)
    bits = np.zeros((m, n_words), dtype=np.uint64)  # pairs (i, j > i) first, then mirrored
    degree = np.zeros(m, dtype=np.int64)
    ok = np.zeros(m, dtype=np.int32)
    amb = np.zeros(m, dtype=np.int32)
    for i in range(m):
        ax, ay, az = sx[i], sy[i], sz[i]
        bx, by, bz = tx[i], ty[i], tz[i]
        # (Loops run k from 0 so that LLVM sees non-negative indices: no wrap-around masks,
        # plain vector loads instead of gathers.)
        for k in range(m - i - 1):  # branch-free float32: vectorised
            j = i + 1 + k
            dx, dy, dz = ax - sx[j], ay - sy[j], az - sz[j]
            ds = np.sqrt(dx * dx + dy * dy + dz * dz)
            ex, ey, ez = bx - tx[j], by - ty[j], bz - tz[j]
            dt = np.sqrt(ex * ex + ey * ey + ez * ez)
            if neighbor:
                ok[j] = (ds < tau32) == (dt < tau32)
                amb[j] = (abs(ds - tau32) < band) | (abs(dt - tau32) < band)
            else:
                diff = abs(ds - dt)
                ok[j] = diff < tau32
                amb[j] = abs(diff - tau32) < band
        n_amb = 0
        for k in range(m - i - 1):
            n_amb += amb[i + 1 + k]
        if n_amb:  # rare: decide these pairs in float64
            for j in range(i + 1, m):
                if amb[j]:
                    es, et = _exact(src, i, j), _exact(dst, i, j)
                    ok[j] = ((es < tau) == (et < tau)) if neighbor else (abs(es - et) < tau)
        count = 0
        for k in range(m - i - 1):
            c = np.int64(ok[i + 1 + k])
            degree[i + 1 + k] += c
            count += c
        degree[i] += count
        for w in range((i + 1) // WORD, n_words):  # pack ok[i+1:] into row i
            lo, hi = max(w * WORD, i + 1), min((w + 1) * WORD, m)
            acc = np.uint64(0)
            for k in range(hi - lo):
                acc |= np.uint64(ok[lo + k]) << np.uint64(lo + k - w * WORD)
            bits[i, w] = acc
    _mirror(bits, m)
    return bits, degree


@kernel(writes=("bits",))
def _mirror(bits: np.ndarray, m: int) -> None:
    """Complete the strictly upper triangle of packed rows into the symmetric matrix, one 64 x 64
    block at a time (bit transposes): no second m^2 / 8 buffer. A diagonal block holds only
    bits above its diagonal, so its transpose ORs in exactly the part below."""
    n_words = bits.shape[1]
    a = np.empty(WORD, dtype=np.uint64)
    for I in range(n_words):  # noqa: E741 (block row, block column)
        for J in range(I, n_words):
            for r in range(WORD):
                row = I * WORD + r
                a[r] = bits[row, J] if row < m else np.uint64(0)
            _transpose64(a)
            for c in range(WORD):
                row = J * WORD + c
                if row < m:
                    bits[row, I] |= a[c]


@njit(cache=True, nogil=True, inline="always")
def _transpose64(a: np.ndarray) -> None:
    """In place: bit c of a[r] <-> bit r of a[c] (a 64 x 64 bit matrix, row r = a[r])."""
    j = 32
    mask = np.uint64(0x00000000FFFFFFFF)
    while j:
        sj = np.uint64(j)
        for k in range(WORD):
            if (k & j) == 0:
                t = ((a[k] >> sj) ^ a[k | j]) & mask
                a[k] ^= t << sj
                a[k | j] ^= t
        j >>= 1
        mask ^= mask << np.uint64(j)


watch_compiles()  # an install's first compile is said (sgloc.kernels)
