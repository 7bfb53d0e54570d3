"""Consistency within a radius: the neighbour constraint at a cost linear in the candidates.

The all-pairs form (`sgloc.consistency.pairwise`) checks every pair of candidate matches: m^2 work
and m^2 / 8 bytes. Here two candidates are compared only when their query objects lie closer than
`radius` metres (the paper's neighbours), so work grows with m x the candidates within the
radius and memory with m. A candidate's support is the count of its spatial neighbours it is
consistent with; Alg. 1 removes the least supported fraction first (`prune_local`). With a
radius that covers the whole query map every candidate neighbours every other and the result
equals Alg. 1 on all pairs (`sgloc.rejection.neighbor.prune_bits`).

`local_counts` and `prune_local` run the compiled kernels (`sgloc.consistency.local_kernels`);
their dense numpy references live with the tests (`tests/references/`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.consistency.pairwise import check_form

#: Cells per axis at most: cells are widened beyond the radius when a map is wider than this
#: many radii, so that a cell's integer key (x, y, z) fits in an int64.
MAX_CELLS_PER_AXIS = 1 << 20


@dataclass(frozen=True)
class RadiusGrid:
    """Points bucketed on a grid of cells at least `radius` wide (every point within the
    radius of a point lies in one of the 27 cells around its cell).

    order: (m,) point indices sorted by cell; cell_start: (n_cells + 1,) each cell's run in
    `order`; point_cell: (m,) each point's cell; near_cells: (n_cells, 27) the occupied cells
    around each cell, -1 where there is none."""

    order: np.ndarray
    cell_start: np.ndarray
    point_cell: np.ndarray
    near_cells: np.ndarray

    @classmethod
    def build(cls, points: np.ndarray, radius: float) -> RadiusGrid:
        """The grid of `points` (m,3) metres for neighbours closer than `radius` metres."""
        points = np.asarray(points, dtype=np.float64)
        lo = points.min(axis=0) if len(points) else np.zeros(3)
        extent = (points.max(axis=0) - lo) if len(points) else np.zeros(3)
        width = max(float(radius), float(extent.max()) / (MAX_CELLS_PER_AXIS - 2), 1e-300)
        cell = np.floor((points - lo) / width).astype(np.int64)
        dims = cell.max(axis=0) + 3 if len(points) else np.ones(3, np.int64)
        # Keys with a margin of one cell on every side: a neighbour offset never wraps.
        key = ((cell[:, 0] + 1) * dims[1] + cell[:, 1] + 1) * dims[2] + cell[:, 2] + 1
        order = np.argsort(key, kind="stable")
        keys, start, point_cell = np.unique(key[order], return_index=True, return_inverse=True)
        cell_of = np.empty(len(points), dtype=np.int64)
        cell_of[order] = point_cell
        offsets = np.array(
            [(a * dims[1] + b) * dims[2] + c for a in (-1, 0, 1) for b in (-1, 0, 1)
             for c in (-1, 0, 1)], dtype=np.int64,
        )  # fmt: skip
        wanted = keys[:, None] + offsets[None, :]
        at = np.minimum(np.searchsorted(keys, wanted), len(keys) - 1)
        near = np.where(keys[at] == wanted, at, -1) if len(keys) else wanted[:, :0]
        return cls(
            order.astype(np.int64),
            np.append(start, len(points)).astype(np.int64),
            cell_of,
            np.ascontiguousarray(near, dtype=np.int64),
        )


def _kernel_args(src, dst, radius: float) -> tuple:
    src = np.ascontiguousarray(src, dtype=np.float64)
    dst = np.ascontiguousarray(dst, dtype=np.float64)
    g = RadiusGrid.build(src, radius)
    return src, dst, g.order, g.cell_start, g.point_cell, g.near_cells, float(radius)


def local_counts(
    src: np.ndarray, dst: np.ndarray, tau: float, radius: float, form: str = "distance"
) -> tuple[np.ndarray, np.ndarray]:
    """(r, V) int64 (m,): per candidate match i (src_i (m,3) query, dst_i target, metres), the
    other candidates whose query points lie closer than `radius` to src_i, and those of them
    consistent with i (`sgloc.consistency.pairwise` forms). Compiled; memory linear in m."""
    check_form(form)
    if len(src) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    from sgloc.consistency.local_kernels import local_counts as kernel

    return kernel(*_kernel_args(src, dst, radius), float(tau), form == "neighbor")


def prune_local(
    src: np.ndarray,
    dst: np.ndarray,
    tau: float,
    eta: float,
    radius: float,
    form: str = "distance",
    self_vote: int = 0,
) -> np.ndarray:
    """Sorted indices of the candidates that survive Alg. 1 on local supports: while the
    remaining candidate with the least support fraction (V_i + s) / (r_i + s) (ties: the lowest
    index) has V_i + s < eta * (r_i + s), remove it (r_i, V_i: `local_counts` among the
    remaining candidates; s = self_vote, 1 for the literal bound). Compiled."""
    check_form(form)
    if len(src) == 0:
        return np.zeros(0, dtype=np.int64)
    from sgloc.consistency.local_kernels import local_prune

    args = _kernel_args(src, dst, radius)
    return local_prune(*args, float(tau), form == "neighbor", float(eta), int(self_vote))

