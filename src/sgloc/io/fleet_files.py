"""Files of a fleet result: merged map, fleet.json, poses (TUM, KITTI), links.g2o, settings."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sgloc.io.g2o import write_g2o
from sgloc.io.poses import write_kitti_poses, write_tum_poses

#: Version of fleet.json (docs/fleet_outputs.md lists its keys); a change of meaning of any key
#: gets a new number.
SCHEMA = "sgloc.online.fleet/1"


def write_fleet_poses(result, folder: str | Path) -> list[Path]:
    """Each placed robot's pose T_fleet_robot as TUM and KITTI files (for evo and friends):
    `poses/<robot>.tum` and `poses/<robot>.kitti` (one line each; <robot> = its unique name),
    and `poses.tum` / `poses.kitti` with every placed robot, one line each in robot order. The
    TUM time column is the pose's stamp (`result.stamps`: 0.0 for a whole map, which has no
    time of its own)."""
    d = Path(folder)
    placed = sorted(result.T_fleet_robot)
    T = np.array([result.T_fleet_robot[i] for i in placed]).reshape(-1, 4, 4)
    stamps = np.array([result.stamps.get(i, 0.0) for i in placed], float)
    files = [write_tum_poses(d / "poses.tum", stamps, T), write_kitti_poses(d / "poses.kitti", T)]
    for k, i in enumerate(placed):
        name = result.names[i]
        files.append(write_tum_poses(d / "poses" / f"{name}.tum", stamps[k:k + 1], T[k:k + 1]))
        files.append(write_kitti_poses(d / "poses" / f"{name}.kitti", T[k:k + 1]))
    return files


def write_fleet_g2o(result, path: str | Path) -> Path:
    """`links.g2o`: a VERTEX_SE3:QUAT per placed robot (id = its index in `names`, pose
    T_fleet_robot) and an EDGE_SE3:QUAT per kept link (T_target_query, its information)."""
    idx = result.names.index
    edges = [(idx(lk.target), idx(lk.query), lk.transform, lk.covariance) for lk in result.links
             if lk.used in ("tree", "loop") and lk.covariance is not None]
    return write_g2o(path, result.T_fleet_robot, edges)


def write_fleet_outputs(result, localizer_config, folder: str | Path) -> list[Path]:
    """merged.json, fleet.json (`{"schema": SCHEMA, **result.to_dict()}`), poses.tum/.kitti,
    poses/<robot>.*, links.g2o, config.yaml."""
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    files = []
    if result.merged is not None:
        files.append(result.merged.save(d / "merged.json"))
    doc = {"schema": SCHEMA, **result.to_dict()}
    (d / "fleet.json").write_text(json.dumps(doc, indent=1))
    files.append(d / "fleet.json")
    files += write_fleet_poses(result, d)
    files.append(write_fleet_g2o(result, d / "links.g2o"))
    localizer_config.to_yaml(d / "config.yaml")
    files.append(d / "config.yaml")
    return files
