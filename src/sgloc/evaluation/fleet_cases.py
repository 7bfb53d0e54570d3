"""The fleet benchmark's runs (`benchmarks/online.py --drift / --big-city / --many`): what to
replay (`Case`), and one run in a child process with a time limit and its peak memory."""

from __future__ import annotations

import dataclasses
import resource
import time
from dataclasses import dataclass
from typing import Any

from sgloc.errors import SglocError


@dataclass(frozen=True)
class Case:
    """One benchmark run. kind "city": the synthetic city `seed` (`blocks` x `blocks`, routes
    of `length` m) cut into `robots`; kind "kitti": KITTI 00 scans first..last cut into
    `robots`, every `every` scan a keyframe, truth = `truth` poses ("refined" or "raw") and
    odometry = the truth drifting at `level`, or KITTI's raw poses (`odometry="raw"`);
    localizer: the localizer preset (default "city-objects" for a city, else
    "kitti-objects"); detections: "all" (the run's own) or "sparse" (a one-class detector's
    view of them, `replay_scenarios.sparse`, seeded with `seed`)."""

    key: str
    group: str
    title: str
    kind: str
    robots: int
    level: float = 0.0
    seed: int = 0
    length: float = 400.0
    blocks: int | None = None
    first: int = 0
    last: int = 2999
    every: int = 1
    truth: str = "refined"
    odometry: str = "drift"
    part: str = ""
    localizer: str = ""
    detections: str = "all"

    @property
    def preset(self) -> str:
        """The localizer preset: `localizer` when given, else the kind's."""
        if self.localizer:
            return self.localizer
        return "city-objects" if self.kind == "city" else "kitti-objects"


def case_scenario(case: Case) -> Any:
    """The replay_scenarios.Scenario of `case` (odometry drifting as it says)."""
    from sgloc.evaluation import replay_scenarios as sc

    if case.kind == "city":
        base = sc.city_scenario(case.robots, case.seed, length=case.length, blocks=case.blocks)
    elif case.kind == "kitti":
        base = sc.kitti_scenario(case.robots, case.first, case.last, case.every, case.truth)
        if case.odometry == "raw":  # KITTI's own poses as the odometry, against the truth
            raw = sc.kitti_scenario(case.robots, case.first, case.last, case.every, "raw")
            return sc.Scenario(raw.logs, base.T_gt_odom, base.class_names,
                               f"{base.note}; odometry: KITTI's raw poses", base.logs)
    else:
        raise SglocError(f"case {case.key}: unknown kind {case.kind!r}; use 'city' or 'kitti'.")
    if case.detections == "sparse":
        base = sc.sparse(base, case.seed)
    elif case.detections != "all":
        raise SglocError(f"case {case.key}: detections {case.detections!r}; use 'all' or "
                         "'sparse'.")
    return sc.drifted(base, case.level, case.seed) if case.level > 0 else base


def run_case(case: Case, settings: dict, oracle: bool = True) -> dict:
    """Warm up (one small replay, so compilation is not counted), build the case's scenario,
    replay and score it (`fleet_runs.run_fleet`); adds the scenario build time and the
    process's peak memory (MB)."""
    import tempfile
    from pathlib import Path

    from sgloc.evaluation.fleet_runs import run_fleet
    from sgloc.evaluation.online_replay import run_scenario
    from sgloc.evaluation.replay_scenarios import world_scenario
    from sgloc.online import OnlineConfig
    from sgloc.pipeline.presets import localizer_preset

    online, localizer = split_settings(settings)
    config = localizer_preset(case.preset).with_overrides(**localizer)
    with tempfile.TemporaryDirectory() as d:
        run_scenario(world_scenario(), Path(d) / "warm", config)
    t0 = time.perf_counter()
    scenario = case_scenario(case)
    built = time.perf_counter() - t0
    out = run_fleet(scenario, config, OnlineConfig(**online), case.level, oracle)
    out.update(case=dataclasses.asdict(case), settings=settings, build_seconds=built,
               peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
               status="done")
    return out


#: A setting named with this prefix goes to the localizer (`LocalizerConfig.with_overrides`),
#: e.g. "localizer.layout_shifts"; one with ODOMETRY_PREFIX to the odometry's noise model
#: (`OdometryNoise`, e.g. "odometry.translation_per_metre"); the others are OnlineConfig's.
LOCALIZER_PREFIX, ODOMETRY_PREFIX = "localizer.", "odometry."


def split_settings(settings: dict) -> tuple[dict, dict]:
    """(OnlineConfig keyword arguments, localizer overrides) of a run's `settings`."""
    from sgloc.online import OdometryNoise

    def part(prefix: str) -> dict:
        return {k[len(prefix):]: v for k, v in settings.items() if k.startswith(prefix)}

    online = {k: v for k, v in settings.items()
              if not k.startswith((LOCALIZER_PREFIX, ODOMETRY_PREFIX))}
    if part(ODOMETRY_PREFIX):
        online["odometry"] = OdometryNoise(**part(ODOMETRY_PREFIX))
    return online, part(LOCALIZER_PREFIX)


def _child(case: Case, settings: dict, oracle: bool, queue: Any) -> None:
    try:
        queue.put(run_case(case, settings, oracle))
    except Exception as e:  # reported as the run's outcome, not lost with the child
        queue.put({"case": dataclasses.asdict(case), "settings": settings,
                   "status": f"failed: {type(e).__name__}: {e}"})


def run_isolated(case: Case, settings: dict, timeout: float, oracle: bool = True) -> dict:
    """`run_case` in a fresh child process (its own memory peak), stopped after `timeout`
    seconds (then status "timed out after ... s")."""
    import multiprocessing as mp
    import queue as queue_mod

    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_child, args=(case, settings, oracle, q))
    t0 = time.perf_counter()
    p.start()
    try:
        out = q.get(timeout=timeout)
    except queue_mod.Empty:
        out = {"case": dataclasses.asdict(case), "settings": settings,
               "status": f"timed out after {timeout:g} s"}
    p.join(5.0)
    if p.is_alive():
        p.terminate()
        p.join()
    out["child_seconds"] = time.perf_counter() - t0
    return out
