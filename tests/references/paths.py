"""`on_references()`: run the library on the numpy references instead of its compiled kernels.

Stage code imports each kernel inside the function that calls it, so replacing a kernel
module's function replaces every call of it. Each replacement here takes the kernel's arguments
and returns its outputs, computed by the reference of `tests/references` (equal to rounding;
the same bits where the references say so). The RANSAC scorer runs `ransac_reference` and the
matching runs the numpy block products.
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Iterator
from types import SimpleNamespace

import numpy as np

from references import acceptance, consistency, descriptors, estimation, maps, rejection
from sgloc.consistency.pairwise import pack_rows, unpack_rows


def _form(neighbor: bool) -> str:
    return "neighbor" if neighbor else "distance"


def _kept_starts(bits, keep):
    """`triangle_kernels.kept_starts` from the listed pairs."""
    ii, _ = consistency.upper_pairs(bits, keep)
    counts = np.bincount(ii, minlength=len(bits))
    keep_words = pack_rows(np.asarray(keep, dtype=bool)[None, :])[0]
    return keep_words[: bits.shape[1]], np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


def _edges_at(bits, keep_words, row_start, ks):
    """`triangle_kernels.edges_at` from the listed pairs."""
    keep = unpack_rows(keep_words[None, :], len(bits))[0]
    ii, jj = consistency.upper_pairs(bits, keep)
    return ii[ks], jj[ks]


def _local_counts(src, dst, order, cell_start, point_cell, near_cells, radius, tau, neighbor):
    return consistency.local_counts(src, dst, tau, radius, _form(neighbor))


def _local_prune(src, dst, order, cell_start, point_cell, near_cells, radius, tau, neighbor,
                 eta, self_vote):  # fmt: skip
    return consistency.prune_local(src, dst, tau, eta, radius, _form(neighbor), self_vote)


def _graph(positions, labels) -> SimpleNamespace:
    return SimpleNamespace(positions=positions, labels=labels)


def _canonical_form(positions, labels, classes, radius, run):
    order, renumbered = maps.canonical_form(_graph(positions, labels), classes)
    return order, renumbered, False


def _first_of_duplicates(order, positions, labels, radius, run):
    return maps.without_duplicates(_graph(positions, labels), order), False


def _near_class_counts(query, points, labels, n_classes, radius, weights, grid=None):
    """`neighbor_kernels.near_class_counts` by KD-trees."""
    if len(points) == 0 or len(query) == 0:
        return np.zeros((len(query), n_classes)), np.zeros((len(query), n_classes))
    model = SimpleNamespace(positions=points, labels=labels, n_classes=n_classes, radius=radius)
    w = weights if len(weights) == len(points) else np.zeros(len(points))
    counts, summed = acceptance.near_counts(model, query, (None, w))
    return counts.astype(np.float64), summed


class _Uniforms:
    """A generator stand-in handing out the given uniforms in order."""

    def __init__(self, u: np.ndarray) -> None:
        self.u, self.at = u, 0

    def random(self, size: int) -> np.ndarray:
        self.at += size
        return self.u[self.at - size : self.at]


def _walk_histograms(indptr, indices, labels, u, n_walks, walk_length, n_classes):
    from scipy import sparse

    n = len(indptr) - 1
    graph = SimpleNamespace(adjacency=sparse.csr_array((np.ones(len(indices)), indices, indptr),
                                                       shape=(n, n)), labels=labels)  # fmt: skip
    desc = SimpleNamespace(n_walks=n_walks, walk_length=walk_length)
    H = descriptors.random_walks(desc, graph, n_classes, _Uniforms(u))
    return H.indptr.astype(np.int64), H.indices.astype(np.int64), H.data


def _irls_model(src, dst, T, prior, iterations, dof, max_tilt):
    return estimation.irls_refine(src, dst, T, prior, iterations, dof, max_tilt or None)


def _irls_class_scaled(src, dst, T, prior, cls, n_cls, height_only, iterations, dof, max_tilt,
                       min_matches, min_ratio):  # fmt: skip
    return estimation.irls_refine(src, dst, T, prior, iterations, dof, max_tilt or None, cls,
                                  "height" if height_only else "full")  # fmt: skip


def _xy_axis(points):
    return (np.nan, np.nan, np.nan, np.nan,
            acceptance.inlier_spread(points, 4) * np.sqrt(len(points)))  # fmt: skip


def _chance_sums(qi, tlab, inlier, counts, used, class_count, labels):
    chance = SimpleNamespace(
        class_count=class_count,
        expected_inliers=lambda c, q, t: float(np.sum(c[q, t] / class_count[t])),
    )
    return acceptance.chance_terms(labels, counts, used, qi, tlab, inlier, chance)


def _object_fits(res2, qi, rows, n_objects, limits):
    from sgloc.acceptance.chance import per_object_min

    ordered = np.sort(per_object_min(res2[rows], qi[rows]))
    within = np.searchsorted(ordered, limits, side="left")
    tops = np.array([ordered[k - 1] if k else -1.0 for k in within])
    return within, tops


def _best_yaw_alternative(src, dst, i, j, free, T, metres, degrees, radius):
    cfg = SimpleNamespace(distinct_translation=metres, distinct_rotation=degrees)
    count, T2 = acceptance.yaw_runner_up(src, dst, T, ~free, i, j, radius, cfg)
    return count, (np.eye(4) if T2 is None else T2), T2 is not None


def _ransac_compiled(src, dst, config=None, rng=None, weights=None):
    from sgloc.estimation.ransac import ransac_reference

    return ransac_reference(src, dst, config, rng, weights)


#: (module, name) -> the reference taking the kernel's place.
REPLACEMENTS = {
    ("sgloc.consistency.pairwise_kernels", "consistency_bits"):
        lambda src, dst, tau, nb: consistency.consistency_bits(src, dst, tau, _form(nb)),
    ("sgloc.consistency.triangle_kernels", "upper_edges"):
        lambda bits, degree: consistency.upper_pairs(bits),
    ("sgloc.consistency.triangle_kernels", "common_counts"): consistency.common_partner_count,
    ("sgloc.consistency.triangle_kernels", "kept_starts"): _kept_starts,
    ("sgloc.consistency.triangle_kernels", "edges_at"): _edges_at,
    ("sgloc.consistency.local_kernels", "local_counts"): _local_counts,
    ("sgloc.consistency.local_kernels", "local_prune"): _local_prune,
    ("sgloc.rejection.prune_kernels", "prune_bits"):
        lambda bits, degree, eta: rejection.prune_by_support(unpack_rows(bits, len(bits)), eta),
    ("sgloc.maps.canonical_kernels", "canonical_order_kernel"):
        lambda positions, labels: maps.canonical_order(_graph(positions, labels)),
    ("sgloc.maps.canonical_kernels", "canonical_form"): _canonical_form,
    ("sgloc.maps.canonical_kernels", "first_of_duplicates"): _first_of_duplicates,
    ("sgloc.maps.canonical_kernels", "restored_pairs"): maps.restored_pairs,
    ("sgloc.maps.neighbor_kernels", "distance_histograms"): descriptors.histograms_at,
    ("sgloc.maps.neighbor_kernels", "near_class_counts"): _near_class_counts,
    ("sgloc.descriptors.walk_kernels", "walk_histograms"): _walk_histograms,
    ("sgloc.estimation.fit_kernels", "irls_model"): _irls_model,
    ("sgloc.estimation.fit_kernels", "irls_class_scaled"): _irls_class_scaled,
    ("sgloc.estimation.ransac", "ransac_compiled"): _ransac_compiled,
    ("sgloc.acceptance.evidence_kernels", "reflect_xy"): acceptance.reflect_across_line,
    ("sgloc.acceptance.evidence_kernels", "xy_axis"): _xy_axis,
    ("sgloc.acceptance.evidence_kernels", "moved_residuals"):
        lambda T, src, dst: acceptance.squared_residuals_of(T, src, dst),
    ("sgloc.acceptance.evidence_kernels", "chance_sums"): _chance_sums,
    ("sgloc.acceptance.evidence_kernels", "object_fits"): _object_fits,
    ("sgloc.acceptance.runner_up_kernels", "best_yaw_alternative"): _best_yaw_alternative,
    ("sgloc.matching.candidates", "_use_kernel"): lambda desc_q, desc_t: False,
}  # fmt: skip


@contextlib.contextmanager
def on_references() -> Iterator[None]:
    """Within the block, every kernel that has a numpy reference is replaced by it."""
    saved = []
    try:
        for (module_name, name), reference in REPLACEMENTS.items():
            module = importlib.import_module(module_name)
            saved.append((module, name, getattr(module, name)))
            setattr(module, name, reference)
        yield
    finally:
        for module, name, original in reversed(saved):
            setattr(module, name, original)
