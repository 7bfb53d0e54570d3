"""Random walks over a graph and their per-vertex label-sequence histograms (numba): the
random-walk descriptor (`sgloc.descriptors.random_walk`) without the sparse sums of its
numpy reference.

The walks take the caller's uniforms, laid out step-major (uniform `s * n * n_walks + v *
n_walks + w` moves walk w of vertex v at step s), with the reference's arithmetic (the
neighbour index is int64(u * degree), clipped to the last stored neighbour), so kernel and
reference give the same bits. Each row's sequence codes come out in DESCENDING order (the
reference's CSR order), counts as float64; a vertex without neighbours has an empty row.
"""

from __future__ import annotations

import numpy as np

from sgloc.kernels import watch_compiles
from sgloc.kernels.dispatch import kernel

#: Histograms whose code range is at most this many bins (or 8 per walk) are counted in a dense
#: array scanned from the row's largest code to its least; larger ones sort each row's codes.
DENSE_BINS = 1 << 16


@kernel(writes=("cur", "code"))
def _vertex_codes(indptr, indices, labels, u, v, stride, walk_length, n_classes, cur, code):
    """Fill code (n_walks,) with the sequence codes of vertex v's walks, advanced together one
    step at a time (independent walks: the loads of one overlap another's); `cur` scratch."""
    n_walks = code.shape[0]
    last = indices.shape[0] - 1
    cur[:] = v
    code[:] = 0
    for s in range(walk_length):
        base = s * stride + v * n_walks
        for w in range(n_walks):
            c = cur[w]
            d = indptr[c + 1] - indptr[c]
            if d > 0:
                c = indices[min(indptr[c] + np.int64(u[base + w] * np.float64(d)), last)]
                cur[w] = c
            code[w] = code[w] * n_classes + labels[c]


@kernel(writes=("a",))
def _sift_down(a, root, end):
    """Restore the max-heap a[:end] below `root`."""
    while True:
        child = 2 * root + 1
        if child >= end:
            return
        if child + 1 < end and a[child + 1] > a[child]:
            child += 1
        if a[root] >= a[child]:
            return
        a[root], a[child] = a[child], a[root]
        root = child


@kernel(writes=("a",))
def _heapsort(a):
    """Sort a (int64) ascending in place (no numba sort helpers in cached kernels)."""
    n = a.shape[0]
    for root in range(n // 2 - 1, -1, -1):
        _sift_down(a, root, n)
    for end in range(n - 1, 0, -1):
        a[0], a[end] = a[end], a[0]
        _sift_down(a, 0, end)


@kernel(writes=("counts", "out_idx", "out_val"))
def _count_dense(code, counts, out_idx, out_val, nnz):
    """Append the histogram of `code` at out_*[nnz:], codes descending, by counting in the
    zeroed `counts` (left zeroed); the new nnz."""
    lo, hi = counts.shape[0], -1
    for w in range(code.shape[0]):
        c = code[w]
        counts[c] += 1
        lo, hi = min(lo, c), max(hi, c)
    for c in range(hi, lo - 1, -1):
        if counts[c]:
            out_idx[nnz], out_val[nnz] = c, counts[c]
            counts[c] = 0
            nnz += 1
    return nnz


@kernel(writes=("code", "out_idx", "out_val"))
def _count_sorted(code, out_idx, out_val, nnz):
    """`_count_dense` by sorting `code` (in place) instead: for histograms of many bins."""
    _heapsort(code)
    w = code.shape[0] - 1
    while w >= 0:
        run = w
        while run > 0 and code[run - 1] == code[w]:
            run -= 1
        out_idx[nnz], out_val[nnz] = code[w], w - run + 1
        nnz += 1
        w = run - 1
    return nnz


@kernel
def walk_histograms(indptr, indices, labels, u, n_walks, walk_length, n_classes):
    """(indptr, indices, data) of the (n, n_classes**walk_length) CSR histogram of the label
    sequences of `n_walks` walks of `walk_length` steps from every vertex of the graph with
    adjacency (`indptr` (n+1,), `indices`) and `labels` (n,) int64, moved by the uniforms `u`
    (walk_length * n * n_walks,) float64 (module docstring). Codes descend within a row."""
    n = indptr.shape[0] - 1
    stride = n * n_walks
    dim = np.int64(n_classes) ** walk_length
    width = min(np.int64(n_walks), dim)
    out_ptr = np.zeros(n + 1, dtype=np.int64)
    out_idx = np.empty(n * width, dtype=np.int64)
    out_val = np.empty(n * width, dtype=np.float64)
    dense = dim <= max(DENSE_BINS, 8 * n_walks)
    counts = np.zeros(dim if dense else 0, dtype=np.int64)
    cur = np.empty(n_walks, dtype=np.int64)
    code = np.empty(n_walks, dtype=np.int64)
    nnz = 0
    for v in range(n):
        if indptr[v + 1] > indptr[v]:
            _vertex_codes(indptr, indices, labels, u, v, stride, walk_length, n_classes, cur,
                          code)  # fmt: skip
            if dense:
                nnz = _count_dense(code, counts, out_idx, out_val, nnz)
            else:
                nnz = _count_sorted(code, out_idx, out_val, nnz)
        out_ptr[v + 1] = nnz
    return out_ptr, out_idx[:nnz].copy(), out_val[:nnz].copy()


watch_compiles()  # an install's first compile is said (sgloc.kernels)
