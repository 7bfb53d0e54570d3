"""One fleet replay scored against its ground truth for the drift, big-city and many-robot
groups of `benchmarks/online.py`: joins, wrong joins and wrong accepted attempts (judged where
the robots meet, so that a drifting but right placement is not called wrong), encounter error,
fleet RMSE, the oracle's, revocations, latency and wall time.

A placement is *wrong* when, over the keyframe pairs it puts within 20 m of keyframes of
robots already placed (the closest pair if none), the median error of their relative position
exceeds 3 m or that of their relative rotation 3 deg (`fleet_metrics.placement_error`).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from sgloc.evaluation.fleet_metrics import (
    encounter_errors,
    error_stats,
    fleet_keyframe_poses,
    odometry_bend,
    outside_truth_group,
    placement_error,
    rigid_rmse,
)
from sgloc.evaluation.online_oracle import oracle_join_stamps
from sgloc.evaluation.online_replay import MAX_DEG, MAX_M
from sgloc.geometry import invert


def run_fleet(scenario: Any, config: Any, online: Any, level: float = 0.0,
              oracle: bool = True) -> dict:
    """Replay `scenario` (a replay_scenarios.Scenario) through a fresh OnlineSession with the
    localizer `config` and `online` settings and score it (`score_fleet`); `level`: the drift
    level of its odometry (the oracle's noise model); `oracle`: solve the oracle too. Adds the
    replay's wall time (`seconds`) and the process's CPU time during it (`cpu_seconds`)."""
    from sgloc.online import OnlineSession
    from sgloc.replay import replay_logs

    session = OnlineSession(config, online)
    t0, c0 = time.perf_counter(), time.process_time()
    record = replay_logs(scenario.logs, session)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    out = score_fleet(scenario, session, record, level, oracle)
    out.update(seconds=seconds, cpu_seconds=cpu)
    return out


def score_fleet(scenario: Any, session: Any, record: Any, level: float,
                oracle: bool = True) -> dict:
    """The figures of one replayed fleet (see the module docstring)."""
    from sgloc.replay.outputs import latency_stats

    names = [g.name for g in scenario.logs]
    gt = scenario.gt_poses()
    T_fleet_gt = invert(scenario.T_gt_odom[session.root])
    est = [fleet_keyframe_poses(session, r) for r in names]
    placed = [k for k, e in enumerate(est) if e is not None]
    out = {
        "robots": len(names), "keyframes": int(sum(len(g) for g in scenario.logs)),
        "placed": len(placed),
        "encounter": error_stats(encounter_errors(est, [gt[r] for r in names], T_fleet_gt)),
        "rmse": rigid_rmse([est[k][:, :3, 3] for k in placed],
                           [gt[names[k]][:, :3, 3] for k in placed]),
        "latency": latency_stats(np.concatenate(list(record.latency_ms.values()))),
        **join_figures(scenario, session, record),
        **attempt_figures(scenario, session),
        **revocation_figures(session),
        **bend_figures(scenario, est, names),
        **loop_figures(scenario, session),
    }
    out["oracle"] = oracle_figures(scenario, session.root, level) if oracle else None
    return out


def bend_figures(scenario: Any, est: list, names: list[str]) -> dict:
    """How far the solution bent each placed robot's odometry (`odometry_bend`: max over its
    keyframes, metres; "bend" max / median over the robots) and the robots outside the group
    one rigid alignment puts on the truth (`outside_truth_group`, "outside")."""
    gt = scenario.gt_poses()
    bends = {names[k]: float(odometry_bend(e, scenario.logs[k].poses).max())
             for k, e in enumerate(est) if e is not None and len(e)}
    out = outside_truth_group(est, [gt[r] for r in names])
    values = list(bends.values())
    return {"bend": {"max": max(values, default=None),
                     "median": float(np.median(values)) if values else None,
                     "robots": bends},
            "outside": [names[k] for k in out]}


def loop_figures(scenario: Any, session: Any, near: float = 10.0, before: float = 200.0
                 ) -> dict:
    """Per robot, the loop closures in its fleet frame at the end (active links within the
    robot, keyframe back-end) and its revisits: keyframes the truth puts within `near` m of
    one of its own keyframes at least `before` m earlier along its path."""
    from scipy.spatial import cKDTree

    gt = scenario.gt_poses()
    loops = {g.name: 0 for g in scenario.logs}
    for lk in session.links:
        if lk.active and lk.robot_a == lk.robot_b:
            loops[lk.robot_a] += 1
    revisits = {}
    for name, X in gt.items():
        P = X[:, :3, 3]
        along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))]
        pairs = cKDTree(P).query_pairs(near, output_type="ndarray")
        far = np.abs(along[pairs[:, 1]] - along[pairs[:, 0]]) >= before
        revisits[name] = len(np.unique(pairs[far].max(axis=1)))
    return {"loops": loops, "revisits": revisits}


def join_figures(scenario: Any, session: Any, record: Any) -> dict:
    """Joined / overlapping robots (the oracle of `online_oracle.oracle_join_stamps` on the
    true poses), mean delay (fraction of the run), and the robots whose join was wrong."""
    root = session.root
    join_oracle = oracle_join_stamps(scenario.true_logs, scenario.T_gt_odom, root)
    gt = scenario.gt_poses()
    R = invert(scenario.T_gt_odom[root])[:3, :3]
    logs = {g.name: g for g in scenario.logs}
    overlapping, joined, delays, wrong, errors = 0, 0, [], [], {}
    for name, g in logs.items():
        if name == root:
            continue
        j = record.joined_ns.get(name)
        run = float(g.stamps[-1] - g.stamps[0]) or 1.0
        if np.isfinite(join_oracle[name]):
            overlapping += 1
            if j is not None:
                joined += 1
                delays.append((j * 1e-9 - join_oracle[name]) / run)
        if j is None:
            continue
        err = _join_error(name, j, logs, gt, record.transforms, R)
        errors[name] = err
        if err is not None and (err[0] > MAX_M or err[1] > MAX_DEG):
            wrong.append(name)
    return {"overlapping": overlapping, "joined": joined,
            "mean_delay": float(np.mean(delays)) if delays else None,
            "wrong_joins": wrong, "join_errors": errors}


def _join_error(name: str, t_ns: int, logs: dict, gt: dict, transforms: list,
                R_fleet_gt: np.ndarray) -> tuple[float, float] | None:
    """`placement_error` of robot `name`'s first fleet frame at its keyframes up to its join
    stamp against the robots placed by then (their fleet frames then, their keyframes then)."""
    now: dict[str, np.ndarray] = {}
    first = None
    for stamp, robot, T in transforms:
        if stamp > t_ns:
            break
        if robot == name:
            first = T if first is None else first
        else:
            now[robot] = T
    if first is None or not now:
        return None
    mine = logs[name].stamps_ns <= t_ns
    est_b, gt_b = [], []
    for robot, T in now.items():
        k = logs[robot].stamps_ns <= t_ns
        est_b.append(T @ logs[robot].poses[k])
        gt_b.append(gt[robot][k])
    return placement_error(first @ logs[name].poses[mine], gt[name][mine],
                           np.concatenate(est_b), np.concatenate(gt_b), R_fleet_gt)


def attempt_figures(scenario: Any, session: Any) -> dict:
    """Accepted attempts and the wrong ones: T_target_query judged by `placement_error` at
    the two robots' keyframes up to the attempt (target's odometry frame)."""
    gt = scenario.gt_poses()
    logs = {g.name: g for g in scenario.logs}
    accepted = [a for a in session.attempts if a.accepted and a.transform is not None]
    wrong = 0
    for a in accepted:
        ns = round(a.stamp * 1e9)
        q, t = logs[a.query].stamps_ns <= ns, logs[a.target].stamps_ns <= ns
        err = placement_error(a.transform @ logs[a.query].poses[q], gt[a.query][q],
                              logs[a.target].poses[t], gt[a.target][t],
                              invert(scenario.T_gt_odom[a.target])[:3, :3])
        wrong += err is not None and (err[0] > MAX_M or err[1] > MAX_DEG)
    return {"attempts": len(session.attempts), "accepted": len(accepted),
            "wrong_accepted": int(wrong)}


def revocation_figures(session: Any) -> dict:
    """Links revoked, re-accepted after a revocation, and the most re-acceptances of one pair
    after its first revocation (from the session's events)."""
    from sgloc.online.records import LINK_ACCEPTED, LINK_REVOKED

    revoked: dict[tuple, int] = {}
    again: dict[tuple, int] = {}
    for e in session.events:
        pair = tuple(sorted(e.robots))
        if e.kind == LINK_REVOKED:
            revoked[pair] = revoked.get(pair, 0) + 1
        elif e.kind == LINK_ACCEPTED and pair in revoked:
            again[pair] = again.get(pair, 0) + 1
    return {"revocations": int(sum(revoked.values())),
            "reacceptances": int(sum(again.values())),
            "most_reaccepted": max(again.values(), default=0)}


def oracle_figures(scenario: Any, root: str, level: float) -> dict | None:
    """The oracle pose graph's (`fleet_oracle.oracle_fleet`) fleet RMSE and encounter error;
    None without gtsam."""
    from sgloc.evaluation.fleet_oracle import oracle_fleet

    names = [g.name for g in scenario.logs]
    gt = scenario.gt_poses()
    G = [gt[r] for r in names]
    t0 = time.perf_counter()
    est = oracle_fleet([g.poses for g in scenario.logs], G, names.index(root), level)
    if est is None:
        return None
    used = [k for k, e in enumerate(est) if e is not None]
    return {
        "rmse": rigid_rmse([est[k][:, :3, 3] for k in used], [G[k][:, :3, 3] for k in used]),
        "encounter": error_stats(encounter_errors(est, G, invert(scenario.T_gt_odom[root]))),
        "robots": len(used), "seconds": time.perf_counter() - t0,
    }
