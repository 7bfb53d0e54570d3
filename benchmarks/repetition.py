"""Pair attempts on repetitive street grids: wrong and right accepts, with and without the
repetition rule of the acceptance test.

    python benchmarks/repetition.py [--seeds 0 1] [--robots 10 8] [--cache DIR] [--out FILE]

The synthetic city's two routes (`sgloc.sim.make_synthetic_run`) are cut into robots exactly
as the `--city` replay cuts them (`sgloc.evaluation.replay_scenarios`), in two sizes: the
default 7x7-block city (400 m routes) and a 12x12-block city with 2,000 m routes. Each cut is
replayed through an online session (`sgloc replay`'s code path, city preset, session seed =
city seed), and every pair attempt it makes (a partial map of one robot against another's)
is recorded: the attempt set is fixed once (cached under --cache) so that each setting is
scored on the same attempts. Each attempt is then localized again under each setting; an
accept is wrong when the robot is more than 3 m (or 3 deg) off at its objects, as the online
benchmark counts it. Tuning seeds are 0-1; seeds 2-3 are reported apart and never tuned on.
Settings (acceptance, over the city preset): `defaults` (the repetition checks off),
`layout 8` (`layout_shifts=8`: the maps' own repetition, measured by 8 self-similar shifts
of each map, as a rival: check 3 of `sgloc.acceptance.repetition`),
`shifts 8` (`repetition_shifts=8`: the target's self-similar shifts as rivals), `agreement
0.75` (`min_agreement=0.75`: the claimed overlap must mostly agree); seconds: all attempts of
the row, one process, with other processes running. The attempts were recorded under the
settings the session had when they were cached (their maps and pairs, not their verdicts,
depend on it).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from sgloc.evaluation.online_oracle import robot_error
from sgloc.evaluation.online_replay import MAX_DEG, MAX_M
from sgloc.evaluation.replay_scenarios import Scenario, city_scenario
from sgloc.maps.graph import SemanticGraph

#: (name, `replay_scenarios.city_scenario` size settings) of the two city sizes.
CITIES = {
    "default": {},
    "big": {"length": 2000.0, "blocks": 12},
}


def city_cut(seed: int, n_robots: int, settings: dict) -> Scenario:
    """The synthetic city run `seed` of the size `settings` cut into `n_robots` robots as the
    `--city` replay cuts it (`replay_scenarios.city_scenario`)."""
    return city_scenario(n_robots, seed, **settings)


def capture_attempts(scenario: Scenario, seed: int) -> list[dict]:
    """Replay `scenario` through an online session (city preset) and return every attempt it
    made: query and target graphs (arrays), the seed, and the ground truth of the pair."""
    import sgloc.online.session as session_module
    from sgloc.online import OnlineConfig, OnlineSession
    from sgloc.pipeline.presets import localizer_preset
    from sgloc.replay import replay_logs

    recorded: list[tuple] = []
    original = session_module.run_attempts

    def recording(pairs, config, scheduler=None, workers=0):
        recorded.extend(pairs)
        return original(pairs, config, scheduler, workers)

    session_module.run_attempts = recording
    try:
        session = OnlineSession(localizer_preset("city"), OnlineConfig(seed=seed))
        replay_logs(scenario.logs, session)
    finally:
        session_module.run_attempts = original
    out = []
    for q, t, s in recorded:
        t = getattr(t, "graph", t)  # a prepared map holds its graph
        out.append({"query": q.name, "target": t.name, "qpos": q.positions,
                    "qlab": q.labels, "qr": q.edge_radius, "tpos": t.positions,
                    "tlab": t.labels, "tr": t.edge_radius, "seed": list(s)})
    return out


def load_or_capture(city: str, seed: int, robots: int, cache: Path) -> tuple[list, Scenario]:
    """The attempts of one cut (from `cache` when there) and its scenario."""
    import pickle

    sc = city_cut(seed, robots, CITIES[city])
    path = cache / f"{city}_s{seed}_r{robots}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes()), sc
    attempts = capture_attempts(sc, seed)
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps(attempts))
    tmp.replace(path)
    return attempts, sc


def score(attempts: list, sc: Scenario, settings: dict) -> dict:
    """Localize every attempt under `settings` (acceptance settings over the city preset):
    counts of right and wrong accepts, refusals, the wrong accepts' errors, and seconds."""
    from sgloc.pipeline.localizer import Localizer
    from sgloc.pipeline.presets import localizer_preset

    cfg = localizer_preset("city").with_overrides(**settings)
    loc = Localizer(cfg)
    right = wrong = refused = 0
    errors, secs = [], 0.0
    for a in attempts:
        q = SemanticGraph(a["qpos"], a["qlab"], a["qr"], name="query")
        t = SemanticGraph(a["tpos"], a["tlab"], a["tr"], name="target")
        t0 = time.perf_counter()
        res = loc(q, t, np.random.default_rng(a["seed"]))
        secs += time.perf_counter() - t0
        if not res.accepted:
            refused += 1
            continue
        G_a, G_b = sc.T_gt_odom[a["target"]], sc.T_gt_odom[a["query"]]
        dm, dd = robot_error(res.transform, G_a, G_b, a["qpos"])
        if dm > MAX_M or dd > MAX_DEG:
            wrong += 1
            errors.append(dm)
        else:
            right += 1
    return {"attempts": len(attempts), "right": right, "wrong": wrong, "refused": refused,
            "wrong_m": errors, "seconds": secs}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--robots", type=int, nargs="+", default=[10, 8])
    p.add_argument("--cities", nargs="+", default=list(CITIES), choices=list(CITIES))
    p.add_argument("--cache", type=Path, default=Path("/tmp/sgloc_repetition"))
    p.add_argument("--variants", nargs="+",
                   default=["defaults", "layout 8", "shifts 8", "agreement 0.75"],
                   choices=["defaults", "layout 8", "shifts 8", "agreement 0.75"],
                   help="defaults: the repetition checks off; 'layout 8': layout_shifts=8; "
                        "'shifts 8': repetition_shifts=8; 'agreement 0.75': min_agreement=0.75")
    p.add_argument("--out", type=Path, default=None,
                   help="also write the table (with this command) to this markdown file")
    args = p.parse_args(argv)
    variants = {"defaults": {}, "layout 8": {"layout_shifts": 8},
                "shifts 8": {"repetition_shifts": 8}, "agreement 0.75": {"min_agreement": 0.75}}
    lines = ["| city | seed | robots | setting | attempts | right accepts | wrong accepts "
             "| wrong: metres off (median, max) | seconds |", "|---" * 9 + "|"]
    print("\n".join(lines))
    for city in args.cities:
        for seed in args.seeds:
            for robots in args.robots if city == "big" else [8]:
                attempts, sc = load_or_capture(city, seed, robots, args.cache)
                for v in args.variants:
                    r = score(attempts, sc, variants[v])
                    e = r["wrong_m"]
                    off = f"{np.median(e):.0f}, {np.max(e):.0f}" if e else "-"
                    lines.append(f"| {city} | {seed} | {robots} | {v} | {r['attempts']} "
                                 f"| {r['right']} | {r['wrong']} | {off} | {r['seconds']:.1f} |")
                    print(lines[-1], flush=True)
    if args.out is not None:
        cmd = "python benchmarks/repetition.py " + shlex.join(argv or sys.argv[1:])
        text = (f"# Pair attempts on repetitive street grids\n\nGenerated by `{cmd}` (do not "
                "edit by hand).\n\n" + __doc__.split("\n\n", 2)[2].strip() + "\n\n"
                + "\n".join(lines) + "\n")
        tmp = args.out.with_suffix(".tmp")
        tmp.write_text(text)
        tmp.replace(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
