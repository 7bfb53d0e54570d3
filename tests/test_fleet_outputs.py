"""`sgloc fleet` outputs: every placed robot's pose as TUM and KITTI, the settings used."""

from __future__ import annotations

import numpy as np
import yaml

from sgloc.cli import main
from sgloc.evaluation.fleet_scenes import world_fleet
from sgloc.fleet import localize_fleet
from sgloc.io.poses import read_kitti_poses, read_tum_poses


def test_fleet_writes_tum_and_kitti_poses(tmp_path):
    scene = world_fleet(0)
    res = localize_fleet(scene.graphs[:4], workers=0, out=tmp_path)
    placed = sorted(res.T_world_robot)
    assert len(placed) >= 2
    stamps, T_tum = read_tum_poses(tmp_path / "poses.tum")
    T_kitti = read_kitti_poses(tmp_path / "poses.kitti")
    assert stamps.astype(int).tolist() == placed
    for k, i in enumerate(placed):
        np.testing.assert_allclose(T_tum[k], res.T_world_robot[i], atol=1e-6)
        np.testing.assert_allclose(T_kitti[k], res.T_world_robot[i], atol=1e-6)
        stem = scene.graphs[i].name.rsplit(".", 1)[0]
        np.testing.assert_allclose(
            read_kitti_poses(tmp_path / "poses" / f"{stem}.kitti")[0], res.T_world_robot[i],
            atol=1e-6,
        )
    assert (tmp_path / "config.yaml").is_file()


def test_cli_fleet_preset_and_set(tmp_path, capsys):
    paths = [str(g.save(tmp_path / f"robot{i}.json"))
             for i, g in enumerate(world_fleet(0).graphs[:2])]
    out = tmp_path / "out"
    argv = ["fleet", *paths, "--out", str(out), "--workers", "0", "--preset", "city",
            "--set", "top_k=2"]
    assert main(argv) == 0
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    assert cfg["class_weights"] == {0: 0.1} and cfg["matching"]["top_k"] == 2
    assert (out / "poses.tum").is_file() and (out / "poses.kitti").is_file()
