"""The replay output folder, written atomically (`sgloc.io.files.staged_folder`).

    fleet/<robot>.tum   each PLACED robot's keyframe poses in the fleet frame (real stamps)
    events.csv          stamp,kind,robots,detail (robots joined by `;`)
    links.g2o           the session's inter-robot factors and fleet poses (session.write_g2o)
    summary.json        per robot: file stem, keyframes, stamp joined, latency median/p99/max
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

from sgloc.io.files import staged_folder
from sgloc.io.keyframes import RobotLog, format_stamp
from sgloc.io.plain_layout import write_tum_exact
from sgloc.replay.names import robot_file_stems
from sgloc.replay.stream import ReplayRecord

SUMMARY, EVENTS, LINKS, FLEET_DIR = "summary.json", "events.csv", "links.g2o", "fleet"


def latency_stats(ms: np.ndarray) -> dict[str, float | None]:
    """Median, 99th percentile and maximum of per-update latencies (milliseconds)."""
    if len(ms) == 0:
        return {"median_ms": None, "p99_ms": None, "max_ms": None}
    return {
        "median_ms": round(float(np.median(ms)), 4),
        "p99_ms": round(float(np.percentile(ms, 99)), 4),
        "max_ms": round(float(np.max(ms)), 4),
    }


def fleet_poses(log: RobotLog, T_fleet_odom: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(xyz (N,3), quat (N,4) x y z w) of the robot's keyframes in the fleet frame."""
    from scipy.spatial.transform import Rotation

    T = T_fleet_odom @ log.poses
    return T[:, :3, 3], Rotation.from_matrix(T[:, :3, :3]).as_quat()


def summarize(
    logs: Sequence[RobotLog], session: Any, record: ReplayRecord, stems: dict[str, str]
) -> dict[str, Any]:
    """The summary.json content."""
    robots = {}
    for g in logs:
        j = record.joined_ns.get(g.name)
        T = session.T_fleet_robot(g.name) if g.name in session.robots else None
        robots[g.name] = {
            "file": f"{FLEET_DIR}/{stems[g.name]}.tum" if T is not None else None,
            "keyframes": len(g),
            "first_stamp": format_stamp(g.stamps_ns[0]),
            "last_stamp": format_stamp(g.stamps_ns[-1]),
            "joined_stamp": None if j is None else format_stamp(j),
            "placed": T is not None,
            "latency": latency_stats(record.latency_ms[g.name]),
        }
    links = session.links
    return {
        "robots": robots,
        "root": getattr(session, "root", None),
        "keyframes": int(sum(len(g) for g in logs)),
        "placed": int(sum(r["placed"] for r in robots.values())),
        "links_active": int(sum(lk.active for lk in links)),
        "links_revoked": int(sum(not lk.active for lk in links)),
        "events": {k: int(sum(e.kind == k for e in session.events))
                   for k in ("robot_joined", "link_accepted", "link_revoked")},
        "latency": latency_stats(np.concatenate([record.latency_ms[g.name] for g in logs])),
    }


def write_events(path: Path, events: Sequence[Any]) -> Path:
    """events.csv: one row per event, in the order the session emitted them."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["stamp", "kind", "robots", "detail"])
        for e in events:
            stamp = format_stamp(round(float(e.stamp) * 1e9))  # the keyframe's stamp as written
            w.writerow([stamp, e.kind, ";".join(e.robots), e.detail])
    return path


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
    from sgloc.replay.plots import plot_fleet, plot_timeline

    (tmp / FLEET_DIR).mkdir(parents=True)
    stems = robot_file_stems([g.name for g in logs])
    frames, maps = {}, {}
    for g in logs:
        T = session.T_fleet_robot(g.name) if g.name in session.robots else None
        if T is None:
            continue
        frames[g.name] = T
        maps[g.name] = session.map(g.name).positions
        write_tum_exact(tmp / FLEET_DIR / f"{stems[g.name]}.tum", g.stamps_ns, *fleet_poses(g, T))
    write_events(tmp / EVENTS, session.events)
    session.write_g2o(tmp / LINKS)
    summary = summarize(logs, session, record, stems)
    (tmp / SUMMARY).write_text(json.dumps(summary, indent=2) + "\n")
    plot_timeline(logs, session.events, tmp / "timeline.png")
    plot_fleet(logs, frames, maps, tmp / "fleet.png")
