"""Candidate matches by cosine similarity of vertex descriptors (paper Eq. 1)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import sparse

from sgloc.validation import validate_settings


@dataclass
class MatchingConfig:
    """Best-per-query matching among same-class vertices.

    min_similarity: keep a candidate when its cosine similarity >= this (Guo: 0.5).
    top_k: candidates kept per query vertex (1 = the paper's best match).
    mutual: keep (i, j) only when i is also among j's best `top_k` queries.
    """

    min_similarity: float = 0.5
    top_k: int = 1
    mutual: bool = False

    def __post_init__(self) -> None:
        validate_settings(self)  # type, range, finiteness of every field (sgloc.validation)

    def get_params(self) -> dict:
        return asdict(self)


def _row_normalised(D) -> sparse.csr_array | np.ndarray:
    if sparse.issparse(D):
        D = sparse.csr_array(D, dtype=np.float64)
        norms = np.sqrt(np.asarray(D.multiply(D).sum(axis=1)).ravel())
        inv = np.divide(1.0, norms, out=np.zeros_like(norms), where=norms > 0)
        return sparse.csr_array(sparse.diags_array(inv) @ D)
    D = np.asarray(D, dtype=np.float64)
    norms = np.linalg.norm(D, axis=1)
    inv = np.divide(1.0, norms, out=np.zeros_like(norms), where=norms > 0)
    return D * inv[:, None]


def cosine_similarity(desc_q, desc_t, labels_q: np.ndarray, labels_t: np.ndarray) -> np.ndarray:
    """(n_q, n_t) cosine similarity; 0 between vertices of different classes or without a
    descriptor (all-zero row). Computed one class block at a time (only same-class pairs)."""
    Q, T = _row_normalised(desc_q), _row_normalised(desc_t)
    S = np.zeros((Q.shape[0], T.shape[0]))
    for c in np.intersect1d(labels_q, labels_t):
        iq, it = np.flatnonzero(labels_q == c), np.flatnonzero(labels_t == c)
        block = Q[iq] @ T[it].T
        S[np.ix_(iq, it)] = block.toarray() if sparse.issparse(block) else block
    return S


def match_descriptors(
    desc_q,
    desc_t,
    labels_q: np.ndarray,
    labels_t: np.ndarray,
    config: MatchingConfig | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate matches (m,2) int (query index, target index) and their scores (m,).

    For each query vertex its `top_k` most similar same-class target vertices with similarity
    >= `min_similarity`, optionally mutually best. Ordered by query index, then score.
    """
    cfg = config or MatchingConfig()
    S = cosine_similarity(desc_q, desc_t, labels_q, labels_t)
    n_q, n_t = S.shape
    if n_q == 0 or n_t == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    k = int(min(max(cfg.top_k, 1), n_t))
    if k == 1:
        best = np.argmax(S, axis=1)[:, None]
    else:
        best = np.argpartition(-S, k - 1, axis=1)[:, :k]
        order = np.argsort(-np.take_along_axis(S, best, axis=1), axis=1, kind="stable")
        best = np.take_along_axis(best, order, axis=1)
    rows = np.repeat(np.arange(n_q), k)
    cols = best.ravel()
    scores = S[rows, cols]
    keep = scores >= cfg.min_similarity
    # Zero similarity never counts as a match, whatever the threshold.
    keep &= scores > 0
    if cfg.mutual:
        kq = int(min(k, n_q))
        best_q = (
            np.argpartition(-S.T, kq - 1, axis=1)[:, :kq]
            if kq > 1
            else np.argmax(S, axis=0)[:, None]
        )
        is_best_q = np.zeros((n_t, n_q), dtype=bool)
        np.put_along_axis(is_best_q, best_q, True, axis=1)
        keep &= is_best_q[cols, rows]
    matches = np.stack([rows[keep], cols[keep]], axis=1).astype(np.int64)
    return matches, scores[keep]
