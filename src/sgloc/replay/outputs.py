"""The replay output folder, written atomically (`sgloc.io.files.staged_folder`).

    fleet/<robot>.tum   each PLACED robot's keyframe poses in the fleet frame (real stamps)
    maps/<robot>.json   each PLACED robot's corrected map: its objects in the fleet frame
    merged.json         the placed robots' maps fused into one graph, fleet frame
    events.csv          stamp,kind,robots,detail (robots joined by `;`; exact input stamps)
    links.g2o           the session's inter-robot factors and fleet poses (vertex id = the
                        robot's place in summary.json's `robots`, also its `g2o_vertex`)
    g2o_keyframes.csv   vertex,robot,keyframe,stamp of every keyframe vertex of links.g2o
                        (backend "keyframes" only)
    summary.json        per robot: its files, keyframes, stamp joined, why not placed, latency
    timeline.png        events over stamps, one row per robot
    fleet.png           the placed robots' paths and objects, top-down, fleet frame
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.geometry import apply
from sgloc.io.files import staged_folder
from sgloc.io.keyframes import RobotLog, format_stamp
from sgloc.io.names import robot_file_stems
from sgloc.io.poses import write_tum
from sgloc.maps.graph import SemanticGraph
from sgloc.online.merge import merge_graphs
from sgloc.replay.stream import ReplayRecord

SUMMARY, EVENTS, LINKS, FLEET_DIR = "summary.json", "events.csv", "links.g2o", "fleet"
MAPS_DIR, MERGED, KEYFRAMES = "maps", "merged.json", "g2o_keyframes.csv"
#: Version of summary.json (docs/fleet_outputs.md lists its keys).
SCHEMA = "sgloc.replay/2"
#: The events.csv row kind of a robot that was never placed (after the session's events).
NOT_PLACED = "robot_not_placed"


def latency_stats(ms: np.ndarray) -> dict[str, float | None]:
    """Median, 99th percentile and maximum of per-update latencies (milliseconds)."""
    if len(ms) == 0:
        return {"median_ms": None, "p99_ms": None, "max_ms": None}
    return {
        "median_ms": round(float(np.median(ms)), 4),
        "p99_ms": round(float(np.percentile(ms, 99)), 4),
        "max_ms": round(float(np.max(ms)), 4),
    }


def fleet_poses(
    log: RobotLog, T_fleet_odom: np.ndarray, corrected: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(xyz (N,3), quat (N,4) x y z w) of the robot's keyframes in the fleet frame: the
    `corrected` keyframe poses T_fleet_sensor (N,4,4) when given (the keyframe back-end),
    else its odometry moved by the one frame T_fleet_odom."""
    from scipy.spatial.transform import Rotation

    T = T_fleet_odom @ log.poses if corrected is None else corrected
    return T[:, :3, 3], Rotation.from_matrix(T[:, :3, :3]).as_quat()


def corrected_keyframes(session: Any, log: RobotLog) -> np.ndarray | None:
    """T_fleet_sensor (N,4,4) of every keyframe of `log` as the session places them
    (`OnlineSession.trajectory`: the keyframe pose graph's corrected poses, or the robot's one
    fleet frame applied to its odometry); None when the session does not hold them all."""
    traj = session.trajectory(log.name)
    if traj is None or len(traj[1]) != len(log.poses):
        return None
    return traj[1]


def unplaced_reason(session: Any, robot: str) -> str:
    """Why `robot` has no fleet frame, from the session's attempts and links ("" if placed)."""
    if robot not in session.robots:
        return "it sent no keyframe"
    if session.T_fleet_robot(robot) is not None:
        return ""
    need, have = session.online.min_objects, len(session.map(robot))
    mine = [a for a in session.attempts if robot in (a.query, a.target)]
    links = [lk for lk in session.links if robot in (lk.robot_a, lk.robot_b)]
    if not mine and have < need:
        return (f"its map never reached the {need} confirmed objects an attempt needs (it has "
                f"{have}; OnlineConfig.min_objects)")
    if not mine:
        return f"no other robot's map reached the {need} confirmed objects an attempt needs"
    if not links:
        return (f"none of its {len(mine)} localization attempts passed the acceptance test "
                f"(the last: {mine[-1].reason})")
    if not any(lk.active for lk in links):
        return f"its links are not in the consistent set ({links[-1].reason})"
    if session.root not in session.robots or session.T_fleet_robot(session.root) is None:
        return "the root robot has no fleet frame"
    if session.online.join_sigmas is not None:
        return ("its links join it to the placed robots, but its predicted error is beyond the "
                "join limits (OnlineConfig.join_sigmas)")
    return "its links join it only to robots outside the root's group"


def replay_summary(
    logs: Sequence[RobotLog], session: Any, record: ReplayRecord, stems: dict[str, str],
    merged_objects: int = 0,
) -> dict[str, Any]:
    """The summary.json content (robots in the order of `logs`, which is also their vertex
    ids in links.g2o with backend "robots"); `merged_objects`: the objects of merged.json."""
    robots = {}
    keyframes = session.keyframe_vertices  # then a g2o vertex per keyframe
    for k, g in enumerate(logs):
        j = record.joined_ns.get(g.name)
        T = session.T_fleet_robot(g.name) if g.name in session.robots else None
        robots[g.name] = {
            "file": f"{FLEET_DIR}/{stems[g.name]}.tum" if T is not None else None,
            "map": f"{MAPS_DIR}/{stems[g.name]}.json" if T is not None else None,
            "g2o_vertex": None if keyframes else k,
            "keyframes": len(g),
            "first_stamp": format_stamp(g.stamps_ns[0]),
            "last_stamp": format_stamp(g.stamps_ns[-1]),
            "joined_stamp": None if j is None else format_stamp(j),
            "placed": T is not None,
            "unplaced_reason": None if T is not None else unplaced_reason(session, g.name),
            "latency": latency_stats(record.latency_ms[g.name]),
        }
    links = session.links
    events = {k: int(sum(e.kind == k for e in session.events))
              for k in ("robot_joined", "link_accepted", "link_revoked")}
    return {
        "schema": SCHEMA,
        "robots": robots,
        "root": getattr(session, "root", None),
        "keyframes": int(sum(len(g) for g in logs)),
        "placed": int(sum(r["placed"] for r in robots.values())),
        "links_active": int(sum(lk.active for lk in links)),
        "links_inactive": int(sum(not lk.active for lk in links)),
        "links_revoked": events["link_revoked"],
        "events": events,
        "latency": latency_stats(np.concatenate([record.latency_ms[g.name] for g in logs])),
        "backend": session.online.backend,
        "g2o_keyframes": KEYFRAMES if keyframes else None,
        "merged": MERGED,
        "merged_objects": merged_objects,
    }


def write_events(
    path: Path,
    events: Sequence[Any],
    stamps_ns: Sequence[int | None] | None = None,
    unplaced: Sequence[tuple[int, str, str]] = (),
) -> Path:
    """events.csv: one row per event, in the order the session emitted them, stamped with
    `stamps_ns` (the exact input stamps, one per event; else the event's float seconds
    rounded to ns), then a `robot_not_placed` row per (stamp ns, robot, reason) of `unplaced`."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["stamp", "kind", "robots", "detail"])
        for k, e in enumerate(events):
            ns = stamps_ns[k] if stamps_ns is not None and k < len(stamps_ns) else None
            ns = round(float(e.stamp) * 1e9) if ns is None else ns
            w.writerow([format_stamp(ns), e.kind, ";".join(e.robots), e.detail])
        for ns, robot, reason in unplaced:
            w.writerow([format_stamp(ns), NOT_PLACED, robot, reason])
    return path


def write_links_g2o(path: Path, session: Any, names: Sequence[str]) -> Path:
    """links.g2o with vertex id = the robot's index in `names` (summary.json's order): a
    VERTEX_SE3:QUAT per placed robot (T_fleet_robot), an EDGE_SE3:QUAT per active link."""
    from sgloc.io.g2o import write_g2o

    ids = {r: k for k, r in enumerate(names)}
    vertices = {ids[r]: T for r in names if r in session.robots
                and (T := session.T_fleet_robot(r)) is not None}
    edges = [(ids[lk.robot_a], ids[lk.robot_b], lk.T_a_b, lk.covariance)
             for lk in session.links if lk.active]
    return write_g2o(path, vertices, edges)


def fleet_maps(session: Any, names: Sequence[str]) -> dict[str, SemanticGraph]:
    """{robot: its corrected map}, each PLACED robot of `names` with its confirmed objects
    moved into the fleet frame (metres; with backend "keyframes" the objects rest on the
    corrected keyframes, `RobotMap.reanchor`)."""
    maps = {}
    for r in names:
        T = session.T_fleet_robot(r) if r in session.robots else None
        if T is not None:
            g = session.map(r)
            maps[r] = SemanticGraph(apply(T, g.positions), g.labels, g.edge_radius, name=r)
    return maps


def merged_map(maps: dict[str, SemanticGraph], fuse_radius: float) -> SemanticGraph:
    """The corrected maps (fleet frame) fused into one graph: same-class objects of different
    robots closer than `fuse_radius` metres merged (`sgloc.online.merge.merge_graphs`)."""
    graphs = list(maps.values())
    return merge_graphs(graphs, {k: np.eye(4) for k in range(len(graphs))}, fuse_radius)[0]


def write_keyframe_table(path: Path, session: Any, logs: Sequence[RobotLog]) -> Path:
    """g2o_keyframes.csv: `vertex,robot,keyframe,stamp` of every keyframe vertex of links.g2o
    (backend "keyframes"; keyframe = its index in the robot's log, stamp exact seconds)."""
    stamps = {g.name: g.stamps_ns for g in logs}
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["vertex", "robot", "keyframe", "stamp"])
        for v, r, k in session.keyframe_ids():
            w.writerow([int(v), r, int(k), format_stamp(stamps[r][k])])
    return path


def write_maps(folder: Path, session: Any, stems: dict[str, str]) -> SemanticGraph:
    """maps/<stem>.json (each placed robot's corrected map) and merged.json (the fleet map)
    into `folder`, in the graph JSON format `sgloc fleet` writes; returns the merged map."""
    corrected = fleet_maps(session, list(stems))
    (folder / MAPS_DIR).mkdir()
    for r, g in corrected.items():
        g.save(folder / MAPS_DIR / f"{stems[r]}.json")
    merged = merged_map(corrected, session.online.fuse_radius)
    merged.save(folder / MERGED)
    return merged


def write_replay(out: str | Path, logs: Sequence[RobotLog], session: Any,
                 record: ReplayRecord, inputs: Sequence[str | Path | None] = ()) -> dict[str, Any]:
    """Write the output folder `out` atomically (`sgloc.io.files.staged_folder`: new, empty or
    an earlier results folder of sgloc, never one holding `inputs` or other files); returns
    the summary."""
    with staged_folder(out, inputs) as stage:
        summary = write_replay_into(stage, logs, session, record)
    return summary


def write_replay_into(folder: Path, logs: Sequence[RobotLog], session: Any,
                      record: ReplayRecord) -> dict[str, Any]:
    """write_replay's files, written into the existing folder `folder`; returns the summary."""
    _write_all(folder, logs, session, record)
    return json.loads((folder / SUMMARY).read_text())


def _write_all(tmp: Path, logs: Sequence[RobotLog], session: Any, record: ReplayRecord) -> None:
    from sgloc.replay.plots import plot_replay_fleet, plot_timeline

    (tmp / FLEET_DIR).mkdir(parents=True)
    stems = robot_file_stems([g.name for g in logs])
    frames, maps = {}, {}
    for g in logs:
        T = session.T_fleet_robot(g.name) if g.name in session.robots else None
        if T is None:
            continue
        frames[g.name] = T
        maps[g.name] = session.map(g.name).positions
        write_tum(tmp / FLEET_DIR / f"{stems[g.name]}.tum", g.stamps_ns,
                        *fleet_poses(g, T, corrected_keyframes(session, g)))
    merged = write_maps(tmp, session, stems)
    summary = replay_summary(logs, session, record, stems, len(merged))
    end = max(int(g.stamps_ns[-1]) for g in logs)
    unplaced = [(end, name, r["unplaced_reason"]) for name, r in summary["robots"].items()
                if not r["placed"]]
    write_events(tmp / EVENTS, session.events, record.event_ns, unplaced)
    if session.keyframe_ids():  # the keyframe pose graph: odometry and link edges
        session.write_g2o(tmp / LINKS)
    else:
        write_links_g2o(tmp / LINKS, session, [g.name for g in logs])
    if session.keyframe_vertices:
        write_keyframe_table(tmp / KEYFRAMES, session, logs)
    (tmp / SUMMARY).write_text(json.dumps(summary, indent=2) + "\n")
    plot_timeline(logs, session.events, tmp / "timeline.png")
    plot_replay_fleet(logs, frames, maps, tmp / "fleet.png")
