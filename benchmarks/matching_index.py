"""The candidate search's index against the exact search (`MatchingConfig.search`): recall of
the exact best matches, and the end-to-end effect on `localize`, on generated city maps (as
`python -m benchmarks.speed --only scale` builds them) and on the KITTI object maps.

    python -m benchmarks.matching_index [--sizes 10000 20000 50000 90000] [--kitti]
                                        [--update-docs]

Prints a markdown page; `--update-docs` writes it to docs/candidate_search.md.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sgloc import LocalizerConfig, localize
from sgloc.geometry import transform_error
from sgloc.matching.candidates import MatchingConfig, match_flagged
from sgloc.sim.object_world import make_two_robot_scene


def scene(n: int):
    """Two maps of about n objects each, as the scale benchmark builds them."""
    return make_two_robot_scene(seed=0, overlap=0.5, stretch=n / 0.47, view_radius=130.0)


def recall(desc_q, desc_t, lq, lt, probes: int | None = None) -> tuple[float, float, float]:
    """(share of the exact best matches the index finds, exact s, index s)."""
    t0 = time.perf_counter()
    exact = match_flagged(desc_q, desc_t, lq, lt, MatchingConfig(search="exact"))[0]
    t1 = time.perf_counter()
    cfg = MatchingConfig(search="index", **({} if probes is None else {"probes": probes}))
    found = match_flagged(desc_q, desc_t, lq, lt, cfg)[0]
    t2 = time.perf_counter()
    n = max(int(desc_t.shape[0]), 1)
    hit = np.isin(exact[:, 0] * n + exact[:, 1], found[:, 0] * n + found[:, 1])
    return float(hit.mean()) if len(hit) else 1.0, t1 - t0, t2 - t1


def end_to_end(q, t, T_gt, search: str) -> str:
    """'localized, t_err x m, r_err y deg, s' of one localize call with this search."""
    config = LocalizerConfig().with_overrides(search=search)
    t0 = time.perf_counter()
    res = localize(q, t, config=config, seed=0)
    s = time.perf_counter() - t0
    if res.transform is None:
        return f"not localized, {s:.2f} s"
    te, re = transform_error(res.transform, T_gt)
    said = "localized" if res.accepted else "not localized"
    return f"{said}, {te:.2f} m, {re:.2f} deg, {s:.2f} s"


def city_rows(sizes: list[int]) -> list[str]:
    cfg = LocalizerConfig()
    rows = []
    for n in sizes:
        sc = scene(n)
        L = int(max(sc.query.labels.max(), sc.target.labels.max())) + 1
        rng = np.random.default_rng(0)
        dq = cfg.descriptor_config(sc.query, L, rng)
        dt = cfg.descriptor_config(sc.target, L, rng)
        r, te, ti = recall(dq, dt, sc.query.labels, sc.target.labels)
        ex = end_to_end(sc.query, sc.target, sc.T_target_query, "exact")
        au = end_to_end(sc.query, sc.target, sc.T_target_query, "auto")
        rows.append(f"| city {n:,} | {r:.3f} | {te:.2f} / {ti:.2f} | {ex} | {au} |")
    return rows


def kitti_rows() -> list[str]:
    """Recall on KITTI 00's object maps (`sgloc.evaluation.pairs_kitti.kitti_graph`): the
    first half of the sequence's scans as the query, the second as the target."""
    from sgloc.evaluation.pairs_kitti import kitti_graph, kitti_root

    root = kitti_root()
    q, t = kitti_graph(root, 0, 2270), kitti_graph(root, 2271, 4540)
    L = int(max(q.labels.max(), t.labels.max())) + 1
    cfg, rng = LocalizerConfig(), np.random.default_rng(0)
    dq, dt = cfg.descriptor_config(q, L, rng), cfg.descriptor_config(t, L, rng)
    r, te, ti = recall(dq, dt, q.labels, t.labels)
    return [f"| KITTI 00 scans 0-2270 / 2271-4540 ({len(q):,}, {len(t):,} objects) | {r:.3f} "
            f"| {te:.3f} / {ti:.3f} | - | - |"]  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="*", default=[10_000, 20_000, 50_000, 90_000])
    ap.add_argument("--kitti", action="store_true")
    ap.add_argument("--update-docs", action="store_true", help="write docs/candidate_search.md")
    args = ap.parse_args()
    localize(scene(2000).query, scene(2000).target, seed=0)  # loads the kernels (not timed)
    head = [
        "# Candidate search: the index against the exhaustive search", "",
        "Matching keeps, per query object, its most similar same-class target objects "
        "(cosine similarity of descriptors). The exhaustive search compares every pair, so "
        "two maps of n objects cost n^2. With `search=\"auto\"` (the default) a class with "
        "more than 4,096 target objects is searched through an index instead "
        "(`sgloc.matching.index`): the class's unit descriptors grouped into about sqrt(n) "
        "lists by spherical k-means, each query object compared with the objects of its "
        "`probes` (8) most similar lists only, with the same similarity values as the "
        "exhaustive search; every smaller class is searched exhaustively, so smaller maps "
        "keep their exact results. `search=\"exact\"` (and the `paper` preset) compares "
        "every pair; `search=\"index\"` uses the index for every class. A prepared map "
        "(`sgloc.prepare`) builds the index once.", "",
        "Command: `python -m benchmarks.matching_index --sizes "
        + " ".join(str(n) for n in args.sizes) + (" --kitti" if args.kitti else "") + "` "
        f"({time.strftime('%Y-%m-%d')}). Recall: the share of the exact search's best matches "
        "(`search=\"exact\"`, top_k 1) that the index (`search=\"index\"`, default probes) also "
        "returns; matching seconds of both (exact / index, matching alone, descriptors given). "
        "End to end: `localize` with `search=\"exact\"` and with the default "
        "`search=\"auto\"` on the same maps (translation error, rotation error, wall seconds).",
        "",
        "| maps | recall | matching s exact / index | exact end to end | auto end to end |",
        "|---|---|---|---|---|",
    ]  # fmt: skip
    rows = city_rows(args.sizes) + (kitti_rows() if args.kitti else [])
    text = "\n".join(head + rows + [""])
    print(text)
    if args.update_docs:
        Path("docs/candidate_search.md").write_text(text)


if __name__ == "__main__":
    main()
