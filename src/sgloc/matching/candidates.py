"""Candidate matches by cosine similarity of vertex descriptors (paper Eq. 1).

Memory is linear in the number of vertices: similarities are computed one class at a time and,
within a class, for blocks of query rows (at most `BLOCK_ENTRIES` similarities at once); only
the kept candidates leave a block.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse

from sgloc.kernels import one_blas_thread
from sgloc.maps.prepared_graph import PreparedGraph
from sgloc.matching.index import build_index, class_index, search_class, uses_index
from sgloc.validation import (
    MAX_ITERATIONS,
    MAX_VERTICES,
    choice,
    flag,
    integer,
    real,
    setting,
    validate_settings,
)

#: Similarities held at once per block (8 MB of float64).
BLOCK_ENTRIES = 1 << 20

STRATEGIES = ("top_k", "all")
SEARCHES = ("auto", "exact", "index")


@dataclass
class MatchingConfig:
    """Which same-class vertex pairs become candidate matches.

    min_similarity: keep a candidate when its cosine similarity >= this (Guo: 0.5).
    top_k: strategy "top_k": candidates kept per query vertex (1 = the paper's best match).
    mutual: keep (i, j) only when i is also among j's best `top_k` queries.
    strategy: "top_k" (per query vertex) or "all" (every same-class pair with similarity >=
        min_similarity, the most similar first, at most `max_candidates`).
    max_candidates: cap on the candidates of strategy "all" (rejection holds an m x m matrix).
    max_ratio: strategy "top_k": keep a query object's candidates only when its best match is
        distinctly better than its second best, (1 - s_1) / (1 - s_2) <= max_ratio (Lowe's
        ratio test on cosine distances; a repetitive place gives near ties). None: no test.
    search: strategy "top_k", how a query object's most similar targets are found: "exact"
        (every same-class target), "index" (only the targets of the `probes` lists of an
        inverted file over the class, `sgloc.matching.index`: sub-quadratic, may miss a best
        match), or "auto": the index for a class of more than 4,096 target objects, exact
        otherwise (so every problem whose classes are all smaller keeps its exact result).
        Dense descriptors and the compiled kernels only; otherwise exact.
    probes: search "index": lists probed per query object (of about sqrt(class size)); more
        finds more of the exact best matches and costs proportionally more.
    """

    min_similarity: float = setting(0.5, check=real(0.0, 1.0))
    top_k: int = setting(1, check=integer(1, MAX_VERTICES))
    mutual: bool = setting(False, check=flag())
    strategy: str = setting(
        "top_k", check=choice(*STRATEGIES, what="which candidates matching keeps")
    )
    max_candidates: int = setting(3000, check=integer(1, MAX_ITERATIONS))
    max_ratio: float | None = setting(None, check=real(0.0, 1.0, low_open=True, none_ok=True))
    search: str = setting(
        "auto", check=choice("auto", "exact", "index", what="how matching finds the most similar")
    )
    probes: int = setting(8, check=integer(1, MAX_VERTICES))

    def __post_init__(self) -> None:
        validate_settings(self, "matching")  # the checks declared beside the fields


def unit_rows(D) -> sparse.csr_array | np.ndarray:
    """Descriptor rows scaled to unit length (all-zero rows stay zero); CSR stays CSR."""
    if sparse.issparse(D):
        D = sparse.csr_array(D, dtype=np.float64)
        norms = np.sqrt(np.asarray(D.multiply(D).sum(axis=1)).ravel())
        inv = np.divide(1.0, norms, out=np.zeros_like(norms), where=norms > 0)
        return sparse.csr_array(sparse.diags_array(inv) @ D)
    D = np.asarray(D, dtype=np.float64)
    norms = np.linalg.norm(D, axis=1)
    inv = np.divide(1.0, norms, out=np.zeros_like(norms), where=norms > 0)
    return D * inv[:, None]


def _blocks(Q, T, labels_q: np.ndarray, labels_t: np.ndarray) -> Iterator[tuple]:
    """(query indices (b,), target indices (t,), similarities (b,t)) for every block of
    same-class pairs; Q, T row-normalised descriptors."""
    for c in np.intersect1d(labels_q, labels_t):
        iq, it = np.flatnonzero(labels_q == c), np.flatnonzero(labels_t == c)
        Tc = T[it]
        TcT = Tc.T.tocsr() if sparse.issparse(Tc) else np.ascontiguousarray(Tc.T)
        step = max(1, BLOCK_ENTRIES // max(len(it), 1))
        for s in range(0, len(iq), step):
            rows = iq[s : s + step]
            block = Q[rows] @ TcT
            yield rows, it, block.toarray() if sparse.issparse(block) else np.asarray(block)


def cosine_similarity(desc_q, desc_t, labels_q: np.ndarray, labels_t: np.ndarray) -> np.ndarray:
    """(n_q, n_t) dense cosine similarity; 0 between vertices of different classes or without
    a descriptor (all-zero row). For inspection of small graphs: `match_descriptors` never
    builds this matrix."""
    Q, T = unit_rows(desc_q), unit_rows(desc_t)
    S = np.zeros((Q.shape[0], T.shape[0]))
    for rows, it, block in _blocks(Q, T, labels_q, labels_t):
        S[np.ix_(rows, it)] = block
    return S


def _top_k(
    desc_q,
    desc_t,
    labels_q,
    labels_t,
    k: int,
    min_sim: float,
    max_ratio: float | None = None,
    flag_ratio: float | None = None,
    compiled: bool = False,
    target: PreparedGraph | None = None,
    search: tuple[str, int] = ("exact", 8),
) -> tuple[np.ndarray, ...]:
    """Per query row its k most similar same-class targets with similarity >= min_sim and > 0
    (and passing the ratio test when max_ratio is set): (query idx, target idx, score, flag),
    ordered by query, then score descending, then target; flag: the query passes the ratio
    test at `flag_ratio` (all True when it is None). Of equally similar targets the lower
    index ranks first. `compiled`: by the kernel (dense descriptors only, `_use_kernel`), with
    the `target`'s kept blocks and indexes when given (its `PreparedGraph`); search:
    (MatchingConfig.search, .probes), for the compiled path."""
    if compiled:
        return _compiled_top_k(desc_q, desc_t, labels_q, labels_t, k, min_sim, max_ratio,
                               flag_ratio, target, *search)  # fmt: skip
    Q, T = unit_rows(desc_q), unit_rows(desc_t)
    out_q, out_t, out_s, out_f = [], [], [], []
    for rows, it, S in _blocks(Q, T, labels_q, labels_t):
        kk = min(k, S.shape[1])
        if kk == 1:
            best = np.argmax(S, axis=1)[:, None]
        else:
            best = np.argsort(-S, axis=1, kind="stable")[:, :kk]
        sc = np.take_along_axis(S, best, axis=1)
        flag = np.ones(len(rows), dtype=bool)
        if (max_ratio is not None or flag_ratio is not None) and S.shape[1] > 1:
            top2 = -np.partition(-S, 1, axis=1)[:, :2]
            if max_ratio is not None:
                distinct = (1.0 - top2[:, 0]) <= max_ratio * (1.0 - top2[:, 1])
                sc = np.where(distinct[:, None], sc, -np.inf)
            if flag_ratio is not None:
                flag = (1.0 - top2[:, 0]) <= flag_ratio * (1.0 - top2[:, 1])
        out_q.append(np.repeat(rows, kk))
        out_t.append(it[best.ravel()])
        out_s.append(sc.ravel())
        out_f.append(np.repeat(flag, kk))
    if not out_q:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool)
    q, t, s, f = (np.concatenate(x) for x in (out_q, out_t, out_s, out_f))
    keep = (s >= min_sim) & (s > 0)  # zero similarity never counts as a match
    q, t, s, f = q[keep], t[keep], s[keep], f[keep]
    order = np.lexsort((t, -s, q))
    return q[order], t[order], s[order], f[order]


def _as_matrix(D):
    """A CSR matrix as it is, anything else as a float64 array."""
    return D if sparse.issparse(D) else np.asarray(D, dtype=np.float64)


def _use_kernel(desc_q, desc_t) -> bool:
    """Whether `_top_k` runs the compiled kernel: dense descriptors (sparse ones, such as the
    random walks' histograms, are matched by sparse block products in numpy)."""
    return not (sparse.issparse(desc_q) or sparse.issparse(desc_t))


@dataclass(frozen=True)
class TargetBlocks:
    """A target's descriptors as the matching kernel reads them, built once for many queries
    (`target_blocks`): per class searched exhaustively, its unit rows transposed
    (`sgloc.matching.similarity_kernels`: blocks, block_class, block_start, order: those
    classes' target indices sorted by class); `index`: the candidate-search index of the other
    classes; classes, counts: every class of the target and its number of rows."""

    n_rows: int
    blocks: np.ndarray
    block_class: np.ndarray
    block_start: np.ndarray
    order: np.ndarray
    index: dict = field(default_factory=dict)
    classes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    counts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def covers(self, classes: np.ndarray) -> bool:
        """Whether every one of `classes` the target holds has a block (is searched
        exhaustively on these blocks)."""
        held = np.intersect1d(classes, self.classes)
        return bool(np.all(np.isin(held, self.block_class)))


#: Targets of more objects than this keep their matching blocks when prepared
# (sgloc.pipeline.prepared).
BLOCKS_MIN_OBJECTS = 1500


def target_blocks(desc_t, labels_t: np.ndarray, search: str = "auto") -> TargetBlocks | None:
    """The kernel's class blocks of a target's descriptors (n,d) and labels (n,), or None when
    they are not worth keeping: sparse descriptors, or at most BLOCKS_MIN_OBJECTS rows (blocks
    that cheap are built per call). With `search` other than "exact", the classes it sends to
    the index (`sgloc.matching.index`: more than INDEX_MIN_CLASS objects under "auto") get
    their index and no block. Memory: another n x d floats (blocks and index together)."""
    if sparse.issparse(desc_t) or len(labels_t) <= BLOCKS_MIN_OBJECTS:
        return None
    from sgloc.matching.similarity_kernels import class_blocks

    labels_t = np.asarray(labels_t, dtype=np.int64)
    classes, counts = np.unique(labels_t, return_counts=True)
    index = {} if search == "exact" else build_index(desc_t, labels_t)
    exact = np.flatnonzero(~np.isin(labels_t, np.fromiter(index, np.int64, len(index))))
    order_t = exact[np.argsort(labels_t[exact], kind="stable")]
    parts = class_blocks(np.ascontiguousarray(desc_t, dtype=np.float64), order_t,
                         labels_t[order_t])  # fmt: skip
    for a in (*parts, order_t, classes, counts):
        a.flags.writeable = False
    return TargetBlocks(len(labels_t), *parts, order_t, index, classes, counts)


def _compiled_top_k(desc_q, desc_t, labels_q, labels_t, k, min_sim, max_ratio, flag_ratio,
                    target: PreparedGraph | None = None, search: str = "exact",
                    probes: int = 8):  # fmt: skip
    """`_top_k` by `sgloc.matching.similarity_kernels.top_k_same_class` (same candidates;
    similarities equal to rounding), on the `target`'s kept blocks when it has them (the same
    bits); the classes `search` sends to an index (`sgloc.matching.index.uses_index`) by their
    index (the one of the target's blocks, else one kept in `target.class_indexes`, else built)."""
    from sgloc.matching.similarity_kernels import top_k_in_blocks, top_k_same_class

    blocks = None if target is None else target.blocks

    labels_q = np.asarray(labels_q, dtype=np.int64)
    labels_t = np.asarray(labels_t, dtype=np.int64)
    tests = (int(k), float(min_sim), np.nan if max_ratio is None else float(max_ratio),
             np.nan if flag_ratio is None else float(flag_ratio))  # fmt: skip
    indexed = _indexed_classes(labels_q, labels_t, search, blocks)
    exact_q = labels_q
    if indexed.size:  # their query rows get a label no target has: the exact pass skips them
        exact_q = np.where(np.isin(labels_q, indexed), labels_t.min() - 1, labels_q)
    order_q = np.argsort(exact_q, kind="stable")
    query = (np.ascontiguousarray(desc_q, dtype=np.float64), order_q, exact_q[order_q])
    if blocks is not None and blocks.covers(np.unique(exact_q)):
        kept_blocks = (blocks.blocks, blocks.block_class, blocks.block_start, blocks.order)
        out = top_k_in_blocks(*query, *kept_blocks, *tests)
    else:
        order_t = np.argsort(labels_t, kind="stable")
        Q, order_q, sorted_q = query
        T = np.ascontiguousarray(desc_t, dtype=np.float64)
        out = top_k_same_class(Q, T, order_q, sorted_q, order_t, labels_t[order_t], *tests)
    if not indexed.size:
        return out
    parts = [out]
    kept = blocks.index if blocks is not None else {}
    store = None if target is None else target.class_indexes
    for c in indexed:
        index = kept.get(int(c)) or class_index(desc_t, labels_t, int(c), store)
        parts.append(search_class(index, query[0], np.flatnonzero(labels_q == c), probes, tests))
    q, t, s, f = (np.concatenate(x) for x in zip(*parts, strict=True))
    order = np.lexsort((t, -s, q))
    return q[order], t[order], s[order], f[order]


def _indexed_classes(labels_q: np.ndarray, labels_t: np.ndarray, search: str,
                     blocks: TargetBlocks | None = None) -> np.ndarray:  # fmt: skip
    """The classes (ascending) that `search` sends to an index for these labels (the target's
    class sizes read from its prepared `blocks` when given)."""
    if search == "exact" or not uses_index(search, len(labels_t)):
        return np.zeros(0, np.int64)  # not even a class of every target would be indexed
    if blocks is not None:
        ct, nt = blocks.classes, blocks.counts
    else:
        ct, nt = np.unique(labels_t, return_counts=True)
    use = np.array([uses_index(search, int(n)) for n in nt], dtype=bool)
    return np.intersect1d(np.unique(labels_q), ct[use])


def _all_pairs(Q, T, labels_q, labels_t, cap: int, min_sim: float) -> tuple[np.ndarray, ...]:
    """Every same-class pair with similarity >= min_sim and > 0, the `cap` most similar,
    ordered by query, then score descending. Holds at most 2 * cap pairs between blocks."""
    q = np.zeros(0, np.int64)
    t = np.zeros(0, np.int64)
    s = np.zeros(0)
    for rows, it, S in _blocks(Q, T, labels_q, labels_t):
        ok = (S >= min_sim) & (S > 0)
        if len(s) == cap:  # only pairs that beat the current worst kept one can enter
            ok &= S > s.min()
        r, c = np.nonzero(ok)
        q = np.concatenate([q, rows[r]])
        t = np.concatenate([t, it[c]])
        s = np.concatenate([s, S[r, c]])
        if len(s) > cap:
            top = np.lexsort((t, q, -s))[:cap]
            q, t, s = q[top], t[top], s[top]
    order = np.lexsort((t, -s, q))
    return q[order], t[order], s[order]


def match_descriptors(
    desc_q,
    desc_t,
    labels_q: np.ndarray,
    labels_t: np.ndarray,
    config: MatchingConfig | None = None,
    target: PreparedGraph | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate matches (m,2) int (query index, target index) and their scores (m,).

    Strategy "top_k": for each query vertex its `top_k` most similar same-class target
    vertices with similarity >= `min_similarity`, optionally mutually best. Strategy "all":
    every same-class pair above `min_similarity`, the `max_candidates` most similar.
    Ordered by query index, then score (descending). target: the target's `PreparedGraph`
    (of `desc_t`) when the caller keeps one: its matching blocks and class indexes are used
    and the indexes built here kept in it (the same result).
    """
    return match_flagged(desc_q, desc_t, labels_q, labels_t, config, target=target)[:2]


def match_flagged(
    desc_q,
    desc_t,
    labels_q: np.ndarray,
    labels_t: np.ndarray,
    config: MatchingConfig | None = None,
    flag_ratio: float | None = None,
    target: PreparedGraph | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """`match_descriptors` plus, per candidate, whether it is also a candidate of the same
    matching with `max_ratio=flag_ratio` (one pass instead of two): (candidates, scores,
    flags (m,) bool). flags is None when that set is not a subset of these candidates (a
    looser flag_ratio than the config's max_ratio); strategy "all" has no ratio test: all
    True. target: as `match_descriptors`' (a prepared map's holds its `target_blocks`)."""
    cfg = config or MatchingConfig()
    if cfg.strategy not in STRATEGIES:
        raise ValueError(f"unknown matching strategy {cfg.strategy!r}; use one of {STRATEGIES}")
    if cfg.search not in SEARCHES:
        raise ValueError(f"unknown matching search {cfg.search!r}; use one of {SEARCHES}")
    if flag_ratio is not None and cfg.max_ratio is not None and flag_ratio > cfg.max_ratio:
        return (*match_descriptors(desc_q, desc_t, labels_q, labels_t, cfg, target), None)
    desc_q, desc_t = _as_matrix(desc_q), _as_matrix(desc_t)
    if cfg.strategy == "top_k" and _use_kernel(desc_q, desc_t):  # no BLAS products
        return _match(desc_q, desc_t, labels_q, labels_t, cfg, flag_ratio, True, target)
    with one_blas_thread():  # small block products
        return _match(desc_q, desc_t, labels_q, labels_t, cfg, flag_ratio)


def _match(
    desc_q,
    desc_t,
    labels_q,
    labels_t,
    cfg: MatchingConfig,
    flag_ratio: float | None = None,
    compiled: bool = False,
    target: PreparedGraph | None = None,
) -> tuple[np.ndarray, ...]:
    if desc_q.shape[0] == 0 or desc_t.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), np.zeros(0, bool)
    min_sim = float(cfg.min_similarity)
    if cfg.strategy == "all":
        Q, T = unit_rows(desc_q), unit_rows(desc_t)
        q, t, s = _all_pairs(Q, T, labels_q, labels_t, max(int(cfg.max_candidates), 1), min_sim)
        f = np.ones(len(q), dtype=bool)
    else:
        k = max(int(cfg.top_k), 1)
        search = (cfg.search, int(cfg.probes))
        args = (labels_q, labels_t, k, min_sim, cfg.max_ratio, flag_ratio, compiled, target)
        q, t, s, f = _top_k(desc_q, desc_t, *args, search)
        if cfg.mutual and q.size:
            # j's best k queries (any similarity), by the same blocks with the roles swapped.
            back_args = (labels_t, labels_q, k, -np.inf, None, None, compiled, None, search)
            tq, qq, _, _ = _top_k(desc_t, desc_q, *back_args)
            n_q = desc_q.shape[0]
            back = np.isin(t * n_q + q, tq * n_q + qq)
            q, t, s, f = q[back], t[back], s[back], f[back]
    return np.stack([q, t], axis=1).astype(np.int64), s, f
