"""Localize a fleet of N robots into one common frame.

1. Every pair of robots is localized (in parallel: local processes, or an existing Dask cluster).
2. Only pairs that pass the acceptance test (`sgloc.acceptance`) are kept.
3. A maximum-confidence spanning tree over the kept pairs places the robots of the largest
   connected group, rooted at its best-connected robot (the world frame is that robot's frame).
4. Cycle check: every kept pair outside the tree is compared with the transform composed along
   the tree; when a loop disagrees (by more than `cycle_translation` metres, measured as the
   RMS displacement of the robot's objects, or `cycle_rotation` degrees), the pair that takes
   part in the most disagreeing loops (ties: the least confident) is dropped and the tree is
   rebuilt, until every loop agrees.
5. Robots outside the placed group are reported as unplaced. The placed robots' objects are
   merged into one graph, fusing same-class objects closer than `fuse_radius` metres.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from sgloc.config import LocalizerConfig
from sgloc.errors import SglocError
from sgloc.estimation import icp_refine
from sgloc.geometry import apply, invert, rotation_angle_deg
from sgloc.graph import SemanticGraph


@dataclass
class FleetConfig:
    """Settings of `localize_fleet`.

    localizer: the pairwise pipeline (its `acceptance` decides which pairs are kept).
    cycle_translation, cycle_rotation: metres / degrees a loop may disagree by.
    fuse_radius: metres; same-class objects of the merged map closer than this are fused.
    refine, refine_distance: after placement, refine each robot's pose by ICP against the
        other placed robots' objects (same-class pairs within refine_distance metres).
    seed: pair (i, j) is localized with the seed [seed, i, j].
    """

    localizer: LocalizerConfig = field(default_factory=LocalizerConfig)
    cycle_translation: float = 3.0
    cycle_rotation: float = 3.0
    fuse_radius: float = 2.0
    refine: bool = True
    refine_distance: float = 3.0
    seed: int = 0


@dataclass
class PairLink:
    """Outcome of localizing robot `query` against robot `target`: T_target_query when
    `accepted`; `confidence` from the acceptance test; `reason` when not accepted or dropped."""

    query: int
    target: int
    accepted: bool
    transform: np.ndarray | None
    confidence: float
    n_matches: int
    reason: str = ""
    seconds: float = 0.0
    used: str = ""  # "tree", "loop" (consistent non-tree pair), "dropped" or ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "query": self.query,
            "target": self.target,
            "accepted": self.accepted,
            "confidence": self.confidence,
            "n_matches": self.n_matches,
            "used": self.used,
            "reason": self.reason,
            "transform": None if self.transform is None else self.transform.tolist(),
        }


@dataclass
class FleetResult:
    """Robots placed in one frame (the frame of robot `root`).

    T_world_robot: {robot index: 4x4} for the placed robots (p_world = T @ p_robot).
    unplaced: robot indices that could not be placed, with `unplaced_reason`.
    links: every pairwise localization; `merged`: the fused map of the placed robots, with
    `merged_robot` (n,) the robot that first contributed each merged object.
    """

    names: list[str]
    root: int | None
    T_world_robot: dict[int, np.ndarray]
    unplaced: list[int]
    unplaced_reason: dict[int, str]
    links: list[PairLink]
    merged: SemanticGraph | None
    merged_robot: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def placed(self) -> list[int]:
        return sorted(self.T_world_robot)

    def to_dict(self) -> dict[str, Any]:
        return {
            "robots": self.names,
            "root": self.root,
            "placed": {self.names[i]: T.tolist() for i, T in sorted(self.T_world_robot.items())},
            "unplaced": {self.names[i]: self.unplaced_reason.get(i, "") for i in self.unplaced},
            "links": [
                {
                    **lk.to_dict(),
                    "query_name": self.names[lk.query],
                    "target_name": self.names[lk.target],
                }
                for lk in self.links
            ],
            "merged_objects": 0 if self.merged is None else len(self.merged),
            "timings": self.timings,
        }


# -- pairwise stage --------------------------------------------------------------------------
def _localize_task(task: tuple) -> dict[str, Any]:
    """Worker: localize one pair (graphs passed as arrays, so any process or Dask worker can)."""
    import time

    from sgloc.localizer import Localizer

    (i, qpos, qlab, qr, j, tpos, tlab, tr, cfg_dict, seed) = task
    t0 = time.perf_counter()
    q = SemanticGraph(qpos, qlab, qr, name=f"robot{i}")
    t = SemanticGraph(tpos, tlab, tr, name=f"robot{j}")
    try:
        res = Localizer(LocalizerConfig.from_dict(cfg_dict))(q, t, np.random.default_rng(seed))
        out = {
            "accepted": bool(res.success),
            "transform": res.transform,
            "confidence": float(res.confidence or 0.0),
            "n_matches": int(len(res.matches)),
            "reason": res.reason,
        }
    except SglocError as e:
        out = {
            "accepted": False,
            "transform": None,
            "confidence": 0.0,
            "n_matches": 0,
            "reason": str(e),
        }
    out.update(query=i, target=j, seconds=time.perf_counter() - t0)
    return out


def _run_tasks(tasks: list[tuple], scheduler: str | None, workers: int | None) -> list[dict]:
    if scheduler:
        from sgloc.optional import require

        Client = require("distributed", "dask", "--scheduler (a Dask cluster)").Client
        try:
            client = Client(scheduler, timeout=10)
        except (OSError, ValueError, TypeError) as e:  # unreachable or malformed address
            raise SglocError(
                f"cannot reach the Dask scheduler at {scheduler!r} ({e}); start one with "
                "`dask scheduler` or omit --scheduler to use local processes."
            ) from None
        try:
            return client.gather(client.map(_localize_task, tasks, pure=False))
        finally:
            client.close()
    n = workers if workers is not None else (os.cpu_count() or 1)
    if n <= 1 or len(tasks) <= 1:
        return [_localize_task(t) for t in tasks]
    with ProcessPoolExecutor(max_workers=min(n, len(tasks))) as pool:
        return list(pool.map(_localize_task, tasks, chunksize=max(1, len(tasks) // (4 * n))))


# -- frame building --------------------------------------------------------------------------
def _spanning_tree(n: int, edges: list[PairLink]) -> list[PairLink]:
    """Kruskal on descending confidence (to 1e-6; ties: more matches): a maximum-confidence
    forest."""
    parent = list(range(n))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    tree = []
    # Confidence saturates near 1 for strong pairs: rank it to 1e-6, then by matches.
    for e in sorted(
        edges, key=lambda e: (-round(e.confidence, 6), -e.n_matches, e.query, e.target)
    ):
        ra, rb = find(e.query), find(e.target)
        if ra != rb:
            parent[ra] = rb
            tree.append(e)
    return tree


def _place(
    n: int, tree: list[PairLink], root: int
) -> tuple[dict[int, np.ndarray], dict[int, list]]:
    """T_world_robot for the tree component of `root`, and each robot's tree path (edges)."""
    adj: dict[int, list[PairLink]] = {}
    for e in tree:
        adj.setdefault(e.query, []).append(e)
        adj.setdefault(e.target, []).append(e)
    poses = {root: np.eye(4)}
    paths: dict[int, list] = {root: []}
    stack = [root]
    while stack:
        a = stack.pop()
        for e in adj.get(a, []):
            b = e.target if e.query == a else e.query
            if b in poses:
                continue
            # e.transform = T_target_query.
            poses[b] = poses[a] @ (e.transform if b == e.query else invert(e.transform))
            paths[b] = paths[a] + [e]
            stack.append(b)
    return poses, paths


def _disagreement(T_a: np.ndarray, T_b: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """(RMS displacement of `points` between T_a and T_b in metres, rotation angle in deg)."""
    d = apply(T_a, points) - apply(T_b, points)
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1)))), rotation_angle_deg(
        T_a[:3, :3].T @ T_b[:3, :3]
    )


def build_common_frame(
    graphs: Sequence[SemanticGraph], links: list[PairLink], config: FleetConfig
) -> tuple[int | None, dict[int, np.ndarray], dict[int, str]]:
    """Spanning tree + cycle check over the accepted links (marks each link's `used`).

    Returns (root, T_world_robot of the placed robots, reasons for the unplaced ones)."""
    n = len(graphs)
    active = [lk for lk in links if lk.accepted and lk.transform is not None]
    while True:
        tree = _spanning_tree(n, active)
        if not active:
            break
        # Largest group (ties: most total confidence); root = its best-connected robot.
        rows = [e.query for e in tree] + [e.target for e in tree]
        cols = [e.target for e in tree] + [e.query for e in tree]
        _, comp = connected_components(
            sparse.coo_array((np.ones(len(rows)), (rows, cols)), shape=(n, n))
        )
        sizes = np.bincount(comp)
        conf_sum = np.zeros(n)
        for e in active:
            conf_sum[e.query] += e.confidence
            conf_sum[e.target] += e.confidence
        group_score = [(sizes[c], conf_sum[comp == c].sum()) for c in range(len(sizes))]
        best = max(range(len(sizes)), key=lambda c: group_score[c])
        members = np.flatnonzero(comp == best)
        root = int(members[np.argmax(conf_sum[members])])
        poses, paths = _place(n, tree, root)
        tree_ids = {id(e) for e in tree}
        bad_votes: dict[int, int] = {}
        good_votes: dict[int, int] = {}
        by_id = {id(e): e for e in active}
        any_bad = False
        for e in active:
            if id(e) in tree_ids or e.query not in poses or e.target not in poses:
                continue
            T_path = invert(poses[e.target]) @ poses[e.query]
            dt, dr = _disagreement(e.transform, T_path, graphs[e.query].positions)
            loop = [e] + _path_between(paths, e.query, e.target)
            bad = dt > config.cycle_translation or dr > config.cycle_rotation
            any_bad |= bad
            votes = bad_votes if bad else good_votes
            for f in loop:
                votes[id(f)] = votes.get(id(f), 0) + 1
        if not any_bad:
            break
        worst = max(
            bad_votes,
            key=lambda k: (bad_votes[k], -good_votes.get(k, 0), -by_id[k].confidence),
        )
        w = by_id[worst]
        w.used = "dropped"
        w.reason = (
            f"dropped: disagrees around {bad_votes[worst]} loop(s) by more than "
            f"{config.cycle_translation} m / {config.cycle_rotation} deg"
        )
        active = [e for e in active if id(e) != worst]
    if not active:
        reasons = {i: "no accepted pair links this robot to another" for i in range(n)}
        if n:
            reasons.pop(0)
            return 0, {0: np.eye(4)}, reasons
        return None, {}, {}
    for e in active:
        e.used = "tree" if id(e) in tree_ids else "loop"
    reasons = {}
    for i in range(n):
        if i not in poses:
            linked = any(lk.accepted and i in (lk.query, lk.target) for lk in links)
            reasons[i] = (
                "its accepted pairs link it only to robots outside the placed group"
                if linked and any(i in (e.query, e.target) for e in active)
                else "its accepted pairs were dropped by the cycle check"
                if linked
                else "no pair with this robot passed the acceptance test"
            )
    return root, poses, reasons


def _path_between(paths: dict[int, list], a: int, b: int) -> list:
    """Tree edges on the path a-b (the symmetric difference of their root paths)."""
    ia, ib = {id(e) for e in paths[a]}, {id(e) for e in paths[b]}
    return [e for e in paths[a] if id(e) not in ib] + [e for e in paths[b] if id(e) not in ia]


def refine_poses(
    graphs: Sequence[SemanticGraph],
    T_world_robot: dict[int, np.ndarray],
    root: int | None,
    max_distance: float,
) -> dict[int, np.ndarray]:
    """One ICP pass per placed robot (root fixed) against all other placed robots' objects."""
    out = dict(T_world_robot)
    for i in sorted(out):
        others = [j for j in out if j != i]
        if i == root or not others:
            continue
        dst = np.concatenate([apply(out[j], graphs[j].positions) for j in others])
        dlab = np.concatenate([graphs[j].labels for j in others])
        out[i] = icp_refine(graphs[i].positions, graphs[i].labels, dst, dlab, out[i], max_distance)
    return out


# -- merging ---------------------------------------------------------------------------------
def merge_graphs(
    graphs: Sequence[SemanticGraph],
    T_world_robot: dict[int, np.ndarray],
    fuse_radius: float,
    name: str = "fleet",
) -> tuple[SemanticGraph, np.ndarray, np.ndarray, np.ndarray]:
    """Placed robots' objects in the world frame, same-class objects closer than `fuse_radius`
    fused (mean position, single-linkage groups).

    Returns (merged graph, robot of each merged object (first contributor), all objects' world
    positions (N,3), robot of each of those (N,))."""
    ids = sorted(T_world_robot)
    if not ids:
        return SemanticGraph(np.zeros((0, 3)), np.zeros(0, np.int64), name=name), *(
            np.zeros(0, np.int64),
        ) * 3
    pos = np.concatenate([apply(T_world_robot[i], graphs[i].positions) for i in ids])
    lab = np.concatenate([graphs[i].labels for i in ids])
    rob = np.concatenate([np.full(len(graphs[i]), i) for i in ids])
    radius = graphs[ids[0]].edge_radius
    offset = 4.0 * (np.abs(pos).max() + fuse_radius) + 1.0 if len(pos) else 1.0
    from scipy.spatial import cKDTree  # deferred: scipy.spatial loads in ~0.2 s

    pairs = cKDTree(np.column_stack([pos, lab * offset])).query_pairs(
        fuse_radius, output_type="ndarray"
    )
    # Fuse only objects of different robots (a robot's own map already merged its duplicates).
    pairs = pairs[rob[pairs[:, 0]] != rob[pairs[:, 1]]] if len(pairs) else pairs
    n = len(pos)
    adj = (
        sparse.coo_array((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        if len(pairs)
        else sparse.coo_array((n, n))
    )
    k, group = connected_components(adj, directed=False)
    counts = np.bincount(group, minlength=k).astype(np.float64)
    mpos = (
        np.stack([np.bincount(group, pos[:, d], minlength=k) for d in range(3)], axis=1)
        / counts[:, None]
    )
    first = np.full(k, n)
    np.minimum.at(first, group, np.arange(n))
    merged = SemanticGraph(mpos, lab[first], radius, name=name)
    return merged, rob[first], pos, rob


def plot_fleet(result: FleetResult, graphs: Sequence[SemanticGraph], path: str | Path) -> Path:
    """PNG of the merged map, top-down (x right, y up): each placed robot's objects with its
    own marker and colour, the fused objects as rings; unplaced robots named in the title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sgloc.viz import CLASS_PALETTE, ROBOT_MARKERS, top_down

    fig, ax = plt.subplots(figsize=(7.5, 6), dpi=100)
    for i in result.placed:
        p = apply(result.T_world_robot[i], graphs[i].positions)
        root = " (world frame)" if i == result.root else ""
        ax.scatter(p[:, 0], p[:, 1], s=9, color=CLASS_PALETTE[i % len(CLASS_PALETTE)],
                   marker=ROBOT_MARKERS[i % len(ROBOT_MARKERS)], alpha=0.75,
                   label=f"{result.names[i]}{root}")
    if result.merged is not None and len(result.merged):
        ax.scatter(*result.merged.positions[:, :2].T, s=20, facecolors="none", edgecolors="k",
                   linewidths=0.3, label=f"merged map, {len(result.merged)} objects")
    title = f"{len(result.placed)} of {len(result.names)} robots placed"
    if result.unplaced:
        title += " (unplaced: " + ", ".join(result.names[i] for i in result.unplaced) + ")"
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, markerscale=1.5, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              frameon=False)
    top_down(ax)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


# -- the whole job ---------------------------------------------------------------------------
def localize_fleet(
    graphs: Sequence[SemanticGraph],
    config: FleetConfig | None = None,
    *,
    names: Sequence[str] | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    out: str | Path | None = None,
) -> FleetResult:
    """Place N robots' graphs in one frame (module docstring).

    Args:
        graphs: the robots' semantic graphs, each in its own frame (metres).
        config: FleetConfig (pairwise localizer with acceptance, cycle tolerances, fusion radius).
        names: robot names (default: the graphs' names).
        scheduler: address of an existing Dask scheduler (e.g. "tcp://10.0.0.5:8786"); None runs
            the pairs on local processes.
        workers: local processes (default: CPU count; 0 or 1 runs in this process).
        out: folder to write `merged.json` (the fused graph), `fleet.json` (poses, links,
            unplaced robots) and `fleet.png`.
    """
    import json
    import time

    cfg = config or FleetConfig()
    graphs = list(graphs)
    if len(graphs) < 2:
        raise SglocError(f"a fleet needs at least 2 robot graphs, got {len(graphs)}.")
    for g in graphs:
        if not isinstance(g, SemanticGraph):
            raise SglocError(f"every robot must be a SemanticGraph, got {type(g).__name__}.")
    names = list(names) if names is not None else [g.name for g in graphs]
    if len(set(names)) != len(names):
        names = [f"{nm}#{i}" for i, nm in enumerate(names)]
    t0 = time.perf_counter()
    cfg_dict = cfg.localizer.to_dict()
    tasks = [
        (
            i,
            gi.positions,
            gi.labels,
            gi.edge_radius,
            j,
            gj.positions,
            gj.labels,
            gj.edge_radius,
            cfg_dict,
            [cfg.seed, i, j],
        )
        for i, gi in enumerate(graphs)
        for j, gj in enumerate(graphs)
        if i < j
    ]
    raw = _run_tasks(tasks, scheduler, workers)
    links = [PairLink(**r) for r in sorted(raw, key=lambda r: (r["query"], r["target"]))]
    t1 = time.perf_counter()
    root, poses, reasons = build_common_frame(graphs, links, cfg)
    if cfg.refine:
        poses = refine_poses(graphs, poses, root, cfg.refine_distance)
    merged, merged_robot, _, _ = merge_graphs(graphs, poses, cfg.fuse_radius)
    t2 = time.perf_counter()
    result = FleetResult(
        names=names,
        root=root,
        T_world_robot=poses,
        unplaced=sorted(reasons),
        unplaced_reason=reasons,
        links=links,
        merged=merged,
        merged_robot=merged_robot,
        timings={"pairs": t1 - t0, "frame_and_merge": t2 - t1},
    )
    if out is not None:
        d = Path(out)
        d.mkdir(parents=True, exist_ok=True)
        merged.save(d / "merged.json")
        (d / "fleet.json").write_text(json.dumps(result.to_dict(), indent=1))
        write_fleet_poses(result, d)
        cfg.localizer.to_yaml(d / "config.yaml")
        plot_fleet(result, graphs, d / "fleet.png")
    return result


def write_fleet_poses(result: FleetResult, folder: str | Path) -> list[Path]:
    """Each placed robot's pose T_world_robot as TUM and KITTI files (for evo and friends):
    `poses/<robot>.tum` and `poses/<robot>.kitti` (one line each), and `poses.tum` /
    `poses.kitti` with every placed robot, one line each, the TUM timestamp = the robot's
    index in `names` (the KITTI rows in the same order)."""
    from sgloc.io.poses import write_kitti_poses, write_tum_poses

    d = Path(folder)
    placed = sorted(result.T_world_robot)
    T = np.array([result.T_world_robot[i] for i in placed]).reshape(-1, 4, 4)
    files = [write_tum_poses(d / "poses.tum", np.array(placed, float), T),
             write_kitti_poses(d / "poses.kitti", T)]
    for k, i in enumerate(placed):
        stem = Path(result.names[i]).stem or f"robot{i}"
        files.append(write_tum_poses(d / "poses" / f"{stem}.tum", np.array([float(i)]), T[k:k + 1]))
        files.append(write_kitti_poses(d / "poses" / f"{stem}.kitti", T[k:k + 1]))
    return files
