"""Online fleet benchmark: recorded runs cut into robots, replayed keyframe by keyframe.

    python benchmarks/online.py [--out docs] [--keep DIR] [--every 1] [--no-batch]
    python benchmarks/online.py --drift | --big-city | --many [--set NAME=VALUE] [--timeout S]

Scenarios: KITTI 00 scans 0-2999 cut into 4 and into 6 consecutive robots (the tuning range),
KITTI 00 scans 1500-4540 cut into 4 robots (held out: never tuned on), each KITTI cut twice:
with KITTI's raw poses and with the refined poses (`sgloc.evaluation.kitti_refined`, needs
gtsam) as the robots' odometry and the truth; the synthetic city's two routes cut into 8
robots (objects only). Every scenario is streamed through one OnlineSession
(`sgloc replay`'s code path); the replay folder is scored against the ground truth: per robot
the stamp it joined against the oracle's (>= 15 same-class objects within 3 m shared with a
robot that can already be placed), wrong joins and links (> 3 m at the robot's objects or
> 3 deg), revoked links, per-update latency, and the fleet trajectory error (evo APE of every
placed robot's fleet/<robot>.tum after one rigid alignment of the whole fleet). With the batch
part, the KITTI fleet of docs/fleet.md is placed by `localize_fleet` and scored the same way.
Writes docs/online.md and docs/online_joins.png.

The fleet groups (`--drift`: the city and KITTI 00 at odometry drift levels 0, 1, 2, 4, scans
0-2999 for tuning and 3000-4540 held out, and KITTI's raw poses as odometry; `--big-city`: the
12x12-block city with 2,000 m routes in 8 and 10 robots on 4 seeds, the 22x22-block city with
8,000 m routes in 8, 10 and 16 robots; `--many`: 64 and 128 robots on the default city;
`--sparse`: KITTI 00 as a sparse one-class detector sees it, 3 robots, at --levels) run
each replay in a child process with a time limit, score it with `sgloc.evaluation.fleet_runs`
(wrong joins and accepted attempts, encounter error, fleet RMSE, the oracle's, revocations,
latency, wall time, peak memory), keep the figures in docs/online_fleet.json and rewrite the
fleet part of docs/online.md from them.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sgloc.evaluation import replay_scenarios as scenarios
from sgloc.evaluation.online_replay import MAX_DEG, MAX_M, is_wrong, run_scenario
from sgloc.evaluation.report import markdown_table
from sgloc.online import OnlineConfig
from sgloc.pipeline.presets import localizer_preset

GOAL_DELAY, GOAL_APE, GOAL_MEDIAN_MS, GOAL_P99_MS = 0.10, 1.0, 5.0, 100.0


def scenario_list(every: int) -> list[tuple[str, str, object, str]]:
    """(key, title, factory, localizer preset) of each benchmark scenario. Every KITTI cut
    runs twice: with KITTI's raw poses and with the refined poses
    (`sgloc.evaluation.kitti_refined`), each as both the robots' odometry and the truth."""
    kitti = [
        ("kitti4", "KITTI 00 scans 0-2999, 4 robots", (4, 0, 2999), "tuning"),
        ("kitti6", "KITTI 00 scans 0-2999, 6 robots", (6, 0, 2999), "tuning"),
        ("kitti4_held_out", "KITTI 00 scans 1500-4540, 4 robots", (4, 1500, 4540), "held out"),
    ]
    out = []
    for poses, suffix in (("raw", ""), ("refined", "_refined")):
        for key, title, (n, a, b), part in kitti:
            out.append((key + suffix, f"{title}, {poses} poses ({part})",
                        _kitti_factory(n, a, b, every, poses), "kitti-objects"))
    out.append(("city8", "synthetic city 0, 8 robots (objects only)",
                lambda: scenarios.city_scenario(8, 0), "city-objects"))
    return out


def _kitti_factory(n: int, first: int, last: int, every: int, poses: str):
    """A factory of one KITTI cut (bound now, not late like a lambda in a loop)."""
    return lambda: scenarios.kitti_scenario(n, first, last, every, poses)


def label(key: str) -> str:
    """A scenario key as the goal lines name it, saying which KITTI poses it uses."""
    if not key.startswith("kitti"):
        return key
    if key.endswith("_refined"):
        return f"{key.removesuffix('_refined')} (refined poses)"
    return f"{key} (raw poses)"


def warm_up(presets: list[str]) -> None:
    """One small replay per localizer preset, so that compilation (numba) is not counted as
    update latency."""
    with tempfile.TemporaryDirectory() as d:
        for p in presets:
            run_scenario(scenarios.world_scenario(), Path(d) / p, localizer_preset(p))
        if "kitti-objects" in presets:  # real detections reach code paths the world does not
            run_scenario(scenarios.kitti_scenario(2, 0, 399), Path(d) / "kitti",
                         localizer_preset("kitti-objects"))


def summarize(key: str, title: str, res: dict, secs: float) -> dict:
    """One row of the overview table (and the goal checks)."""
    rows = res["robots"]
    overl = [r for r in rows if not r["root"] and np.isfinite(r["oracle_s"])]
    joined = [r for r in overl if r["joined_s"] is not None]
    delays = [r["delay"] for r in joined]
    end = [r["end_error"] for r in rows if r["end_error"] is not None and not r["root"]]
    links = res["links"]
    return {
        "key": key, "title": title, "n": len(rows), "seconds": secs,
        "overlapping": len(overl), "joined": len(joined),
        "missed": [r["robot"] for r in overl if r["joined_s"] is None],
        "mean_delay": float(np.mean(delays)) if delays else None,
        "wrong_joins": [r["robot"] for r in rows if is_wrong(r["join_error"])],
        "oracle_end": {r["robot"]: r["oracle_end_error"] for r in rows},
        "wrong_joins_final": [r["robot"] for r in rows if is_wrong(r["join_error_final"])],
        "wrong_links": sum(lk["wrong"] for lk in links),
        "wrong_active": sum(lk["wrong"] and lk["active"] for lk in links),
        "revoked": sum(not lk["active"] for lk in links),
        "links": len(links),
        "worst_m": max((e[0] for e in end), default=0.0),
        "worst_deg": max((e[1] for e in end), default=0.0),
        "unreachable": [r["robot"] for r in rows if is_wrong(r["oracle_end_error"])],
        "oracle_worst": max((r["oracle_end_error"] for r in rows
                             if r["oracle_end_error"] is not None and not r["root"]),
                            default=(0.0, 0.0)),
        "ape": res["ape"]["rmse"],
        "ape_oracle": res["ape_oracle"]["rmse"],
        "latency": res["latency"],
        "keyframes": res["keyframes"],
    }


def fmt(x: float | None, spec: str = ".2f", none: str = "-") -> str:
    return none if x is None or not np.isfinite(x) else format(x, spec)


def robot_table(res: dict) -> str:
    body = []
    def err(e: tuple[float, float] | None) -> str:
        return "-" if e is None else f"{e[0]:.2f} / {e[1]:.2f}"

    for r in res["robots"]:
        e, lat = r["end_error"], r["latency"]
        body.append([
            r["robot"] + (" (root)" if r["root"] else ""), r["keyframes"], fmt(r["run_s"], ".1f"),
            fmt(r["oracle_s"], ".1f", "never"), fmt(r["joined_s"], ".1f", "never"),
            fmt(None if r["delay"] is None else 100 * r["delay"], "+.1f"),
            err(r["join_error"]), err(r["join_error_final"]), err(e), err(r["oracle_end_error"]),
            f"{lat['median_ms']:.2f} / {lat['p99_ms']:.1f} / {lat['max_ms']:.1f}",
        ])
    return markdown_table(
        ["robot", "keyframes", "run (s)", "oracle overlap from (s)", "joined at (s)",
         "delay (% of run)", "join error at its objects then (m / deg)",
         "join error at its final objects (m / deg)", "end error (m / deg)",
         "end error, links refitted on true pairs (m / deg)",
         "latency median / p99 / max (ms)"], body)


def link_table(res: dict) -> str:
    """Every accepted link of one replay against the ground truth."""
    def pair(e) -> str:
        return "-" if e is None else f"{e[0]:.2f} / {e[1]:.2f}"

    body = [[f"{lk['a']} - {lk['b']}", "active" if lk["active"] else "revoked",
             f"{lk['stamp']:.1f}", lk["matches"], lk["pairs"], fmt(lk["lever_m"], ".0f"),
             f"{lk['error_m']:.2f} / {lk['error_deg']:.2f}", pair(lk["oracle_error"]),
             pair(lk["predicted_2sigma"])] for lk in res["links"]]
    return markdown_table(
        ["link (a - b)", "state", "last accepted (s)", "matches", "object pairs co-located",
         "farthest b object from them (m)", "error at b's objects (m / deg)",
         "refitted on true pairs: error (m / deg)", "its covariance's 2 sigma (m / deg)"],
        body)


def overview_table(sums: list[dict]) -> str:
    body = []
    for s in sums:
        lat = s["latency"]
        body.append([
            s["title"], s["n"], f"{s['joined']} / {s['overlapping']}",
            fmt(None if s["mean_delay"] is None else 100 * s["mean_delay"], "+.1f"),
            f"{len(s['wrong_joins'])} / {len(s['wrong_joins_final'])}",
            f"{s['links']} ({s['wrong_links']} wrong)", s["revoked"],
            f"{s['worst_m']:.2f} / {s['worst_deg']:.2f}",
            f"{s['oracle_worst'][0]:.2f} / {s['oracle_worst'][1]:.2f}",
            f"{fmt(s['ape'], '.3f')} ({fmt(s['ape_oracle'], '.3f')})",
            f"{lat['median_ms']:.2f} / {lat['p99_ms']:.1f} / {lat['max_ms']:.1f}",
            f"{s['keyframes']} in {s['seconds']:.0f} s",
        ])
    return markdown_table(
        ["scenario", "robots", "joined / overlapping (oracle)", "mean delay (% of run)",
         "wrong joins (at its objects then / at its final objects)", "links accepted",
         "revoked", "worst end error (m / deg)",
         "worst end error, links refitted on true pairs (m / deg)",
         "trajectory APE RMSE (m) (links refitted on true pairs)",
         "latency median / p99 / max (ms)", "keyframes"], body)


def goals(sums: list[dict]) -> list[str]:
    """One line per goal: met or not, with the measured figures."""
    def line(ok: bool, text: str) -> str:
        return f"- {'met' if ok else '**NOT met**'}: {text}"

    missed = [f"{label(s['key'])}: {', '.join(s['missed'])}" for s in sums if s["missed"]]
    delays = {label(s["key"]): s["mean_delay"] for s in sums if s["mean_delay"] is not None}
    per = ", ".join(f"{k} {100 * v:+.1f} %" for k, v in delays.items())
    late = {k: v for k, v in delays.items() if v > GOAL_DELAY}
    wrong = {label(s["key"]): s["wrong_joins"] for s in sums if s["wrong_joins"]}
    wrong_final = {label(s["key"]): s["wrong_joins_final"] for s in sums if s["wrong_joins_final"]}
    off = {label(s["key"]): (s["worst_m"], s["worst_deg"]) for s in sums
           if s["worst_m"] > MAX_M or s["worst_deg"] > MAX_DEG}
    apes = {label(s["key"]): s["ape"] for s in sums if s["key"].startswith("kitti")}
    lat = {label(s["key"]): s["latency"] for s in sums}
    slow = {k: v for k, v in lat.items()
            if v["median_ms"] > GOAL_MEDIAN_MS or v["p99_ms"] > GOAL_P99_MS}
    return [
        line(not missed, "every robot that overlaps a placed robot (oracle) joins"
             + (f" (missed: {'; '.join(missed)})" if missed else "")),
        line(not late, "on average within 10 % of its run after the oracle overlap begins "
             f"(mean delay per scenario: {per})"),
        line(not wrong, "no wrong join, judged at the objects the robot had when it joined"
             + _listed(wrong) + _oracle_of(wrong, sums)),
        line(not wrong_final, "no wrong join, judged at the robot's final objects (the "
             "stricter, earlier definition)" + _listed(wrong_final)),
        line(not off, f"no robot more than {MAX_M:g} m (at its objects) / {MAX_DEG:g} deg off at "
             "the end" + (" (worst: " + ", ".join(f"{k} {m:.2f} m / {d:.2f} deg"
                                                   for k, (m, d) in off.items()) + ")"
                          if off else "") + _unreachable(sums)),
        line(all(v is not None and v <= GOAL_APE for v in apes.values()),
             "fleet trajectory error <= 1.0 m RMSE on KITTI 00 ("
             + ", ".join(f"{k} {fmt(v, '.3f')} m" for k, v in apes.items())
             + "; with the same links refitted on the true correspondences: "
             + ", ".join(f"{label(s['key'])} {fmt(s['ape_oracle'], '.3f')} m" for s in sums
                         if label(s["key"]) in apes) + ")"),
        line(not slow, "per-update latency median <= 5 ms and p99 <= 100 ms ("
             + ", ".join(f"{k} {v['median_ms']:.2f} / {v['p99_ms']:.1f} ms"
                         for k, v in lat.items()) + ")"),
    ]


def goal_table(sums: list[dict]) -> str:
    """Every scenario judged on each goal on its own (met / NOT met, with its figure)."""
    def cell(ok: bool, text: str) -> str:
        return f"{'met' if ok else '**NOT met**'}: {text}"

    body = []
    for s in sums:
        d, lat, ape = s["mean_delay"], s["latency"], s["ape"]
        ape_cell = (cell(ape is not None and ape <= GOAL_APE, f"{fmt(ape, '.3f')} m")
                    if s["key"].startswith("kitti") else f"{fmt(ape, '.3f')} m (no goal)")
        body.append([
            s["title"],
            cell(not s["missed"], f"{s['joined']} / {s['overlapping']}"),
            cell(d is None or d <= GOAL_DELAY, f"{fmt(None if d is None else 100 * d, '+.1f')} %"),
            cell(not s["wrong_joins"], f"{len(s['wrong_joins'])}"),
            cell(not s["wrong_joins_final"], f"{len(s['wrong_joins_final'])}"),
            cell(s["worst_m"] <= MAX_M and s["worst_deg"] <= MAX_DEG,
                 f"{s['worst_m']:.2f} m / {s['worst_deg']:.2f} deg"),
            ape_cell,
            cell(lat["median_ms"] <= GOAL_MEDIAN_MS and lat["p99_ms"] <= GOAL_P99_MS,
                 f"{lat['median_ms']:.2f} / {lat['p99_ms']:.1f} ms"),
        ])
    return markdown_table(
        ["scenario", "every overlapping robot joins", "mean delay <= 10 % of run",
         "no wrong join (objects then)", "no wrong join (final objects)",
         "worst end error <= 3 m / 3 deg", "trajectory APE <= 1.0 m (KITTI)",
         "latency median <= 5 ms, p99 <= 100 ms"], body)


def _oracle_of(per: dict[str, list[str]], sums: list[dict]) -> str:
    """'; their frames at the end with the links refitted on the true pairs: ...' or ''."""
    by_key = {label(s["key"]): s["oracle_end"] for s in sums}
    parts = [f"{k}: {r} " + ("not placed" if by_key[k][r] is None
                             else f"{by_key[k][r][0]:.2f} m / {by_key[k][r][1]:.2f} deg")
             for k, robots in per.items() for r in robots]
    return ("; their fleet frames at the end with the same links refitted on the true "
            "correspondences: " + ", ".join(parts)) if parts else ""


def _unreachable(sums: list[dict]) -> str:
    """'; beyond the limit even with its links refitted on the true pairs: ...' or ''."""
    per = {label(s["key"]): s["unreachable"] for s in sums if s["unreachable"]}
    if not per:
        return ""
    return ("; beyond the limit even with its links refitted on the true correspondences "
            "(what the maps and their poses allow): "
            + "; ".join(f"{k}: {', '.join(v)}" for k, v in per.items()))


def _listed(per: dict[str, list[str]]) -> str:
    """' (wrong: key: a, b; key2: c)' or ''."""
    return (" (wrong: " + "; ".join(f"{k}: {', '.join(v)}" for k, v in per.items()) + ")"
            if per else "")


def plot_joins(results: list[tuple[str, dict]], path: Path) -> Path:
    """Per scenario: each robot's run (bar), the oracle overlap stamp (hollow diamond) and the
    stamp it joined (dot; red when the join was wrong)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(results), 1, figsize=(8, 2.2 * len(results)), squeeze=False)
    for ax, (title, res) in zip(axes[:, 0], results, strict=True):
        rows = res["robots"]
        for y, r in enumerate(rows):
            ax.plot([0, r["run_s"]], [y, y], lw=5, color="lightgrey", solid_capstyle="butt")
            if np.isfinite(r["oracle_s"]):
                ax.plot(r["oracle_s"], y, "D", mfc="none", mec="black", ms=7)
            if r["joined_s"] is not None:
                ax.plot(r["joined_s"], y, "o", ms=6,
                        color="#D62728" if is_wrong(r["join_error"]) else "#2CA02C")
        ax.set_yticks(range(len(rows)), [r["robot"] for r in rows], fontsize=7)
        ax.invert_yaxis()
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("stamp (s, each robot starts at 0)", fontsize=8)
    from matplotlib.lines import Line2D

    axes[0, 0].legend(handles=[
        Line2D([], [], ls="", marker="D", mfc="none", mec="black", label="oracle overlap"),
        Line2D([], [], ls="", marker="o", color="#2CA02C", label="joined"),
        Line2D([], [], ls="", marker="o", color="#D62728", label="joined wrongly"),
    ], fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def batch_kitti(out: Path) -> dict:
    """The KITTI fleet of docs/fleet.md placed by `localize_fleet` (default settings, as there):
    every placed robot's scans in the fleet frame against the KITTI poses, one alignment."""
    from sgloc.evaluation.fleet_scenes import KITTI_FLEET, kitti_fleet
    from sgloc.evaluation.fleet_trajectory import fleet_ape
    from sgloc.evaluation.pairs_kitti import kitti_root, kitti_sequence
    from sgloc.evaluation.replay_scenarios import log_from_frames
    from sgloc.io.poses import write_tum
    from sgloc.online.fleet import localize_fleet
    from sgloc.replay.outputs import fleet_poses

    scene = kitti_fleet()
    L = kitti_sequence(kitti_root())[0]
    res = localize_fleet(scene.graphs, workers=1)
    pairs = []
    for i, (a, b) in enumerate(KITTI_FLEET):
        scans = np.arange(a, b + 1)
        empty = [(np.zeros((0, 3)), np.zeros(0, np.int64))] * len(scans)
        log = log_from_frames(f"r{i}", scans * 0.1, L[scans], empty, L[a])
        gt = write_tum(out / f"gt_{i}.tum", log.stamps_ns, *fleet_poses(log, L[a]))
        if i in res.T_fleet_robot:
            est = write_tum(out / f"est_{i}.tum", log.stamps_ns,
                                  *fleet_poses(log, res.T_fleet_robot[i]))
            pairs.append((est, gt))
    return {"placed": len(res.placed), "n": len(KITTI_FLEET), "ape": fleet_ape(pairs)}


#: Settings compared on every scenario besides the default (`--no-variants` skips them).
VARIANTS = [
    ("back-end robots", {"backend": "robots"}),
    ("links not refitted", {"refine_links": False}),
    ("no co-location factors", {"refine_fleet": False}),
    ("no viewpoint correction", {"view_correction": False}),
    ("back-end robots, joins held back (2 sigma)", {"backend": "robots", "join_sigmas": 2.0}),
]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path("docs"))
    ap.add_argument("--keep", type=Path, default=None, help="keep the replay folders here")
    ap.add_argument("--every", type=int, default=1, help="KITTI: every n-th scan a keyframe")
    ap.add_argument("--no-batch", action="store_true", help="skip the batch KITTI fleet")
    ap.add_argument("--no-variants", action="store_true", help="skip the settings compared")
    ap.add_argument("--only", nargs="*", default=None, help="scenario keys to run")
    ap.add_argument("--drift", action="store_true",
                    help="run the drift group (city and KITTI at drift levels) instead")
    ap.add_argument("--big-city", action="store_true",
                    help="run the bigger cities (12x12 blocks, 22x22 blocks) instead")
    ap.add_argument("--many", action="store_true",
                    help="run 64 and 128 robots on the default city instead")
    ap.add_argument("--sparse", action="store_true",
                    help="run KITTI 00 as a sparse one-class detector sees it (vehicles, ~3 "
                         "per keyframe within 40 m, depth noise 1.5 %% of range) at --levels "
                         "instead")
    ap.add_argument("--levels", type=float, nargs="+", default=list(LEVELS),
                    help="drift levels of --drift")
    ap.add_argument("--drift-seeds", type=int, nargs="+", default=[0], help="seeds of --drift")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3],
                    help="city seeds of the 12x12-block city (--big-city)")
    ap.add_argument("--cases", nargs="+", default=None,
                    help="run only these keys of the chosen groups (shell patterns)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="an OnlineConfig setting for the fleet groups (repeatable); "
                         "localizer.NAME=VALUE: a localizer setting (e.g. "
                         "localizer.layout_shifts=8); odometry.NAME=VALUE: the odometry's "
                         "noise model (e.g. odometry.translation_per_metre=0.001)")
    ap.add_argument("--timeout", type=float, default=600.0,
                    help="seconds one fleet-group run may take (then reported as timed out)")
    ap.add_argument("--list", action="store_true", help="list the chosen groups' runs and stop")
    ap.add_argument("--city-levels", action="store_true",
                    help="run the 12x12-block city with 10 robots at drift 0, 1 and 2 over "
                         "--seeds instead (table: docs/online_city_seeds.md)")
    ap.add_argument("--part", default="development",
                    help="--city-levels: what the seeds are (e.g. development, held out)")
    ap.add_argument("--preset", default="city-objects",
                    help="--city-levels: the localizer preset (the city replay's own)")
    ap.add_argument("--workers", type=int, default=1,
                    help="--city-levels: runs at once (each in its own process)")
    args = ap.parse_args(argv)
    if args.city_levels:
        return main_city_levels(args)
    groups = {g for g, on in (("drift", args.drift), ("big-city", args.big_city),
                              ("many", args.many), ("sparse", args.sparse)) if on}
    if groups:
        return main_fleet(args, groups)
    work = args.keep or Path(tempfile.mkdtemp(prefix="sgloc-online-"))
    chosen = [c for c in scenario_list(args.every) if not args.only or c[0] in args.only]
    if any(c[0].endswith("_refined") for c in chosen):
        from sgloc.errors import SglocError
        from sgloc.optional import require

        try:  # the refined KITTI poses are a gtsam pose graph
            require("gtsam", "gtsam", "the refined KITTI poses (scenarios *_refined)")
        except SglocError as e:
            print(f"error: {e}; or skip them with --only", file=sys.stderr)
            return 2
    warm_up(sorted({c[3] for c in chosen}))
    sums, results, sections = [], [], []
    for key, title, make, preset in chosen:
        sc = make()
        s, res = run_one(sc, key, title, work / key, preset, OnlineConfig())
        sums.append(s)
        results.append((title, res))
        sections.append(f"### {title}\n\n{sc.note}; localizer preset `{preset}`.\n\n"
                        + robot_table(res) + "\nLinks at the end:\n\n" + link_table(res))
    variants = [] if args.no_variants else [
        (name, run_one(make(), key, title, work / f"{key}_{k}", preset,
                       OnlineConfig(**kw))[0])
        for k, (name, kw) in enumerate(VARIANTS)
        for key, title, make, preset in chosen
    ]
    batch = None if args.no_batch else batch_kitti(Path(tempfile.mkdtemp(prefix="sgloc-batch-")))
    refined = None
    if any(c[0].endswith("_refined") for c in chosen):
        from sgloc.evaluation.kitti_refined import refinement_figures
        from sgloc.evaluation.pairs_kitti import kitti_root

        refined = refinement_figures(kitti_root())
    args.out.mkdir(parents=True, exist_ok=True)
    plot_joins(results, args.out / "online_joins.png")
    text = page(sums, sections, batch, args.every, variants, refined)
    fleet = load_results(args.out / FLEET_RESULTS)
    (args.out / "online.md").write_text(splice(text, fleet_section(fleet)) if fleet else text)
    return 0


def main_fleet(args: argparse.Namespace, groups: set[str]) -> int:
    """Run the chosen fleet groups, store their results and rewrite the page's fleet part."""
    import fnmatch

    from sgloc.online.robots.solve import gtsam_available

    truth = "refined" if gtsam_available() else "raw"
    cases = fleet_cases(groups, args.levels, args.seeds, args.drift_seeds, truth)
    if args.cases:
        cases = [c for c in cases if any(fnmatch.fnmatch(c.key, p) for p in args.cases)]
    if args.list:
        print("\n".join(f"{c.key}: {c.title}" for c in cases))
        return 0
    settings = parse_settings(args.set)
    args.out.mkdir(parents=True, exist_ok=True)
    store = args.out / FLEET_RESULTS
    results = load_results(store)
    for case in cases:  # stored after each run: a stopped benchmark keeps what it measured
        run_fleet_groups([case], settings, args.timeout, results)
        save_results(store, results)
    page_path = args.out / "online.md"
    text = page_path.read_text() if page_path.is_file() else "# Online fleet localization\n"
    page_path.write_text(splice(text, fleet_section(results)))
    return 0


# -- the 12x12-block city over seeds at drift 0, 1 and 2 ----------------------------------------
CITY_RESULTS, CITY_PAGE = "online_city_seeds.json", "online_city_seeds.md"
CITY_LEVELS = (0.0, 1.0, 2.0)
GOAL_BEND_M = 0.05


def city_level_cases(seeds, preset: str, part: str) -> list:
    """The --city-levels runs: city `seed`, 12x12 blocks, 2,000 m routes, 10 robots, each drift
    level of CITY_LEVELS."""
    from sgloc.evaluation.fleet_cases import Case

    return [Case(f"city12_10r_{preset}_d{lv:g}_s{sd}", "city levels", f"12x12-block city {sd}, "
                 f"10 robots, drift {lv:g}", "city", 10, lv, sd, 2000.0, 12, part=part,
                 localizer=preset) for sd in seeds for lv in CITY_LEVELS]


def main_city_levels(args: argparse.Namespace) -> int:
    """Run the --city-levels cases (at most --workers at once, each in a child process),
    store their results after each and rewrite docs/online_city_seeds.md."""
    from concurrent.futures import ThreadPoolExecutor, as_completed

    from sgloc.evaluation.fleet_cases import run_isolated

    cases = city_level_cases(args.seeds, args.preset, args.part)
    if args.list:
        print("\n".join(f"{c.key}: {c.title}" for c in cases))
        return 0
    settings = parse_settings(args.set)
    args.out.mkdir(parents=True, exist_ok=True)
    store = args.out / CITY_RESULTS
    results = load_results(store)
    suffix = "".join(f" [{k}={v}]" for k, v in sorted(settings.items()))
    with ThreadPoolExecutor(max(1, min(args.workers, 2))) as pool:
        jobs = {pool.submit(run_isolated, c, settings, args.timeout, c.level > 0): c
                for c in cases}
        for job in as_completed(jobs):
            c, res = jobs[job], job.result()
            results[c.key + suffix] = res
            save_results(store, results)
            print(f"{c.title}{suffix}: {res['status']}, {city_brief(res)}", file=sys.stderr)
    (args.out / CITY_PAGE).write_text(city_page(results))
    return 0


def city_brief(res: dict) -> str:
    """One line of a --city-levels run."""
    if res.get("status") != "done":
        return brief(res)
    b = res["bend"]
    return (f"{len(res['outside'])} outside, bend {fmt(b['max'], '.3f')} / "
            f"{fmt(b['median'], '.3f')} m, " + brief(res))


def city_goal_cells(r: dict) -> tuple[str, bool | None]:
    """(cell, met) of one drift 1-2 run's fleet goals: encounter p95 <= max(0.5 m, 3 x the
    oracle's), fleet RMSE <= 1.25 x the oracle's + 0.25 m, every overlapping robot joined
    within 10 % of its run on average (as the fleet groups' goals)."""
    o = r.get("oracle")
    if o is None:
        return "no oracle", None
    enc, rmse = r["encounter"]["p95"], r["rmse"]
    lim_enc = max(0.5, 3 * (o["encounter"]["p95"] or 0.0))
    lim_rmse = 1.25 * (o["rmse"] or 0.0) + 0.25
    delay = None if r["mean_delay"] is None else 100 * r["mean_delay"]
    ok = [enc is not None and enc <= lim_enc, rmse is not None and rmse <= lim_rmse,
          r["joined"] >= r["overlapping"] and (delay or 0.0) <= 100 * GOAL_DELAY]
    cell = (f"p95 {fmt(enc)} ({fmt(lim_enc)}), RMSE {fmt(rmse)} ({fmt(lim_rmse)}), "
            f"{r['joined']}/{r['overlapping']} joined, {fmt(delay, '+.1f')} %")
    return cell + ("" if all(ok) else " **not met**"), all(ok)


def city_row(seed: int, runs: dict) -> list:
    """One seed's row: per level the robots outside the truth group at the end (and wrong at
    their join), drift 0's bend, drift 1-2's goals."""
    row = [seed]
    for lv in CITY_LEVELS:
        r = runs.get(lv)
        if r is None or r.get("status") != "done":
            row += ["-" if r is None else r["status"]] * 2
            continue
        out = f"{len(r['outside'])} / {len(r['wrong_joins'])}"
        if lv == 0:
            b = r["bend"]
            row += [out, f"{fmt(b['max'], '.3f')} / {fmt(b['median'], '.3f')}"]
        else:
            row += [out, city_goal_cells(r)[0]]
    return row


CITY_HEADER = ["seed", "drift 0: outside / wrong at join", "drift 0: bend max / median (m)",
               "drift 1: outside / wrong at join", "drift 1: fleet goals (limit)",
               "drift 2: outside / wrong at join", "drift 2: fleet goals (limit)"]


def city_page(results: dict) -> str:
    """docs/online_city_seeds.md from the stored --city-levels runs (default settings only in
    the tables of goals; runs with settings in their own tables)."""
    groups: dict[tuple[str, str, str], dict[int, dict]] = {}
    for r in results.values():
        c = r["case"]
        settings = ", ".join(f"{k}={v}" for k, v in sorted(r.get("settings", {}).items()))
        groups.setdefault((c["part"], c["localizer"], settings), {}).setdefault(
            c["seed"], {})[c["level"]] = r
    parts = []
    for (part, preset, settings), seeds in sorted(groups.items()):
        done = [r for runs in seeds.values() for r in runs.values() if r.get("status") == "done"]
        outside = sum(len(r["outside"]) for r in done)
        bends = [r["bend"]["max"] for r in done if r["case"]["level"] == 0
                 and r["bend"]["max"] is not None]
        goals = [city_goal_cells(r)[1] for r in done if r["case"]["level"] > 0]
        parts.append(
            f"## {part} seeds, preset `{preset}`" + (f", settings {settings}" if settings else "")
            + f"\n\n- robots outside the truth group at the end, all runs: {outside}"
            f"\n- drift 0 bend <= {GOAL_BEND_M:g} m: {sum(b <= GOAL_BEND_M for b in bends)} "
            f"of {len(bends)} seeds (worst {fmt(max(bends, default=None), '.3f')} m)"
            f"\n- drift 1-2 fleet goals met: {sum(g is True for g in goals)} of {len(goals)} "
            "runs\n\n" + markdown_table(CITY_HEADER, [city_row(sd, seeds[sd])
                                                      for sd in sorted(seeds)]) + "\n")
    return (
        "# Online fleet localization: the 12x12-block city over seeds\n\n"
        "Regenerate with `python benchmarks/online.py --city-levels --seeds 0 1 2 --part "
        "development --workers 2` (`--preset` the localizer preset, default `city-objects`, "
        "the city replay's own; `--set` "
        "as for the fleet groups). Each run: the synthetic city of that seed, 12x12 blocks, two "
        "2,000 m routes cut into 10 robots, replayed through the keyframe back-end at drift "
        "level 0 (exact odometry), 1 and 2 (see the drift levels on the "
        "[online benchmark page](online.md)), each in a child process of its own.\n\n"
        "*Outside*: the placed robots outside the largest group one rigid alignment puts on the "
        "truth (median keyframe error within 3 m) at the end of the run; *wrong at join*: the "
        "robots whose placement was wrong when they joined (the fleet groups' wrong joins; a "
        "later correction does not clear it). *Bend* (drift 0): each placed robot's corrected "
        "keyframe positions against its exact odometry after one rigid fit, the largest "
        f"distance per robot; max and median over the robots (goal <= {GOAL_BEND_M:g} m). "
        "*Fleet goals* (drift 1 and 2): encounter p95 <= max(0.5 m, 3 x the oracle's), fleet "
        "RMSE <= 1.25 x the oracle's + 0.25 m, every overlapping robot joined within 10 % of "
        "its run on average; the limits in brackets.\n\n" + "\n".join(parts))


def run_one(sc, key: str, title: str, out: Path, preset: str, online: OnlineConfig):
    """(summary row, score) of one scenario replayed with `online`."""
    t0 = time.perf_counter()
    res = run_scenario(sc, out, localizer_preset(preset), online)
    secs = time.perf_counter() - t0
    s = summarize(key, title, res, secs)
    print(f"{title}: {s['joined']}/{s['overlapping']} joined, APE {fmt(s['ape'], '.3f')} m, "
          f"{secs:.0f} s", file=sys.stderr)
    return s, res


def variant_table(variants: list[tuple[str, dict]], sums: list[dict]) -> str:
    """Every scenario with the default settings and with each variant."""
    rows = [("default (keyframe back-end)", s) for s in sums]
    body = []
    for name, s in rows + variants:
        body.append([
            name, s["title"], f"{s['joined']} / {s['overlapping']}",
            fmt(None if s["mean_delay"] is None else 100 * s["mean_delay"], "+.1f"),
            f"{len(s['wrong_joins'])} / {len(s['wrong_joins_final'])}",
            f"{s['worst_m']:.2f} / {s['worst_deg']:.2f}", fmt(s["ape"], ".3f"),
            f"{s['latency']['median_ms']:.2f} / {s['latency']['p99_ms']:.1f}",
        ])
    return markdown_table(
        ["settings", "scenario", "joined / overlapping", "mean delay (% of run)",
         "wrong joins (then / final objects)", "worst end error (m / deg)",
         "trajectory APE RMSE (m)", "latency median / p99 (ms)"], body)


def variant_text(variants: list[tuple[str, dict]], sums: list[dict]) -> str:
    """The section comparing settings (empty with --no-variants)."""
    if not variants:
        return ""
    return (
        "## Settings compared\n\n"
        "The default settings use the keyframe back-end (a pose graph over every robot's "
        "keyframes, [online_session.md](online_session.md)). *Back-end robots* "
        "(`OnlineConfig.backend=\"robots\"`): each robot placed by one rigid frame of its "
        "odometry, the fleet frame refined jointly on every object pair the placed robots' maps "
        "co-locate. *Links not refitted* (`refine_links=False`): each link as its attempt "
        "aligned it, not refitted on every object pair it co-locates between the query submap "
        "and the target map. *No co-location factors* (`refine_fleet=False`): the graph holds "
        "two robots only where a link relates their keyframes, not all along where their maps "
        "coincide. *No viewpoint correction* (`view_correction=False`): the refits and the "
        "co-location factors use the objects where they were seen, not corrected for the side "
        "they were seen from. *Joins held back* (`join_sigmas=2`, back-end robots): a robot "
        "joins only once 2 standard deviations of its predicted error (its links' covariances "
        "composed along its path from the root, at the centroid of its objects, worst "
        "direction) are within 3 m and 3 deg; every link's covariance includes the shared "
        "offset of two maps measured on real data ([covariance.md](covariance.md)), so the "
        "hold cannot tell a precise link from an imprecise one (which is why it is off by "
        "default). The trajectory APE counts the placed robots only, so a run that "
        "places fewer robots is not comparable on it. The held-out "
        "cut was never used to choose a setting.\n\n" + variant_table(variants, sums) + "\n"
    )


def ground_truth_text(f: dict | None) -> str:
    """The paragraph on the KITTI ground truth (raw and refined poses) of docs/online.md."""
    text = (
        "Ground truth. Every KITTI cut runs twice, each time with the same poses as the robots' "
        "odometry and as the truth: *raw poses* (KITTI's poses_00.txt) and *refined poses*. "
        "KITTI's raw poses are themselves off by 1-2 m (up to ~1 deg) at some revisits, so with "
        "them part of the 3 m limit and of the trajectory error is the ground truth's own "
        "error; the city's ground truth is exact.")
    if f is None:
        return text + "\n\n"
    from sgloc.evaluation import kitti_refined as kr

    return text + (
        " The refined poses (`sgloc.evaluation.kitti_refined`) are a pose graph over all "
        "4,541 scans' LiDAR poses, solved with gtsam: a between factor per consecutive scan "
        f"pair equal to the raw relative motion (sigma {100 * kr.ODOM_SIGMA_M:g} cm / "
        f"{kr.ODOM_SIGMA_DEG:g} deg: the raw poses are locally accurate), one per refined "
        f"revisit transform ({f['revisits']} pairs of kitti_lc_test_*.txt, sigma "
        f"{kr.REVISIT_SIGMA_M:g} m / {kr.REVISIT_SIGMA_DEG:g} deg, Huber kernel), scan 0 "
        "fixed; about a second to compute, never stored. At the revisits, the true "
        "same-class object pairs "
        "(mutual nearest neighbours within 2 m under the refined transforms; "
        f"{f['object_pairs']} pairs) lie a median {f['raw_median_m']:.2f} m apart with the raw "
        f"poses (90th percentile {f['raw_p90_m']:.2f} m) and {f['refined_median_m']:.2f} m "
        f"with the refined ones ({f['refined_p90_m']:.2f} m; the refined transforms themselves: "
        f"{f['M_median_m']:.2f} m). On every 5th revisit ({f['held_out_revisits']} pairs) "
        "left out of the fit (nearby revisits stay in it): "
        f"{f['held_out_raw_median_m']:.2f} m raw, "
        f"{f['held_out_refined_median_m']:.2f} m refined. The consecutive relative motions "
        f"change by a median {1000 * f['step_median_m']:.1f} mm / {f['step_median_deg']:.4f} "
        f"deg (at most {1000 * f['step_max_m']:.1f} mm / {f['step_max_deg']:.3f} deg).\n\n")


def page(
    sums: list[dict], sections: list[str], batch: dict | None, every: int,
    variants: list[tuple[str, dict]], refined: dict | None = None,
) -> str:
    """docs/online.md."""
    batch_text = "The batch part was not run (`--no-batch`).\n"
    if batch is not None:
        a = batch["ape"]
        batch_text = (
            f"The KITTI fleet of [fleet.md](fleet.md) (6 robots, whole maps) placed by "
            f"`localize_fleet`: {batch['placed']} of {batch['n']} robots placed; trajectory "
            f"APE RMSE {fmt(a['rmse'], '.3f')} m (mean {fmt(a['mean'], '.3f')}, max "
            f"{fmt(a['max'], '.3f')} m over {a['n_poses']} scans of the placed robots, one "
            "alignment).\n"
        )
    return (
        "# Online fleet localization: replay benchmark\n\n"
        "Recorded runs cut into robots and replayed keyframe by keyframe, all robots at once, "
        "through one `OnlineSession` (the code path of `sgloc replay`; layouts in "
        "[replay.md](replay.md)). Regenerate with `python benchmarks/online.py` "
        f"(KITTI keyframes: every {every} scan(s)). Latencies are wall times "
        "after one small warm-up replay (compilation is not counted).\n\n"
        "Definitions. *Oracle overlap*: the first stamp at which the robot has seen >= 15 "
        "same-class objects within 3 m (ground truth) of objects seen by a robot that can "
        "already be placed (the root from its first keyframe). *Delay*: (stamp joined - oracle "
        "stamp) / the robot's run length; negative = joined before the oracle threshold. *Wrong*: "
        f"more than {MAX_M:g} m off at the centroid of the robot's objects or more than "
        f"{MAX_DEG:g} deg. A join is the first fleet frame the robot got, a decision taken on "
        "the objects it had seen by then: a *wrong join* is judged at the centroid of THOSE "
        "objects; the table also gives the same first fleet frame judged at the robot's final "
        "objects (the earlier, stricter definition: a small rotation error at the join is "
        "amplified by the distance the robot drives afterwards). A link is judged by its "
        "final T_a_b at robot_b's final objects. *End error*: the robot's final fleet frame "
        "against the ground truth relative to the root, at its final objects. "
        "*Trajectory APE*: evo's APE (translation) of every placed robot's `fleet/<robot>.tum` "
        "against its ground-truth poses, all robots stacked and aligned by ONE rigid "
        "transform. *Links refitted on true pairs*: every active link refitted on the object "
        "pairs the ground truth puts on top of each other (mutual nearest same-class "
        "neighbours within the RANSAC threshold under the true transform), and the fleet frame "
        "re-solved with them (same links, covariances and root; one rigid frame per robot, as "
        "the back-end robots places them), without the joint refinement: "
        "what those links themselves allow. An error that remains there is the data's (poses "
        "that disagree with each other at a revisit, object centres seen from other sides), "
        "not the links' estimator's. *Joint refinement* (`OnlineConfig.refine_fleet`, on by "
        "default): after the pose graph, the placed robots' frames are refined together on "
        "every object pair their maps co-locate in the fleet frame, linked robots or not; "
        "where a robot also passed objects of a robot it has no link to, this can beat the "
        "refitted links. *Latency*: "
        "wall time of each `add_keyframe` call; a robot's last one includes its final attempts "
        "(`OnlineSession.finish`).\n\n"
        + ground_truth_text(refined)
        + "## Overview\n\n" + overview_table(sums) + "\n## Goals\n\n" + "\n".join(goals(sums))
        + "\n\nEach scenario on its own:\n\n" + goal_table(sums)
        + "\n\n![joins](online_joins.png)\n\n## Per robot\n\n" + "\n".join(sections)
        + "\n" + variant_text(variants, sums) + "\n## Batch fleet\n\n" + batch_text
    )


# -- the fleet groups: drift, bigger cities, many robots ----------------------------------------
#: Where the fleet groups' results accumulate (each run replaces its own entry), next to the page.
FLEET_RESULTS = "online_fleet.json"
FLEET_BEGIN, FLEET_END = "<!-- fleet runs: begin -->", "<!-- fleet runs: end -->"
GOAL_BIG_MEDIAN_MS, GOAL_BIG_P99_MS, GOAL_128_S, GOAL_MB = 5.0, 100.0, 180.0, 1024.0
LEVELS = (0.0, 1.0, 2.0, 4.0)


def fleet_cases(groups: set[str], levels, seeds, drift_seeds, truth: str) -> list:
    """The runs of the chosen groups ("drift", "big-city", "many")."""
    from sgloc.evaluation.fleet_cases import Case

    out = []
    if "drift" in groups:
        for lv in levels:
            for sd in drift_seeds:
                tag = f"d{lv:g}_s{sd}"
                out += [
                    Case(f"city8_{tag}", "drift", f"city {sd}, 8 robots, drift {lv:g}", "city",
                         8, lv, sd),
                    Case(f"kitti4_{tag}", "drift", f"KITTI 00 scans 0-2999, 4 robots, drift "
                         f"{lv:g} (seed {sd})", "kitti", 4, lv, sd, truth=truth, part="tuning"),
                    Case(f"kitti3_after3000_{tag}", "drift held out", f"KITTI 00 scans "
                         f"3000-4540, 3 robots, drift {lv:g} (seed {sd})", "kitti", 3, lv, sd,
                         first=3000, last=4540, truth=truth, part="held out"),
                ]
        out.append(Case("kitti4_raw_odometry", "drift", "KITTI 00 scans 0-2999, 4 robots, "
                        f"KITTI's raw poses as odometry ({truth} truth)", "kitti", 4,
                        truth=truth, odometry="raw", part="tuning"))
    if "big-city" in groups:
        for n in (8, 10):
            out += [Case(f"city12_{n}r_s{sd}", "big city", f"12x12-block city {sd}, 2,000 m "
                         f"routes, {n} robots", "city", n, 0.0, sd, 2000.0, 12) for sd in seeds]
        out += [Case(f"city22_{n}r_s0", "big city", f"22x22-block city 0, 8,000 m routes, {n} "
                     "robots", "city", n, 0.0, 0, 8000.0, 22) for n in (8, 10, 16)]
    if "many" in groups:
        out += [Case(f"city{n}", "many", f"default city 0, {n} robots", "city", n)
                for n in (64, 128)]
    if "sparse" in groups:
        for lv in levels:
            for sd in drift_seeds:
                tag = f"d{lv:g}_s{sd}"
                out += [
                    Case(f"kitti3_sparse_{tag}", "sparse", "KITTI 00 scans 0-2999, 3 robots, "
                         f"one class, ~3 detections per keyframe, drift {lv:g} (seed {sd})",
                         "kitti", 3, lv, sd, truth=truth, part="tuning", detections="sparse"),
                    Case(f"kitti3_sparse_after3000_{tag}", "sparse held out", "KITTI 00 scans "
                         f"3000-4540, 3 robots, one class, ~3 detections per keyframe, drift "
                         f"{lv:g} (seed {sd})", "kitti", 3, lv, sd, first=3000, last=4540,
                         truth=truth, part="held out", detections="sparse"),
                ]
    return out


def parse_settings(items: list[str]) -> dict:
    """`--set name=value` items -> OnlineConfig keyword arguments (values read as JSON when
    they are: numbers, true/false, null; else as text)."""
    import json

    out = {}
    for item in items:
        name, eq, value = item.partition("=")
        if not eq or not name:
            raise SystemExit(f"error: --set {item!r}: give name=value, e.g. --set seed=1")
        try:
            out[name] = json.loads(value)
        except json.JSONDecodeError:
            out[name] = value
    from sgloc.errors import SglocError
    from sgloc.evaluation.fleet_cases import split_settings

    try:  # a bad name or value fails here, before any run
        online, localizer = split_settings(out)
        OnlineConfig(**online)
        localizer_preset("city-objects").with_overrides(**localizer)
    except (TypeError, SglocError) as e:
        raise SystemExit(f"error: --set: {e}; the settings are OnlineConfig's fields, the "
                         "localizer's as localizer.NAME, the odometry noise model's as "
                         "odometry.NAME") from None
    return out


def run_fleet_groups(cases: list, settings: dict, timeout: float, results: dict) -> dict:
    """Run every case in a child process (time limit `timeout` s); results[key] replaced."""
    from sgloc.evaluation.fleet_cases import run_isolated

    suffix = "".join(f" [{k}={v}]" for k, v in sorted(settings.items()))
    for case in cases:
        res = run_isolated(case, settings, timeout)
        results[case.key + suffix] = res
        print(f"{case.title}{suffix}: {res['status']}, {brief(res)}", file=sys.stderr)
    return results


def brief(res: dict) -> str:
    """One line of a run's main figures (or its status)."""
    if res.get("status") != "done":
        return f"{res.get('child_seconds', 0):.0f} s"
    e = res["encounter"]
    return (f"{res['joined']}/{res['overlapping']} joined, {len(res['wrong_joins'])} wrong joins,"
            f" {res['wrong_accepted']} wrong accepted, encounter {fmt(e['median'])} / "
            f"{fmt(e['p95'])} m, RMSE {fmt(res['rmse'])} m, {res['seconds']:.0f} s, "
            f"{res['peak_mb']:.0f} MB")


def fleet_row(key: str, r: dict) -> list:
    """One row of a fleet group's table."""
    c = r["case"]
    settings = ", ".join(f"{k}={v}" for k, v in sorted(r.get("settings", {}).items())) or "-"
    if r.get("status") != "done":
        return [c["title"], settings, c["robots"], r["status"]] + ["-"] * 10
    e, o, lat = r["encounter"], r["oracle"], r["latency"]
    oracle = ("-" if o is None else
              f"{fmt(o['rmse'])}, {fmt(o['encounter']['median'])} / {fmt(o['encounter']['p95'])}")
    return [
        c["title"], settings, c["robots"],
        f"{r['placed']} / {r['joined']} / {r['overlapping']}",
        fmt(None if r["mean_delay"] is None else 100 * r["mean_delay"], "+.1f"),
        f"{len(r['wrong_joins'])}" + (f" ({', '.join(r['wrong_joins'])})" if r["wrong_joins"]
                                      else ""),
        f"{r['accepted']} ({r['wrong_accepted']} wrong) of {r['attempts']}",
        f"{fmt(e['median'])} / {fmt(e['p95'])} / {fmt(e['max'], '.1f')}", fmt(r["rmse"]), oracle,
        f"{r['revocations']} / {r['reacceptances']} ({r['most_reaccepted']})",
        f"{lat['median_ms']:.2f} / {lat['p99_ms']:.1f} / {lat['max_ms']:.0f}",
        f"{r['seconds']:.1f}" + (f" ({r['cpu_seconds']:.1f})" if "cpu_seconds" in r else ""),
        f"{r['peak_mb']:.0f}",
    ]


FLEET_HEADER = [
    "run", "settings", "robots", "placed / joined / overlapping (oracle)", "mean delay (% of run)",
    "wrong joins", "accepted attempts (wrong) of all", "encounter error median / p95 / max (m)",
    "fleet RMSE (m)", "oracle: RMSE, encounter median / p95 (m)",
    "revocations / re-acceptances (most for one link)", "latency median / p99 / max (ms)",
    "replay wall time (CPU time) (s)", "peak memory (MB)",
]


def fleet_goals(results: dict) -> list[str]:
    """The fleet goals, met or not, on the stored runs with the default settings (a goal no
    such run measures says so); runs with other settings are for comparison only."""
    def line(ok: bool | None, text: str) -> str:
        text = text.replace(" ()", "")
        return f"- {'not measured' if ok is None else 'met' if ok else '**NOT met**'}: {text}"

    everything = results
    results = {k: r for k, r in results.items() if not r.get("settings")}
    done = {k: r for k, r in results.items() if r.get("status") == "done"}
    wrong = {k: r["wrong_joins"] for k, r in done.items() if r["wrong_joins"]}
    wrong_acc = {k: r["wrong_accepted"] for k, r in done.items() if r["wrong_accepted"]}
    lines = [line(not wrong if done else None, "0 wrong joins in every run" + (
        " (wrong: " + "; ".join(f"{k}: {len(v)}" for k, v in wrong.items()) + ")" if wrong
        else "") + (" (wrong accepted attempts: " + ", ".join(
            f"{k} {v}" for k, v in wrong_acc.items()) + ")" if wrong_acc else ""))]
    drifting = {k: r for k, r in done.items() if r["case"]["level"] in (1.0, 2.0)}
    bad_enc, bad_rmse, bad_join = [], [], []
    for k, r in drifting.items():
        o = r["oracle"]
        if o is None or r["encounter"]["p95"] is None:
            continue
        enc_limit = max(0.5, 3 * (o["encounter"]["p95"] or 0.0))
        if r["encounter"]["p95"] > enc_limit:
            bad_enc.append(f"{k} {r['encounter']['p95']:.2f} > {enc_limit:.2f} m")
        rmse_limit = 1.25 * (o["rmse"] or 0.0) + 0.25
        if r["rmse"] is None or r["rmse"] > rmse_limit:
            bad_rmse.append(f"{k} {fmt(r['rmse'])} > {rmse_limit:.2f} m")
        delay = None if r["mean_delay"] is None else 100 * r["mean_delay"]
        if r["joined"] < r["overlapping"] or (delay or 0.0) > 100 * GOAL_DELAY:
            bad_join.append(f"{k} {r['joined']}/{r['overlapping']}, {fmt(delay, '+.1f')} %")
    have = bool(drifting) or None
    lines += [
        line(have and not bad_enc, "drift 1 and 2: encounter p95 <= max(0.5 m, 3 x the "
             "oracle's)" + (f" (not met: {'; '.join(bad_enc)})" if bad_enc else "")),
        line(have and not bad_rmse, "drift 1 and 2: fleet RMSE <= 1.25 x the oracle's + 0.25 m"
             + (f" (not met: {'; '.join(bad_rmse)})" if bad_rmse else "")),
        line(have and not bad_join, "drift 1 and 2: every overlapping robot joins, on average "
             "within 10 % of its run" + (f" (not met: {'; '.join(bad_join)})" if bad_join else "")),
    ]
    city0 = {k: r["rmse"] for k, r in done.items()
             if r["case"]["kind"] == "city" and r["case"]["level"] == 0.0
             and r["case"]["group"] == "drift"}
    lines.append(line(bool(city0) and all(v is not None and v <= 0.05 for v in city0.values())
                      if city0 else None, "drift 0: city fleet RMSE <= 0.05 m ("
                      + ", ".join(f"{k} {fmt(v, '.3f')} m" for k, v in city0.items()) + ")"))
    lines.append(kitti_drift0_line(done, everything, line))
    flip = {k: r["most_reaccepted"] for k, r in done.items() if r["most_reaccepted"] > 1}
    lines.append(line(not flip if done else None, "no link re-accepted more than once after a "
                      "revocation" + (f" (not met: {flip})" if flip else "")))
    long8 = {k: r["latency"] for k, r in done.items()
             if r["case"]["length"] >= 8000 and r["case"]["robots"] == 8}
    more = {k: r["latency"] for k, r in done.items()
            if r["case"]["length"] >= 8000 and r["case"]["robots"] != 8}
    lines.append(line(None if not long8 else all(
        v["median_ms"] <= GOAL_BIG_MEDIAN_MS and v["p99_ms"] <= GOAL_BIG_P99_MS
        for v in long8.values()), "latency median <= 5 ms and p99 <= 100 ms with 8 robots on "
        "8,000 m routes (" + ", ".join(f"{k} {v['median_ms']:.2f} / {v['p99_ms']:.1f} ms"
                                       for k, v in long8.items())
        + ")" + ("; with more robots, no goal: " + ", ".join(
            f"{k} {v['median_ms']:.2f} / {v['p99_ms']:.1f} ms" for k, v in more.items())
            if more else "")))
    many = {k: r for k, r in results.items() if r["case"]["robots"] == 128}
    lines.append(line(None if not many else all(
        r.get("status") == "done" and r["seconds"] <= GOAL_128_S for r in many.values()),
        "128 robots on the default city replayed in <= 3 minutes (" + ", ".join(
            f"{k} {r['seconds']:.0f} s" if r.get("status") == "done" else f"{k} {r['status']}"
            for k, r in many.items()) + ")"))
    heavy = {k: r["peak_mb"] for k, r in done.items() if r["peak_mb"] > GOAL_MB}
    lines.append(line(not heavy if done else None, "memory under 1 GB in every run (peak of the "
                      "run's process)" + (f" (not met: {heavy})" if heavy else "")))
    return lines


def kitti_drift0_line(done: dict, everything: dict, line) -> str:
    """The goal "drift 0: KITTI no worse than today": each default KITTI run at drift 0
    against the same run with one rigid frame per robot (`backend=robots`, the earlier
    default), on fleet RMSE and encounter p95."""
    pairs = {k: (r, everything.get(f"{k} [backend=robots]")) for k, r in done.items()
             if r["case"]["kind"] == "kitti" and r["case"]["level"] == 0.0
             and r["case"].get("odometry", "drift") != "raw"}
    pairs = {k: (r, ref) for k, (r, ref) in pairs.items()
             if ref is not None and ref.get("status") == "done"}
    ok = all(r["rmse"] <= ref["rmse"] and r["encounter"]["p95"] <= ref["encounter"]["p95"]
             for r, ref in pairs.values())
    return line(ok if pairs else None, "drift 0: KITTI no worse than one rigid frame per robot "
                "(fleet RMSE, encounter p95: " + "; ".join(
                    f"{k} {fmt(r['rmse'], '.3f')} m, {fmt(r['encounter']['p95'])} m against "
                    f"{fmt(ref['rmse'], '.3f')} m, {fmt(ref['encounter']['p95'])} m"
                    for k, (r, ref) in pairs.items()) + ")")


def fleet_section(results: dict) -> str:
    """The fleet runs' part of docs/online.md (between FLEET_BEGIN and FLEET_END)."""
    groups: dict[str, list] = {}
    for key, r in results.items():
        groups.setdefault(r["case"]["group"], []).append(fleet_row(key, r))
    tables = "".join(f"### {g}\n\n" + markdown_table(FLEET_HEADER, rows) + "\n"
                     for g, rows in groups.items())
    return (
        f"{FLEET_BEGIN}\n## Drifting odometry, bigger cities, many robots\n\n"
        "Regenerate a group with `python benchmarks/online.py --drift`, `--big-city`, "
        "`--many` or `--sparse` (KITTI 00 as a sparse one-class detector sees it: vehicles "
        "only, about 3 sightings per keyframe within 40 m, each moved along its line of sight "
        "by 1.5 % of its range, `sgloc.sim.detector`; 3 robots, scans 0-2999 and, held out, "
        "3000-4540) (`--set name=value` passes an OnlineConfig setting, `--set "
        "localizer.name=value` a localizer setting, `--set odometry.name=value` one of the "
        "odometry noise model's, `--timeout` the time limit of one run); "
        "the city runs use the localizer preset `city-objects` (the agreement check; its "
        "setting was chosen on pair attempts of the 12x12-block city, seeds 0-1: seeds 2-3, "
        "the 22x22-block city, the default city's 64 and 128 robots and the drift runs were "
        "never tuned on), the KITTI runs `kitti-objects`; every run replays in a child "
        "process of its own after a small warm-up replay, and its figures accumulate in "
        f"[{FLEET_RESULTS}]({FLEET_RESULTS}), from which this part is written.\n\n"
        "*Drift level L*: each robot's odometry drifts by a scale error of 0.5 L %, a heading "
        "bias of 0.002 L deg per metre and a heading random walk of 0.002 L deg per sqrt(metre) "
        "(`sgloc.sim.drift`, seeded); the sightings stay in the sensor frame. The KITTI drift "
        "runs drift the refined poses (the truth; KITTI's raw poses where gtsam is missing). "
        "*Wrong join* / *wrong accepted attempt*: the placement (a robot's first fleet frame; "
        "an attempt's transform) puts the robot's keyframes, where the truth has them within "
        f"20 m of keyframes of the robots placed by then, more than {MAX_M:g} m (median of "
        f"their relative position's error) or {MAX_DEG:g} deg off: judged where the robots "
        "meet, so that right but drifting placements are not called wrong. *Encounter "
        "error*: for every pair of keyframes of two different robots within 20 m of each other "
        "(truth), the error of their relative position in the fleet frame. *Fleet RMSE*: every "
        "placed robot's keyframe positions in the fleet frame against the truth after one rigid "
        "alignment of the whole fleet. *Oracle*: a pose graph over every robot's keyframes with "
        "the same drifting odometry and perfect loop closures wherever the truth puts two "
        "keyframes within 10 m (gtsam): what the odometry itself allows. The fleet's keyframe "
        "poses are the session's own per-keyframe poses when it keeps them, else its fleet "
        "frame applied to the odometry. *Latency*: wall time of each `add_keyframe` call; "
        "*replay wall time*: the whole replay (in brackets the process's CPU time during it: "
        "wall time also counts any wait for a processor); *peak memory*: the "
        "run's process, library and scenario included.\n\n"
        "The goals are judged on the runs with the default settings (settings \"-\": the "
        "keyframe back-end); the runs with other settings (such as `backend=robots`, one rigid "
        "frame per robot) are there for comparison.\n\n"
        + "\n".join(fleet_goals(results)) + "\n\n" + tables + f"{FLEET_END}\n"
    )


def splice(page_text: str, section: str) -> str:
    """`page_text` with its fleet part replaced by `section` (added at the end if absent)."""
    a, b = page_text.find(FLEET_BEGIN), page_text.find(FLEET_END)
    if a < 0 or b < 0:
        return page_text.rstrip("\n") + "\n\n" + section
    return page_text[:a] + section + page_text[b + len(FLEET_END) + 1:]


def load_results(path: Path) -> dict:
    import json

    return json.loads(path.read_text()) if path.is_file() else {}


def save_results(path: Path, results: dict) -> None:
    """Written whole then renamed, so a stopped run leaves the old file."""
    import json

    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(results, indent=1, default=float) + "\n")
    tmp.replace(path)


if __name__ == "__main__":
    sys.exit(main())
