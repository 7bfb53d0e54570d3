"""Fleet trajectory error with evo: every placed robot's written fleet-frame trajectory against
its ground truth, after ONE rigid alignment of the whole fleet (Umeyama, no scale).

Needs evo (`pip install 'sgloc[dev]'`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.optional import require


def fleet_ape(pairs: Sequence[tuple[str | Path, str | Path]]) -> dict[str, Any]:
    """APE (translation, metres) of (estimate TUM file, ground-truth TUM file) pairs, one pair
    per robot: poses matched by stamp within each pair, all robots stacked, aligned once.
    Returns rmse, mean, max and the number of poses; rmse None without pairs or when every
    position lies on one line (no unique alignment)."""
    require("evo", "dev", "the fleet trajectory error")
    from evo.core import metrics, sync
    from evo.core.geometry import GeometryException
    from evo.core.trajectory import PoseTrajectory3D
    from evo.tools import file_interface

    est, ref = [], []
    for e_path, g_path in pairs:
        e = file_interface.read_tum_trajectory_file(str(e_path))
        g = file_interface.read_tum_trajectory_file(str(g_path))
        g, e = sync.associate_trajectories(g, e, max_diff=1e-6)
        est.append(e.poses_se3)
        ref.append(g.poses_se3)
    if not est:
        return {"rmse": None, "mean": None, "max": None, "n_poses": 0}
    E = [p for block in est for p in block]
    G = [p for block in ref for p in block]
    stamps = np.arange(len(E), dtype=np.float64)  # robots share stamps: index the stack instead
    traj_e = PoseTrajectory3D(poses_se3=E, timestamps=stamps)
    traj_g = PoseTrajectory3D(poses_se3=G, timestamps=stamps)
    try:
        traj_e.align(traj_g, correct_scale=False)
    except GeometryException:  # all positions on one line: the alignment is not unique
        return {"rmse": None, "mean": None, "max": None, "n_poses": len(E)}
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((traj_g, traj_e))
    st = ape.get_all_statistics()
    return {"rmse": float(st["rmse"]), "mean": float(st["mean"]), "max": float(st["max"]),
            "n_poses": len(E)}
