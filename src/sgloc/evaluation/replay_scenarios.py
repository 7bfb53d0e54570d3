"""Recorded or simulated runs cut into robots, with ground truth: the KITTI 00 run, the
synthetic city and a small object world, each as RobotLogs ready to replay. The first two are
also `sgloc replay`'s named scenarios (`kitti00`, `city`), added here to the replay's
REPLAY_SCENARIOS.

Every robot's odometry frame is its first keyframe's sensor frame (the KITTI and city cuts) or
a random rigid frame (the object world); T_gt_odom places it in the ground-truth frame, so the
ground-truth sensor poses are T_gt_odom @ log.poses (the recorded poses are the odometry).
Each robot's stamps start at 0 s, so all robots run at once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sgloc.errors import SglocError
from sgloc.geometry import apply, invert, random_rigid_transform
from sgloc.io.keyframes import RobotLog, make_robot_log
from sgloc.replay.scenarios import REPLAY_SCENARIOS, ReplayInput


@dataclass
class Scenario:
    """Robots to replay and their ground truth (T_gt_odom per robot name). `truth`: the same
    robots with their TRUE odometry poses when `logs` carry drifting ones (`drifted`); None
    when the logs' poses are exact."""

    logs: list[RobotLog]
    T_gt_odom: dict[str, np.ndarray]
    class_names: tuple[str, ...] | None = None
    note: str = ""
    truth: list[RobotLog] | None = None

    @property
    def true_logs(self) -> list[RobotLog]:
        """The robots with their true odometry poses."""
        return self.logs if self.truth is None else self.truth

    def gt_poses(self) -> dict[str, np.ndarray]:
        """{robot: (k,4,4) true keyframe sensor poses in the ground-truth frame}."""
        return {g.name: self.T_gt_odom[g.name] @ g.poses for g in self.true_logs}


def drifted(scenario: Scenario, level: float, seed: int) -> Scenario:
    """`scenario` with every robot's odometry drifting at `level` (`sgloc.sim.drift`, robot k
    seeded with [seed, k]); the true poses kept as `truth`."""
    from sgloc.sim.drift import drift_log

    true = scenario.true_logs
    logs = [drift_log(g, level, np.random.default_rng([seed, k])) for k, g in enumerate(true)]
    return Scenario(logs, scenario.T_gt_odom, scenario.class_names,
                    f"{scenario.note}, odometry drift level {level:g} (seed {seed})", true)


def sparse(scenario: Scenario, seed: int, label: int = 0) -> Scenario:
    """`scenario` as a sparse one-class detector sees it (`sgloc.sim.detector`, defaults:
    about 3 sightings per keyframe within 40 m, depth noise 1.5 % of range), class `label`
    only (KITTI's 0: vehicles); robot k seeded with [seed, k]. Exact odometry only (drift
    it afterwards)."""
    from sgloc.sim.detector import sparse_detections

    if scenario.truth is not None:
        raise SglocError("sparse detections: thin the exact scenario, then drift it.")
    logs = [sparse_detections(g, label, np.random.default_rng([seed, k]))
            for k, g in enumerate(scenario.logs)]
    names = scenario.class_names
    return Scenario(logs, scenario.T_gt_odom, names, f"{scenario.note}, sparse detections of "
                    f"class {names[label] if names else label}")


def segments(first: int, last: int, n: int) -> list[tuple[int, int]]:
    """`n` consecutive, non-overlapping (first, last) index ranges covering first..last."""
    if n < 1 or last - first + 1 < 2 * n:
        raise SglocError(f"cannot cut {last - first + 1} frames into {n} robots; use fewer robots.")
    edges = np.linspace(first, last + 1, n + 1).round().astype(int)
    return [(int(a), int(b) - 1) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def log_from_frames(
    name: str,
    stamps_s: np.ndarray,
    T_world_sensor: np.ndarray,
    detections: Sequence[tuple[np.ndarray, np.ndarray]],
    T_world_odom: np.ndarray,
) -> RobotLog:
    """A RobotLog from world-frame sensor poses and per-frame sensor-frame detections."""
    from scipy.spatial.transform import Rotation

    T = invert(T_world_odom) @ T_world_sensor
    kf = np.concatenate([np.full(len(p), i) for i, (p, _) in enumerate(detections)])
    pos = np.concatenate([p for p, _ in detections]).reshape(-1, 3)
    lab = np.concatenate([lb for _, lb in detections])
    ns = np.round((np.asarray(stamps_s) - stamps_s[0]) * 1e9).astype(np.int64)
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    return make_robot_log(name, ns, T[:, :3, 3], q, kf, pos, lab)


def kitti_scenario(
    n_robots: int, first: int = 0, last: int = 2999, every: int = 1, poses: str = "raw"
) -> Scenario:
    """KITTI 00 scans first..last cut into `n_robots` consecutive segments (robot k = `kitti<k>`),
    every `every`-th scan a keyframe; detections of the GOSMatch objects; odometry AND ground
    truth = the KITTI poses: `poses` "raw" (poses_00.txt) or "refined" (made consistent with
    the refined revisit transforms, `kitti_refined.kitti_refined_poses`; needs gtsam);
    ground-truth frame = the sequence frame."""
    from sgloc.datasets import make_dataset
    from sgloc.datasets.kitti_objects import CLASS_NAMES
    from sgloc.evaluation.pairs_kitti import kitti_root, kitti_sequence
    from sgloc.io.text import read_numbers

    if poses not in ("raw", "refined"):
        raise SglocError(f"poses={poses!r}: choose 'raw' or 'refined'.")
    root = kitti_root()
    L = kitti_sequence(root)[0]
    if poses == "refined":
        from sgloc.evaluation.kitti_refined import kitti_refined_poses

        L = kitti_refined_poses(root)
    times = read_numbers(Path(root) / "times_00.txt", "KITTI times")[:, 0]
    logs, gt = [], {}
    for k, (a, b) in enumerate(segments(first, last, n_robots)):
        ds = make_dataset("kitti_objects", root, scans=(a, b))
        idx = np.arange(0, b - a + 1, every)
        frames = [ds[int(i)] for i in idx]
        det = [f.detections for f in frames]
        scans = a + idx
        name = f"kitti{k}"
        logs.append(log_from_frames(name, times[scans], L[scans], det, L[a]))
        gt[name] = L[a]
    note = (f"KITTI 00 scans {first}-{last} in {n_robots} robots, every {every} scan(s), "
            f"{poses} poses")
    return Scenario(logs, gt, tuple(CLASS_NAMES), note)


def observe(
    T_world_sensor: np.ndarray,
    pos: np.ndarray,
    lab: np.ndarray,
    rng: np.random.Generator,
    view: tuple[float, float, float, float] = (30.0, 70.0, 0.9, 0.1),
) -> tuple[np.ndarray, np.ndarray]:
    """Objects one keyframe sees: within `view` = (range m, half field of view deg about the
    sensor x axis, keep probability, Gaussian noise m), in the SENSOR frame."""
    rng_m, fov, keep, noise = view
    p = apply(invert(T_world_sensor), pos)
    d = np.linalg.norm(p[:, :2], axis=1)
    ang = np.degrees(np.abs(np.arctan2(p[:, 1], p[:, 0])))
    seen = (d < rng_m) & (ang < fov) & (rng.random(len(p)) < keep)
    return p[seen] + rng.normal(0, noise, (int(seen.sum()), 3)), lab[seen]


def city_scenario(
    n_robots: int = 8, seed: int = 0, overlap: float = 0.5, period: float = 0.15,
    length: float = 400.0, blocks: int | None = None,
) -> Scenario:
    """The synthetic city run `seed` (its two routes, as in the `city` pairs) cut into
    `n_robots` robots (half per route, consecutive segments; robot `city<k>`), one keyframe
    per route frame, `period` seconds apart. Objects only (no rendering): each keyframe sees
    the city's objects (bounding-box centres) all around within 40 m, like a LiDAR, each with
    probability 0.9 and 0.1 m noise; ground-truth frame = the city frame. `length`: metres
    of each route; `blocks`: blocks of the city each way (None: the default city)."""
    from sgloc.sim.city import CITY_CLASSES, CityConfig
    from sgloc.sim.run import make_synthetic_run

    if n_robots < 2 or n_robots % 2:
        raise SglocError(f"--robots {n_robots}: the city has two routes; give an even number.")
    city = CityConfig() if blocks is None else CityConfig(blocks=blocks)
    run = make_synthetic_run(seed=seed, overlap=overlap, length=length, city=city)
    rng = np.random.default_rng([seed, 17])
    pos, lab = run.city.object_positions, run.city.object_labels
    logs, gt = [], {}
    for route in run.robots:
        T_all = run.routes.T_world_body[route]
        for a, b in segments(0, len(T_all) - 1, n_robots // 2):
            T = T_all[a : b + 1]
            det = [observe(Ti, pos, lab, rng, (40.0, 180.0, 0.9, 0.1)) for Ti in T]
            name = f"city{len(logs)}"
            logs.append(log_from_frames(name, np.arange(len(T)) * period, T, det, T[0]))
            gt[name] = T[0]
    size = ("" if blocks is None and length == 400.0
            else f", {city.blocks} blocks, {length:g} m routes")
    note = f"synthetic city {seed} (overlap {overlap:g}{size}) in {n_robots} robots, objects only"
    return Scenario(logs, gt, tuple(CITY_CLASSES), note)


def world_scenario(
    stretches: Sequence[tuple[float, float]] = ((0.0, 200.0), (100.0, 300.0)),
    seed: int = 0,
    spacing: float = 4.0,
    period: float = 0.5,
) -> Scenario:
    """Robots driving stretches [x0, x1] (metres) of the main street of a small object world
    (`sgloc.sim.object_world`), a keyframe every `spacing` metres, `period` seconds apart;
    each robot's odometry frame is a random rigid frame (robot `world<k>`)."""
    from sgloc.sim.object_world import make_object_world

    rng = np.random.default_rng([seed, 23])
    pos, lab = make_object_world(rng, length=max(b for _, b in stretches) + 60.0)
    logs, gt = [], {}
    for k, (x0, x1) in enumerate(stretches):
        x = np.arange(x0, x1 + 1e-9, spacing)
        T = np.tile(np.eye(4), (len(x), 1, 1))
        T[:, 0, 3], T[:, 2, 3] = x, 1.5
        det = [observe(Ti, pos, lab, rng, (30.0, 180.0, 0.9, 0.05)) for Ti in T]
        T_world_odom = random_rigid_transform(rng, 100.0, 3.0)
        name = f"world{k}"
        logs.append(log_from_frames(name, np.arange(len(x)) * period, T, det, T_world_odom))
        gt[name] = T_world_odom
    return Scenario(logs, gt, None, f"object world {seed}: {len(stretches)} robots")


def lost_robot(offset_ns: int = 0) -> RobotLog:
    """`lost`: 12 keyframes, 3 m apart along x, each seeing the same 40 objects of a random world
    of its own (8 classes), stamps from `offset_ns` + 0.25 s every 0.7 s: a robot no other
    shares objects with, so it is never placed."""
    rng = np.random.default_rng(5)
    n = 12
    xyz = np.column_stack([np.arange(n) * 3.0, np.zeros(n), np.zeros(n)])
    world, classes = rng.uniform(-40, 40, (40, 3)), rng.integers(0, 8, 40)  # seen every time
    return make_robot_log("lost", offset_ns + 250_000_001 + 700_000_000 * np.arange(n), xyz,
                          np.tile([0, 0, 0, 1.0], (n, 1)), np.repeat(np.arange(n), len(world)),
                          np.concatenate([world - p for p in xyz]), np.tile(classes, n))


@REPLAY_SCENARIOS.register("kitti00")
def kitti00(robots: int = 4, scans: str = "0-2999", every: int = 1,
            poses: str = "raw") -> ReplayInput:
    """KITTI 00 (data `kitti00`) scans `first-last` cut into `robots` consecutive segments,
    every `every`-th scan a keyframe; `poses` raw (poses_00.txt) or refined (needs gtsam)
    (`kitti_scenario`)."""
    try:
        first, last = (int(v) for v in scans.split("-"))
    except ValueError:
        raise SglocError(f"--scans {scans!r}: give first-last, e.g. 0-2999.") from None
    if last < first:
        raise SglocError(f"--scans {scans!r}: the last scan comes before the first; give "
                         "first-last, e.g. 0-2999.")
    return ReplayInput(kitti_scenario(robots, first, last, every, poses).logs, "kitti-objects")


@REPLAY_SCENARIOS.register("city")
def city(robots: int = 4, seed: int = 0) -> ReplayInput:
    """The synthetic city `seed`'s two routes cut into `robots` robots, objects only
    (`city_scenario`)."""
    return ReplayInput(city_scenario(robots, seed).logs, "city-objects")
