"""Score one replay of a Scenario against its ground truth (the `benchmarks/online.py` rows)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.evaluation.online_oracle import oracle_join_stamps, oracle_link_frames, robot_error

#: A placement or link is wrong beyond these (metres at the robot's objects, degrees).
MAX_M, MAX_DEG = 3.0, 3.0


def run_scenario(scenario: Any, out: Path, config: Any = None, online: Any = None) -> dict:
    """Replay `scenario` through a fresh OnlineSession, write the replay folder `out` (plus
    `gt/<stem>.tum`, each robot's ground-truth keyframe poses) and score it."""
    from sgloc.io.files import staged_folder

    with staged_folder(out) as stage:  # the replay folder and the score, whole or not at all
        return _run_into(scenario, Path(stage), config, online)


def _run_into(scenario: Any, out: Path, config: Any, online: Any) -> dict:
    """run_scenario's work, written into the existing folder `out`."""
    from sgloc.evaluation.fleet_trajectory import fleet_ape
    from sgloc.io.names import robot_file_stems
    from sgloc.io.poses import write_tum
    from sgloc.online import OnlineSession
    from sgloc.replay import replay_logs
    from sgloc.replay.outputs import fleet_poses, write_replay_into

    session = OnlineSession(config, online)
    record = replay_logs(scenario.logs, session)
    summary = write_replay_into(out, scenario.logs, session, record)
    stems = robot_file_stems([g.name for g in scenario.logs])
    T_oracle = oracle_link_frames(session, scenario.T_gt_odom)
    pairs, oracle_pairs = [], []
    for g in scenario.logs:
        gt = out / "gt" / f"{stems[g.name]}.tum"
        write_tum(gt, g.stamps_ns, *fleet_poses(g, scenario.T_gt_odom[g.name]))
        if summary["robots"][g.name]["placed"]:
            pairs.append((out / summary["robots"][g.name]["file"], gt))
        if g.name in T_oracle:
            est = out / "oracle" / f"{stems[g.name]}.tum"
            write_tum(est, g.stamps_ns, *fleet_poses(g, T_oracle[g.name]))
            oracle_pairs.append((est, gt))
    rows = robot_rows(scenario, session, record, T_oracle)
    result = {
        "note": scenario.note,
        "robots": rows,
        "links": link_rows(scenario, session),
        "ape": fleet_ape(pairs),
        "ape_oracle": fleet_ape(oracle_pairs),
        "latency": summary["latency"],
        "keyframes": summary["keyframes"],
    }
    (out / "score.json").write_text(json.dumps(result, indent=2, default=float) + "\n")
    return result


def robot_rows(
    scenario: Any, session: Any, record: Any, T_oracle: dict[str, np.ndarray]
) -> list[dict]:
    """Per robot: joined vs oracle stamp, delay (fraction of its run), latency, the error of the
    first fleet frame it got at the objects it had then (`join_error`: what the join was decided
    on) and at its final objects (`join_error_final`), and of its final fleet frame at its final
    objects (`end_error`), and that of the frame its links refitted on the true
    correspondences would give (`oracle_end_error`; T_oracle: `oracle_link_frames`)."""
    from sgloc.replay.outputs import latency_stats

    root = session.root
    G_fleet = scenario.T_gt_odom[root]
    oracle = oracle_join_stamps(scenario.logs, scenario.T_gt_odom, root)
    first_T = {}
    for _, robot, T in record.transforms:
        first_T.setdefault(robot, T)
    rows = []
    for g in scenario.logs:
        j = record.joined_ns.get(g.name)
        T_end = session.T_fleet_robot(g.name)
        objs = session.map(g.name).positions
        G = scenario.T_gt_odom[g.name]
        run = float(g.stamps[-1] - g.stamps[0]) or 1.0
        rows.append({
            "robot": g.name,
            "root": g.name == root,
            "keyframes": len(g),
            "run_s": run,
            "oracle_s": oracle[g.name],
            "joined_s": None if j is None else j * 1e-9,
            "delay": None if j is None or not np.isfinite(oracle[g.name])
            else (j * 1e-9 - oracle[g.name]) / run,
            "join_error": None if g.name not in first_T
            else robot_error(first_T[g.name], G_fleet, G, record.join_objects[g.name]),
            "join_error_final": None if g.name not in first_T
            else robot_error(first_T[g.name], G_fleet, G, objs),
            "end_error": None if T_end is None else robot_error(T_end, G_fleet, G, objs),
            "oracle_end_error": None if g.name not in T_oracle
            else robot_error(T_oracle[g.name], G_fleet, G, objs),
            "latency": latency_stats(record.latency_ms[g.name]),
        })
    return rows


def link_rows(scenario: Any, session: Any) -> list[dict]:
    """Every accepted link: active or revoked, its error against the ground truth at robot_b's
    objects, that of the link refitted on the true correspondences (`oracle_error`), the
    error its covariance predicts there (2 sigma, worst direction: `predicted_2sigma`), the
    object pairs it co-locates and `lever_m`, the farthest of robot_b's objects from their
    centroid (metres: how far a rotation error of the link is carried)."""
    from sgloc.evaluation.online_oracle import link_of_odometry_frames, oracle_refit
    from sgloc.geometry import invert
    from sgloc.online.refine import co_located
    from sgloc.online.robots.precision import predicted_error

    cfg, out = session.config, []
    for lk in session.links:
        G_a, G_b = scenario.T_gt_odom[lk.robot_a], scenario.T_gt_odom[lk.robot_b]
        a, b = session.map(lk.robot_a), session.map(lk.robot_b)
        T_ab, cov = link_of_odometry_frames(session, lk)
        dm, dd = robot_error(T_ab, G_a, G_b, b.positions)
        T_or = oracle_refit(b.positions, b.labels, a.positions, a.labels, invert(G_a) @ G_b,
                            cfg.ransac.threshold, cfg.motion)
        i, _ = co_located(b.positions, b.labels, a.positions, a.labels, T_ab,
                          cfg.ransac.threshold)
        lever = (float(np.linalg.norm(b.positions - b.positions[i].mean(axis=0), axis=1).max())
                 if len(i) else None)
        out.append({"a": lk.robot_a, "b": lk.robot_b, "active": bool(lk.active),
                    "stamp": float(lk.stamp), "error_m": dm, "error_deg": dd,
                    "wrong": bool(dm > MAX_M or dd > MAX_DEG),
                    "oracle_error": None if T_or is None
                    else robot_error(T_or, G_a, G_b, b.positions),
                    "predicted_2sigma": predicted_error(cov, b.positions, 2.0),
                    "matches": int(lk.n_matches), "pairs": int(len(i)), "lever_m": lever})
    return out


def is_wrong(err: tuple[float, float] | None) -> bool:
    """True for a placement beyond MAX_M / MAX_DEG."""
    return err is not None and (err[0] > MAX_M or err[1] > MAX_DEG)


