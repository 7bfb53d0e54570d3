"""Per-query top-k of same-class cosine similarities in one pass (numba).

The compiled `sgloc.matching.candidates._top_k` for dense descriptors: no similarity block leaves
the kernel, only the kept candidates. Classes are walked on label-sorted index lists, so any class
ids work; a class's target descriptors are normalised into one transposed buffer, and each
query row's similarities are accumulated feature by feature over it (vectorised across the
targets, four features per pass; zero features skipped). Similarities equal the numpy blocks'
to rounding (the sum over features runs in order, as BLAS's does, without fused multiply-adds).
"""

from __future__ import annotations

import numpy as np

from sgloc.kernels import watch_compiles
from sgloc.kernels.dispatch import kernel


@kernel
def inverse_norms(D: np.ndarray) -> np.ndarray:
    """1 / the Euclidean norm of each row of D (n,d), 0 for an all-zero row; the squares summed
    in order, four rows at a time (independent sums: no wait on one long chain)."""
    n, d = D.shape
    out = np.zeros(n)
    for i0 in range(0, n, 4):
        s0 = s1 = s2 = s3 = 0.0
        i1, i2, i3 = min(i0 + 1, n - 1), min(i0 + 2, n - 1), min(i0 + 3, n - 1)
        for f in range(d):
            a, b, c, e = D[i0, f], D[i1, f], D[i2, f], D[i3, f]
            s0 += a * a
            s1 += b * b
            s2 += c * c
            s3 += e * e
        sums = (s0, s1, s2, s3)
        for r in range(min(4, n - i0)):
            if sums[r] > 0:
                out[i0 + r] = 1.0 / np.sqrt(sums[r])
    return out


@kernel(writes=("sim",))
def _similarities(
    sim: np.ndarray, blocks: np.ndarray, base: int, stride: int, x: np.ndarray, nz: np.ndarray
) -> None:
    """sim[j] = sum over the features f in nz (ascending) of x[f] * blocks[base + f * stride
    + j], added in that order (the rows of a C-ordered (d, stride) buffer, or a run of
    len(sim) columns of it); four features per pass over sim (one load and store of sim[j]
    per four terms)."""
    sim[:] = 0.0
    n = stride
    p = 0
    while p + 4 <= nz.shape[0]:
        f0, f1, f2, f3 = nz[p], nz[p + 1], nz[p + 2], nz[p + 3]
        x0, x1, x2, x3 = x[f0], x[f1], x[f2], x[f3]
        r0, r1 = blocks[base + f0 * n :], blocks[base + f1 * n :]
        r2, r3 = blocks[base + f2 * n :], blocks[base + f3 * n :]
        for j in range(sim.shape[0]):
            acc = sim[j]
            acc += x0 * r0[j]
            acc += x1 * r1[j]
            acc += x2 * r2[j]
            acc += x3 * r3[j]
            sim[j] = acc
        p += 4
    while p < nz.shape[0]:
        f0 = nz[p]
        x0, r0 = x[f0], blocks[base + f0 * n :]
        for j in range(sim.shape[0]):
            sim[j] += x0 * r0[j]
        p += 1


@kernel
def _unit_rows(Q: np.ndarray, rows: np.ndarray, inv_q: np.ndarray):
    """(X, nz, n_nz): the rows `rows` of Q (n_q,d) times their inverse norms `inv_q` (n_q,),
    and per row its non-zero features ascending (nz[r, :n_nz[r]])."""
    d = Q.shape[1]
    X = np.empty((rows.shape[0], d))
    nz = np.empty((rows.shape[0], d), dtype=np.int64)
    n_nz = np.zeros(rows.shape[0], dtype=np.int64)
    for r in range(rows.shape[0]):
        i, m = rows[r], 0
        for f in range(d):
            X[r, f] = Q[i, f] * inv_q[i]
            nz[r, m] = f
            m += X[r, f] != 0.0
        n_nz[r] = m
    return X, nz, n_nz


@kernel(writes=("x", "nz"))
def _unit_row(Q: np.ndarray, i: int, w: float, x: np.ndarray, nz: np.ndarray) -> int:
    """One row of `_unit_rows` into reused buffers: x = Q[i] * w, nz[:n] its non-zero
    features ascending; returns n."""
    m = 0
    for f in range(Q.shape[1]):
        x[f] = Q[i, f] * w
        nz[m] = f
        m += x[f] != 0.0
    return m


@kernel(writes=("best_s", "best_j", "out_j", "out_s", "out_n", "out_f"))
def _rank(i, sim, it, kk, best_s, best_j, test_ratio, min_sim, max_ratio, flag_ratio,
          out_j, out_s, out_n, out_f) -> None:  # fmt: skip
    """Query row i's kept candidates among the similarities `sim` (n_t,) to the class's
    targets `it` (`top_k_same_class`: top kk, the ratio tests, min_sim), into out_*."""
    n_t = sim.shape[0]
    s1, s2, j1 = -np.inf, -np.inf, 0
    for j in range(n_t):
        s = sim[j]
        if s > s1:
            s1, s2, j1 = s, s1, j
        elif s > s2:
            s2 = s
    if kk == 1:
        best_s[0], best_j[0] = s1, j1
    else:
        n = np.int64(0)  # one specialisation of _insert, not two
        for j in range(n_t):
            n = _insert(best_s[:kk], best_j[:kk], n, sim[j], j)
    if test_ratio and n_t > 1:
        if not np.isnan(max_ratio) and not (1.0 - s1) <= max_ratio * (1.0 - s2):
            return
        if not np.isnan(flag_ratio):
            out_f[i] = (1.0 - s1) <= flag_ratio * (1.0 - s2)
    m = 0
    for h in range(kk):
        if best_s[h] >= min_sim and best_s[h] > 0:
            out_j[i, m], out_s[i, m] = it[best_j[h]], best_s[h]
            m += 1
    out_n[i] = m


#: The exhaustive search scores the query rows of a class against its targets in tiles of
#: this many targets (a tile's descriptor rows, d x _TILE floats, stay in cache while every
#: query row of the class is scored on them), ...
_TILE = 256
#: ... holding at most this many similarities (query rows x class targets) at once.
_HELD = 1 << 18


@kernel(writes=("best_s", "best_j"))
def _insert(best_s: np.ndarray, best_j: np.ndarray, n: int, s: float, j: int) -> int:
    """Insert (s, j) into the n entries of best_* kept sorted by score descending, then target
    ascending, at most len(best_s) entries; returns the new count."""
    kk = best_s.shape[0]
    if n == kk and not (s > best_s[n - 1] or (s == best_s[n - 1] and j < best_j[n - 1])):
        return n
    pos = min(n, kk - 1)
    while pos > 0 and (s > best_s[pos - 1] or (s == best_s[pos - 1] and j < best_j[pos - 1])):
        if pos < kk:
            best_s[pos], best_j[pos] = best_s[pos - 1], best_j[pos - 1]
        pos -= 1
    best_s[pos], best_j[pos] = s, j
    return min(n + 1, kk)


@kernel
def _flatten(
    row_ids: np.ndarray, out_n: np.ndarray, out_j: np.ndarray, out_s: np.ndarray,
    out_f: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(query, target, similarity, flag) flat arrays of the per-row results: row r's first
    out_n[r] entries of out_j / out_s, its query index row_ids[r] and flag out_f[r]."""
    total = out_n.sum()
    q = np.empty(total, dtype=np.int64)
    t = np.empty(total, dtype=np.int64)
    s = np.empty(total)
    flag = np.empty(total, dtype=np.bool_)
    p = 0
    for r in range(row_ids.shape[0]):
        for h in range(out_n[r]):
            q[p], t[p], s[p], flag[p] = row_ids[r], out_j[r, h], out_s[r, h], out_f[r]
            p += 1
    return q, t, s, flag


@kernel
def class_blocks(
    T: np.ndarray, order_t: np.ndarray, sorted_t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The target side of `top_k_in_blocks`, built once per target: (blocks, block_class,
    block_start). Per class (ascending), its rows of T (n_t,d) normalised and transposed into
    one C-ordered (d, n_c) buffer, stored flat one after the other in `blocks`;
    block_class (b,) its label, block_start (b+1,) its first position in sorted_t. order_t
    (n,): the rows of T to take (all of them, or some classes' only), sorted by class."""
    n, d = order_t.shape[0], T.shape[1]
    inv_t = inverse_norms(T)
    blocks = np.empty(n * d)
    n_blocks = 0
    for j in range(n):
        n_blocks += j == 0 or sorted_t[j] != sorted_t[j - 1]
    block_class = np.empty(n_blocks, dtype=np.int64)
    block_start = np.empty(n_blocks + 1, dtype=np.int64)
    c = -1
    for j in range(n):
        if j == 0 or sorted_t[j] != sorted_t[j - 1]:
            c += 1
            block_class[c], block_start[c] = sorted_t[j], j
    block_start[n_blocks] = n
    for c in range(n_blocks):
        b, n_c = block_start[c], block_start[c + 1] - block_start[c]
        for j in range(n_c):
            row = order_t[b + j]
            w = inv_t[row]
            for f in range(d):
                blocks[b * d + f * n_c + j] = T[row, f] * w
    return blocks, block_class, block_start


@kernel
def top_k_same_class(
    Q: np.ndarray,
    T: np.ndarray,
    order_q: np.ndarray,
    sorted_q: np.ndarray,
    order_t: np.ndarray,
    sorted_t: np.ndarray,
    k: int,
    min_sim: float,
    max_ratio: float,
    flag_ratio: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per query row its k most similar same-class target rows (cosine similarity of the rows
    of Q (n_q,d) and T (n_t,d); a zero row is similar to nothing), kept when similarity >=
    min_sim and > 0.

    order_* / sorted_*: a stable argsort of each side's labels and the sorted labels.
    max_ratio / flag_ratio (NaN: unset): a query row whose best similarity s_1 and second s_2
    (same class) fail (1 - s_1) <= ratio * (1 - s_2) keeps no candidate (max_ratio) / is
    flagged False (flag_ratio); a class with one target passes both.
    Returns (query idx, target idx, score, flag), ordered by query, then score descending,
    then target; among equal scores the lower target index ranks first.
    """
    blocks, block_class, block_start = class_blocks(T, order_t, sorted_t)
    return top_k_in_blocks(Q, order_q, sorted_q, blocks, block_class, block_start, order_t,
                           k, min_sim, max_ratio, flag_ratio)  # fmt: skip


@kernel
def top_k_in_blocks(
    Q: np.ndarray,
    order_q: np.ndarray,
    sorted_q: np.ndarray,
    blocks: np.ndarray,
    block_class: np.ndarray,
    block_start: np.ndarray,
    order_t: np.ndarray,
    k: int,
    min_sim: float,
    max_ratio: float,
    flag_ratio: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`top_k_same_class` on the target's `class_blocks` (kept for many queries)."""
    n_q, d = Q.shape
    inv_q = inverse_norms(Q)
    out_j = np.full((n_q, k), -1, dtype=np.int64)
    out_s = np.zeros((n_q, k))
    out_n = np.zeros(n_q, dtype=np.int64)
    out_f = np.ones(n_q, dtype=np.bool_)
    test_ratio = not (np.isnan(max_ratio) and np.isnan(flag_ratio))
    best_s, best_j = np.empty(k), np.empty(k, dtype=np.int64)
    a, c = 0, 0
    while a < order_q.shape[0] and c < block_class.shape[0]:
        if sorted_q[a] < block_class[c]:
            a += 1
            continue
        if sorted_q[a] > block_class[c]:
            c += 1
            continue
        a_end = a
        while a_end < order_q.shape[0] and sorted_q[a_end] == block_class[c]:
            a_end += 1
        b, b_end = block_start[c], block_start[c + 1]
        n_t = b_end - b
        it = order_t[b:b_end]
        kk = min(k, n_t)
        ranks = (kk, best_s, best_j, test_ratio, min_sim, max_ratio, flag_ratio)
        outs = (out_j, out_s, out_n, out_f)
        if n_t <= _TILE:  # one tile: row by row on reused buffers, no per-class copies
            sim, x, row_nz = np.empty(n_t), np.empty(d), np.empty(d, dtype=np.int64)
            for r in range(a, a_end):
                i = order_q[r]
                m = _unit_row(Q, i, inv_q[i], x, row_nz)
                _similarities(sim, blocks, b * d, n_t, x, row_nz[:m])
                _rank(i, sim, it, *ranks, *outs)
            a, c = a_end, c + 1
            continue
        chunk = max(1, _HELD // max(n_t, 1))
        for a0 in range(a, a_end, chunk):
            rows = order_q[a0 : min(a_end, a0 + chunk)]
            X, nz, n_nz = _unit_rows(Q, rows, inv_q)
            S = np.empty((rows.shape[0], n_t))
            for j0 in range(0, n_t, _TILE):  # the same sums, pair by pair, as row by row
                j1 = min(n_t, j0 + _TILE)
                for r in range(rows.shape[0]):
                    _similarities(S[r, j0:j1], blocks, b * d + j0, n_t, X[r], nz[r, : n_nz[r]])
            for r in range(rows.shape[0]):
                _rank(rows[r], S[r], it, *ranks, *outs)
        a, c = a_end, c + 1
    return _flatten(np.arange(n_q), out_n, out_j, out_s, out_f)


@kernel
def top_k_in_lists(
    Q: np.ndarray,
    rows: np.ndarray,
    probes: np.ndarray,
    blocks: np.ndarray,
    list_start: np.ndarray,
    members: np.ndarray,
    k: int,
    min_sim: float,
    max_ratio: float,
    flag_ratio: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`top_k_in_blocks` for the query rows `rows` (r,) of Q (n_q,d) of one class, each
    scored only against the targets of its probed lists `probes` (r, p) (ids into the lists
    of a `class_blocks` buffer built on the class's rows sorted by list: `blocks`,
    `list_start` (l+1,), `members` (n_c,) their target indices). A pair's similarity has the
    same bits as in `top_k_in_blocks`; ranks and the ratio test run over the probed targets
    (ties: the lower target index first). Probing every list gives `top_k_in_blocks`'s result.
    Returns (query idx, target idx, score, flag) ordered by query, score descending, target.
    """
    n_r, n_p = probes.shape
    d = Q.shape[1]
    X, nz, n_nz = _unit_rows(Q, rows, inverse_norms(Q))
    out_j = np.full((n_r, k), -1, dtype=np.int64)
    out_s = np.zeros((n_r, k))
    out_n = np.zeros(n_r, dtype=np.int64)
    out_f = np.ones(n_r, dtype=np.bool_)
    test_ratio = not (np.isnan(max_ratio) and np.isnan(flag_ratio))
    # Per query row: best, second best and its index, the k best, targets seen. Every row is
    # scored list by list (each probed list read once for all the rows probing it); ranks
    # do not depend on the order targets are met in (ties: the lower target index).
    s1, s2 = np.full(n_r, -np.inf), np.full(n_r, -np.inf)
    j1 = np.full(n_r, -1, dtype=np.int64)
    best_s, best_j = np.empty((n_r, k)), np.empty((n_r, k), dtype=np.int64)
    n_best, seen = np.zeros(n_r, dtype=np.int64), np.zeros(n_r, dtype=np.int64)
    n_lists = list_start.shape[0] - 1
    first = np.zeros(n_lists + 1, dtype=np.int64)  # the rows probing each list, by list
    for r in range(n_r):
        for p in range(n_p):
            first[probes[r, p] + 1] += 1
    longest = 0
    for h in range(n_lists):
        first[h + 1] += first[h]
        longest = max(longest, list_start[h + 1] - list_start[h])
    fill = first[:-1].copy()
    prober = np.empty(n_r * n_p, dtype=np.int64)
    for r in range(n_r):
        for p in range(n_p):
            prober[fill[probes[r, p]]] = r
            fill[probes[r, p]] += 1
    sim_buf = np.empty(longest)
    for h in range(n_lists):
        b, n_l = list_start[h], list_start[h + 1] - list_start[h]
        sim = sim_buf[:n_l]
        for u in range(first[h], first[h + 1]):
            r = prober[u]
            _similarities(sim, blocks, b * d, n_l, X[r], nz[r, : n_nz[r]])
            n = n_best[r]
            for jj in range(n_l):
                s, j = sim[jj], members[b + jj]
                if s > s1[r] or (s == s1[r] and j < j1[r]):
                    s1[r], s2[r], j1[r] = s, s1[r], j
                elif s > s2[r]:
                    s2[r] = s
                if k > 1 and (n < k or s >= best_s[r, n - 1]):
                    n = _insert(best_s[r], best_j[r], n, s, j)
            n_best[r] = n
            seen[r] += n_l
    for r in range(n_r):
        if seen[r] == 0:
            continue
        if k == 1:
            best_s[r, 0], best_j[r, 0], n_best[r] = s1[r], j1[r], 1
        if test_ratio and seen[r] > 1:
            if not np.isnan(max_ratio) and not (1.0 - s1[r]) <= max_ratio * (1.0 - s2[r]):
                continue
            if not np.isnan(flag_ratio):
                out_f[r] = (1.0 - s1[r]) <= flag_ratio * (1.0 - s2[r])
        m = 0
        for h in range(n_best[r]):
            if best_s[r, h] >= min_sim and best_s[r, h] > 0:
                out_j[r, m], out_s[r, m] = best_j[r, h], best_s[r, h]
                m += 1
        out_n[r] = m
    return _flatten(rows, out_n, out_j, out_s, out_f)


watch_compiles()  # an install's first compile is said (sgloc.kernels)
