"""A sub-quadratic candidate search for descriptor matching: per class, an inverted file over
the target's unit descriptor rows (cosine top-k = nearest neighbours on unit vectors).

A class's target rows are clustered into about sqrt(n) lists (spherical k-means on a seeded
sample, a few rounds, then every row assigned to its most similar centre); a query row is
scored exactly, with the same bits as the exhaustive search, against the rows of its `probes`
most similar lists only. Probing every list is the exhaustive search; otherwise a query's true
best match is missed when it lies in an unprobed list (recall measured in
docs/speed_benchmark.md). Deterministic: the sample comes from a Generator seeded by the class
size, and the matrix products run on one BLAS thread.

Used by `sgloc.matching.candidates` (`MatchingConfig.search`) per class: see `uses_index` for the
rule. """

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.kernels import one_blas_thread

#: search "auto": a class is searched by its index when it has more target rows than this.
INDEX_MIN_CLASS = 4096
#: k-means rounds on the sample, and sample rows per list.
KMEANS_ROUNDS = 4
SAMPLE_PER_LIST = 32


@dataclass(frozen=True)
class ClassIndex:
    """One class's inverted file: centres (l, d) unit rows; the class's target rows sorted by
    list as the matching kernel reads them (`blocks`, `list_start` (l+1,), `members` (n_c,)
    target indices, ascending within a list)."""

    centres: np.ndarray
    blocks: np.ndarray
    list_start: np.ndarray
    members: np.ndarray

    @property
    def n_lists(self) -> int:
        return len(self.centres)


def uses_index(search: str, n_target: int) -> bool:
    """Whether a class of `n_target` target rows is searched by its index under `search`
    ("exact", "index" or "auto": index when n_target > INDEX_MIN_CLASS; so every problem
    whose classes all have at most that many target rows is searched exactly)."""
    if search == "index":
        return n_target > 0
    if search == "auto":
        return n_target > INDEX_MIN_CLASS
    return False


def n_lists(n: int) -> int:
    """Lists of a class of n target rows: about sqrt(n)."""
    return max(1, int(np.ceil(np.sqrt(n))))


def _unit(X: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(X, axis=1)
    return X * np.divide(1.0, norms, out=np.zeros_like(norms), where=norms > 0)[:, None]


def _kmeans(X: np.ndarray, n_centres: int) -> np.ndarray:
    """Spherical k-means centres (n_centres, d) of the unit rows X, on a seeded sample."""
    rng = np.random.default_rng(len(X))
    n_sample = min(len(X), SAMPLE_PER_LIST * n_centres)
    sample = X[np.sort(rng.choice(len(X), n_sample, replace=False))]
    centres = sample[np.linspace(0, n_sample - 1, n_centres).astype(np.int64)]
    for _ in range(KMEANS_ROUNDS):
        assign = np.argmax(sample @ centres.T, axis=1)
        order = np.argsort(assign, kind="stable")
        used, first = np.unique(assign[order], return_index=True)
        sums = np.add.reduceat(sample[order], first, axis=0)
        centres = centres.copy()
        centres[used] = _unit(sums)
    return centres


def build_class_index(desc: np.ndarray, rows: np.ndarray) -> ClassIndex:
    """The index of the target rows `rows` (one class, ascending) of descriptors desc (n, d)."""
    from sgloc.matching.similarity_kernels import class_blocks

    X = np.ascontiguousarray(desc[rows], dtype=np.float64)
    with one_blas_thread():  # the same bits in every process
        U = _unit(X)
        centres = _kmeans(U, n_lists(len(rows)))
        assign = np.argmax(U @ centres.T, axis=1).astype(np.int64)
    order = np.argsort(assign, kind="stable")
    blocks, used, start = class_blocks(X, order, assign[order])
    list_start = np.zeros(len(centres) + 1, dtype=np.int64)
    counts = np.diff(start)
    list_start[used + 1] = counts
    list_start = np.cumsum(list_start)
    out = ClassIndex(centres, blocks, list_start, np.asarray(rows, np.int64)[order])
    for a in (out.centres, out.blocks, out.list_start, out.members):
        a.flags.writeable = False
    return out


def build_index(desc: np.ndarray, labels: np.ndarray, min_class: int | None = None) -> dict:
    """{class label: ClassIndex} for every class of more than `min_class` (default
    INDEX_MIN_CLASS) rows of a target's dense descriptors (n, d) and labels (n,) (a prepared
    map keeps it)."""
    min_class = INDEX_MIN_CLASS if min_class is None else min_class
    labels = np.asarray(labels)
    classes, counts = np.unique(labels, return_counts=True)
    return {
        int(c): build_class_index(desc, np.flatnonzero(labels == c))
        for c, n in zip(classes, counts, strict=True)
        if n > min_class
    }


def class_index(
    desc: np.ndarray, labels: np.ndarray, c: int, kept: dict | None = None
) -> ClassIndex:
    """The index of class c of a target's descriptors (n, d) and labels (n,). `kept`: the
    indexes of these descriptors that the caller keeps ({class: (rows, ClassIndex)}, a
    prepared graph's `class_indexes`): read when it holds class c with the same rows, else
    the index is built and stored there."""
    rows = np.flatnonzero(np.asarray(labels) == c)
    if kept is None:
        return build_class_index(desc, rows)
    entry = kept.get(int(c))
    if entry is None or not np.array_equal(entry[0], rows):
        entry = kept[int(c)] = (rows, build_class_index(desc, rows))
    return entry[1]


def probe_lists(index: ClassIndex, Q: np.ndarray, rows: np.ndarray, probes: int) -> np.ndarray:
    """(r, p) the `probes` lists most similar to each query row `rows` of Q (all when fewer)."""
    p = min(int(probes), index.n_lists)
    with one_blas_thread():
        S = _unit(np.ascontiguousarray(Q[rows], dtype=np.float64)) @ index.centres.T
    if p == index.n_lists:
        return np.broadcast_to(np.arange(p, dtype=np.int64), (len(rows), p)).copy()
    return np.argpartition(-S, p - 1, axis=1)[:, :p].astype(np.int64)


def search_class(index: ClassIndex, Q: np.ndarray, rows: np.ndarray, probes: int, tests: tuple):
    """(query idx, target idx, score, flag) of the query rows `rows` of Q in this class
    (`sgloc.matching.similarity_kernels.top_k_in_lists`; tests: k, min_sim, max_ratio,
    flag_ratio)."""
    from sgloc.matching.similarity_kernels import top_k_in_lists

    lists = probe_lists(index, Q, rows, probes)
    return top_k_in_lists(Q, np.asarray(rows, np.int64), lists, index.blocks, index.list_start,
                          index.members, *tests)  # fmt: skip
