"""Extraction benchmark: image throughput and the KITTI 00 two-robot localization.

    python benchmarks/extraction.py [--seeds 20] [--out docs/extraction_benchmark.md]

1. Segmentation + back-projection + association on synthetic blocky semantic/depth images
   (40 boxes of 11 classes a frame, depth ramps), frames/s at 320x180 and 1024x576 (median of
   repeats, in-process).
2. KITTI 00 LiDAR objects: robot A = scans 0-800, robot B = scans 3900-4540, each in its own
   start frame; graph sizes, B objects with a same-class A object within 2 m under the
   ground truth, and B->A / A->B localization over seeds for the preset and the paper defaults.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.spatial.distance import cdist

from sgloc import localize
from sgloc.datasets import Frame, make_dataset
from sgloc.datasets.downloads import data_path
from sgloc.extraction import (
    ExtractionConfig,
    build_graph,
    extraction_preset,
)
from sgloc.geometry import transform_error
from sgloc.pipeline.presets import localizer_preset


def blocky_frame(rng: np.random.Generator, H: int, W: int, index: int) -> Frame:
    sem = np.full((H, W), -1)
    dep = np.full((H, W), np.inf)
    for _ in range(40):
        h, w = rng.integers(H // 20, H // 3), rng.integers(W // 20, W // 4)
        y, x = rng.integers(0, H - h), rng.integers(0, W - w)
        sem[y : y + h, x : x + w] = rng.integers(0, 11)
        dep[y : y + h, x : x + w] = rng.uniform(3, 40) + np.linspace(0, 2, w)[None]
    K = np.array([[W / 2, 0, W / 2], [0, W / 2, H / 2], [0, 0, 1.0]])
    return Frame(index, np.eye(4), semantic=sem, depth=dep, K=K)


def image_throughput(n_frames: int = 30, repeats: int = 3) -> list[tuple[str, float, int]]:
    rng = np.random.default_rng(0)
    rows = []
    for W, H in ((320, 180), (1024, 576)):
        frames = [blocky_frame(rng, H, W, i) for i in range(n_frames)]
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            g = build_graph(frames, ExtractionConfig())
            times.append(time.perf_counter() - t)
        rows.append((f"{W}x{H}", n_frames / float(np.median(times)), len(g)))
    return rows


def kitti(seeds: int) -> list[tuple]:
    root = data_path("kitti00")
    t = time.perf_counter()
    a = make_dataset("kitti_objects", root, scans="0-800", start_frame=True)
    b = make_dataset("kitti_objects", root, scans="3900-4540", start_frame=True)
    t_parse = time.perf_counter() - t
    a_w = make_dataset("kitti_objects", root, scans="0-800")
    b_w = make_dataset("kitti_objects", root, scans="3900-4540")
    T_gt = np.linalg.inv(a_w.poses[0]) @ b_w.poses[0]
    rows = []
    for name, cfg in (
        ("preset (3 m, >=2 obs)", extraction_preset("kitti-objects")),
        ("defaults (5 m, >=1 obs)", ExtractionConfig()),
    ):
        t = time.perf_counter()
        ga, gb = build_graph(a, cfg), build_graph(b, cfg)
        t_build = time.perf_counter() - t
        D = cdist(gb.transformed(T_gt).positions, ga.positions)
        D[gb.labels[:, None] != ga.labels[None, :]] = np.inf
        overlap = int((D.min(axis=1) < 2.0).sum())
        for direction, q, tg, G in (("B->A", gb, ga, T_gt), ("A->B", ga, gb, np.linalg.inv(T_gt))):
            errs, ok = [], 0
            for s in range(seeds):
                r = localize(q, tg, seed=s, config=localizer_preset("kitti-objects"))
                if r.accepted:
                    e = transform_error(r.transform, G)
                    errs.append(e)
                    ok += e[0] < 3 and e[1] < 3
            med = np.median(errs, axis=0) if errs else (np.nan, np.nan)
            rows.append(
                (name, f"{len(ga)} / {len(gb)}", overlap, direction, f"{ok}/{seeds}",
                 f"{med[0]:.2f} m, {med[1]:.2f} deg", f"{t_build:.2f}")
            )  # fmt: skip
    rows.append(("archive parse (s)", f"{t_parse:.2f}", "", "", "", "", ""))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", type=Path, default=Path("docs/extraction_benchmark.md"))
    args = ap.parse_args()
    console = Console()
    img = image_throughput()
    t1 = Table("image size", "frames/s", "vertices", title="image extraction throughput")
    for size, fps, n in img:
        t1.add_row(size, f"{fps:.1f}", str(n))
    console.print(t1)
    kit = kitti(args.seeds)
    head = ("extraction", "A / B vertices", "B objs < 2 m", "query->target", "within 3 m 3 deg",
            "median error", "build both (s)")  # fmt: skip
    t2 = Table(*head, title="KITTI 00 objects (localizer preset: ransac_threshold 2, tau 2)")
    for r in kit:
        t2.add_row(*map(str, r))
    console.print(t2)
    lines = ["# Extraction benchmark", "", "`python benchmarks/extraction.py`", "",
             "| image size | frames/s | vertices |", "|---|---|---|"]  # fmt: skip
    lines += [f"| {s} | {f:.1f} | {n} |" for s, f, n in img]
    lines += ["", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(map(str, r)) + " |" for r in kit]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    console.print(f"written {args.out}")


if __name__ == "__main__":
    main()
