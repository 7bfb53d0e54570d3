"""Which candidate matches count as evidence: the one selection every caller uses.

`select_evidence` keeps the distinctive candidates for a query of a given size
(`EvidenceConfig.ratio_for`, `exclusion_for`): the ratio test flagged during matching, or the
ratio test against rivals at *other places* (`spatially_distinctive`) for small queries.

Lowe's ratio test keeps a match when it is clearly better than the second best. Against a map,
the second best is often a neighbour of the best target (two trees of one row, 6 m apart): a
near tie between objects of one place, not an ambiguity about the place. `spatially_distinctive`
takes the rival only among the same-class targets farther than `exclusion` metres from the
candidate's target, so a match is refused for a look-alike elsewhere (another block of a
repetitive city), not for its own neighbours.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from sgloc.acceptance.config import EvidenceConfig
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.prepared_graph import PreparedGraph
from sgloc.matching.candidates import BLOCK_ENTRIES, MatchingConfig, match_descriptors, unit_rows


def spatially_distinctive(
    desc_q,
    desc_t,
    labels_t: np.ndarray,
    target_positions: np.ndarray,
    candidates: np.ndarray,
    ratio: float,
    exclusion: float,
) -> np.ndarray:
    """(m,) bool: candidate (i, j) passes (1 - s_ij) <= ratio * (1 - s_2), s = cosine similarity
    of the descriptors, s_2 = the best similarity of query i to a target of j's class farther
    than `exclusion` metres from target j (none: passes). exclusion 0: the usual ratio test
    against the second best target of the class (for top-1 candidates)."""
    cand = np.asarray(candidates, dtype=np.int64).reshape(-1, 2)
    out = np.ones(len(cand), dtype=bool)
    if len(cand) == 0:
        return out
    Q, T = (unit_rows(D.toarray() if hasattr(D, "toarray") else D) for D in (desc_q, desc_t))
    tlab = labels_t[cand[:, 1]]
    for c in np.unique(tlab):
        rows = np.flatnonzero(tlab == c)
        members = np.flatnonzero(labels_t == c)
        TcT, Pc = np.ascontiguousarray(T[members].T), target_positions[members]
        pc2 = np.einsum("ij,ij->i", Pc, Pc)
        step = max(1, BLOCK_ENTRIES // max(len(members), 1))
        for s in range(0, len(rows), step):
            r = rows[s : s + step]
            S = Q[cand[r, 0]] @ TcT
            s1 = np.einsum("ij,ij->i", Q[cand[r, 0]], T[cand[r, 1]])
            # Targets within `exclusion` of the candidate's target (itself included): no rivals.
            pj = target_positions[cand[r, 1]]
            d2 = np.einsum("ij,ij->i", pj, pj)[:, None] + pc2[None, :] - 2.0 * (pj @ Pc.T)
            S[d2 <= exclusion**2 + 1e-9] = -np.inf
            s2 = S.max(axis=1)
            out[r] = ~np.isfinite(s2) | ((1.0 - s1) <= ratio * (1.0 - s2))
    return out


def select_evidence(
    query: SemanticGraph,
    target: SemanticGraph,
    desc_q,
    desc_t,
    candidates: np.ndarray,
    flags: np.ndarray | None,
    matching: MatchingConfig,
    config: EvidenceConfig,
    prepared: PreparedGraph | None = None,
) -> np.ndarray:
    """The candidates (m,2) (query index, target index) that count as evidence for a query of
    this size: all of them when its ratio (`config.ratio_for`) is None; else those passing the
    ratio test against rivals farther than `config.exclusion_for` metres when that is > 0
    (`spatially_distinctive`), else those `flags` marks (`sgloc.matching.candidates.match_flagged`
    at that ratio); without flags, the candidates of `matching` with `max_ratio` at that ratio.
    desc_q, desc_t: the graphs' vertex descriptors (dense or CSR); prepared: the target's
    `PreparedGraph` (of desc_t) for that matching, or None."""
    ratio = config.ratio_for(len(query))
    if ratio is None:
        return candidates
    # Only distinctive matches count: in a repetitive place near-tied matches line up with a
    # wrong alignment as readily as with the right one.
    exclusion = config.exclusion_for(len(query))
    if exclusion > 0:  # rivals only at other places
        keep = spatially_distinctive(
            desc_q, desc_t, target.labels, target.positions, candidates, ratio, exclusion
        )
        return candidates[keep]
    if flags is not None:
        return candidates[flags]
    strict = dataclasses.replace(matching, max_ratio=ratio)
    return match_descriptors(desc_q, desc_t, query.labels, target.labels, strict, prepared)[0]
