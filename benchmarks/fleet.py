"""Fleet benchmark: place N robots in one frame and check every placement against ground truth.

    python benchmarks/fleet.py [--world-seeds 0 1 2 3 4] [--city] [--out docs]

Fleets: robots cut from the object world (6 per seed: a chain of 4 overlapping stretches and 2
stretches nobody else sees), robots = KITTI 00 scan ranges (6: some sharing scans, some
revisiting the same streets, some alone), and with --city robots cut from the rendered synthetic
city (two extracted robot maps, each split into 3 pieces along its route). A placed robot is
correct when within 3 m (at its objects' centroid) and 3 deg of the ground truth relative to the
root; "wrong" = placed beyond that. Writes docs/fleet.md and docs/fleet_*.png.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

from sgloc.datasets.downloads import present_or_say
from sgloc.evaluation.fleet_scenes import (
    FleetScene,
    city_fleet,
    expected_placeable,
    fleet_errors,
    kitti_fleet,
    world_fleet,
)
from sgloc.online.fleet import FleetConfig, localize_fleet
from sgloc.pipeline.config import LocalizerConfig

MAX_M, MAX_DEG = 3.0, 3.0


def run_fleet(
    name: str, scene: FleetScene, out: Path, workers: int | None, config: FleetConfig | None = None
) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = localize_fleet(scene.graphs, config, workers=workers, out=tmp)
        secs = time.perf_counter() - t0
        if config is None and not name.startswith("world") or name == "world0":
            shutil.copy(Path(tmp) / "fleet.png", out / f"fleet_{name}.png")
    errs = fleet_errors(res.T_fleet_robot, scene.T_gt_robot, res.root, scene.graphs)
    wrong = [i for i, (dt, dr) in errs.items() if dt > MAX_M or dr > MAX_DEG]
    oracle = expected_placeable(scene)
    # Robots with a real overlap (oracle) to some other robot: could be placed in principle.
    could = [i for i in range(len(scene.graphs)) if oracle[i].any()]
    worst = max((dt for i, (dt, _) in errs.items() if i != res.root), default=0.0)
    worst_r = max((dr for i, (_, dr) in errs.items() if i != res.root), default=0.0)
    dropped = sum(lk.used == "dropped" for lk in res.links)
    return {
        "name": name,
        "n": len(scene.graphs),
        "placed": res.placed,
        "unplaced": res.unplaced,
        "could": could,
        "wrong": wrong,
        "worst_m": worst,
        "worst_deg": worst_r,
        "accepted": sum(lk.accepted for lk in res.links),
        "pairs": len(res.links),
        "dropped": dropped,
        "seconds": secs,
        "errors": errs,
        "notes": scene.notes,
        "reasons": res.unplaced_reason,
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| fleet | robots | placed | unplaced (reported) | overlapping robots (oracle) | "
        "missed (oracle overlaps, unplaced) | wrong | worst error | pairs accepted | "
        "dropped by loops | s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['name']} | {r['n']} | {len(r['placed'])} | {r['unplaced']} | "
            f"{len(r['could'])} | {sorted(set(r['could']) - set(r['placed']))} | "
            f"{len(r['wrong'])} | {r['worst_m']:.2f} m / "
            f"{r['worst_deg']:.2f} deg | {r['accepted']}/{r['pairs']} | {r['dropped']} | "
            f"{r['seconds']:.1f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--world-seeds", type=int, nargs="*", default=[0, 1, 2, 3, 4])
    ap.add_argument("--city", action="store_true", help="also cut a fleet from the rendered city")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs")
    args = ap.parse_args(argv)
    docs = args.out.resolve() == Path(__file__).resolve().parents[1] / "docs"
    kitti = present_or_say("kitti00", "the KITTI 00 fleet", required=docs)
    warnings.filterwarnings("ignore", category=RuntimeWarning)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    fleets = [(f"world{s}", lambda s=s: world_fleet(s)) for s in args.world_seeds]
    fleets += [("kitti00", kitti_fleet)] if kitti else []
    if args.city:
        fleets.append(("city", city_fleet))
    guo = FleetConfig(localizer=LocalizerConfig().with_overrides(acceptance=False))
    baseline = []
    for name, make in fleets:
        scene = make()
        r = run_fleet(name, scene, args.out, args.workers)
        rows.append(r)
        print(
            f"{name}: placed {r['placed']} unplaced {r['unplaced']} wrong {r['wrong']} "
            f"worst {r['worst_m']:.2f} m {r['worst_deg']:.2f} deg ({r['seconds']:.1f} s)"
        )
        baseline.append(run_fleet(f"{name} (Guo's rule only)", scene, args.out, args.workers, guo))
    total_wrong = sum(len(r["wrong"]) for r in rows)
    placed = sum(len(r["placed"]) for r in rows)
    text = "\n".join(
        [
            "# Fleet localization benchmark",
            "",
            "Generated by `python benchmarks/fleet.py"
            + (" --city" if args.city else "")
            + "` (do not edit by hand). `localize_fleet` runs the online session "
            "(`sgloc.online`) on whole maps: each map is one keyframe, every pair is localized "
            "once (default acceptance), links that disagree around loops (3 m / 3 deg) are "
            "dropped, the robots linked to the root are placed by a pose graph over the kept "
            "links weighted by their covariances, the placed robots are refined together on "
            "every same-class object pair their maps put within 3 m of each other "
            "(`sgloc.online.joint`), and robots it cannot place are reported. The root is the "
            "best-connected "
            "robot of the largest placed group.",
            "",
            f"Goal: every placed robot within {MAX_M:g} m (at its objects' centroid) and "
            f"{MAX_DEG:g} deg of the ground truth relative to the root; no robot placed wrongly; "
            "unplaceable robots reported. 'overlapping robots (oracle)' counts robots that share "
            ">= 15 same-class objects within 3 m with another robot under ground truth (an upper "
            "bound on what could be placed).",
            "",
            table(rows),
            "",
            f"Total: {placed} robots placed, {total_wrong} placed wrongly.",
            "",
            "The same fleets with the acceptance test off (Guo's rule alone decides which pairs "
            "are kept; the loop check and the pose graph still run):",
            "",
            table(baseline),
            "",
            "Per robot (translation m, rotation deg relative to the root; '-' = unplaced):",
            "",
        ]
        + [
            f"- {r['name']}: "
            + "; ".join(
                f"{i} ({r['notes'][i]}): "
                + (
                    f"{r['errors'][i][0]:.2f} m {r['errors'][i][1]:.2f} deg"
                    if i in r["errors"]
                    else f"- ({r['reasons'].get(i, '')})"
                )
                for i in range(r["n"])
            )
            for r in rows
        ]
        + [
            "",
            "![world fleet](fleet_world0.png) ![KITTI fleet](fleet_kitti00.png)"
            + (" ![city fleet](fleet_city.png)" if args.city else ""),
            "",
        ]
    )
    (args.out / "fleet.md").write_text(text)
    print(table(rows))
    print(f"wrote {args.out / 'fleet.md'}")
    return 0 if total_wrong == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
