"""`sgloc fleet` outputs: every placed robot's pose as TUM and KITTI (keyed by unique robot
name), the inter-robot factors as g2o, the settings used; the root can be chosen."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from sgloc.cli import main
from sgloc.evaluation.fleet_scenes import fleet_errors, world_fleet
from sgloc.io.g2o import read_g2o
from sgloc.io.names import robot_names
from sgloc.io.poses import read_kitti_poses, read_tum_poses
from sgloc.online.fleet import localize_fleet


@pytest.fixture(scope="module")
def fleet4(tmp_path_factory):
    out = tmp_path_factory.mktemp("fleet4")
    scene = world_fleet(0)
    return scene, localize_fleet(scene.graphs[:4], workers=0, out=out), out


def test_fleet_writes_tum_and_kitti_poses(fleet4):
    scene, res, out = fleet4
    placed = sorted(res.T_fleet_robot)
    assert len(placed) >= 2
    stamps, T_tum = read_tum_poses(out / "poses.tum")
    T_kitti = read_kitti_poses(out / "poses.kitti")
    assert stamps.tolist() == [0.0] * len(placed)  # whole maps have no time of their own
    for k, i in enumerate(placed):
        np.testing.assert_allclose(T_tum[k], res.T_fleet_robot[i], atol=1e-6)
        np.testing.assert_allclose(T_kitti[k], res.T_fleet_robot[i], atol=1e-6)
        np.testing.assert_allclose(
            read_kitti_poses(out / "poses" / f"{scene.graphs[i].name}.kitti")[0],
            res.T_fleet_robot[i], atol=1e-6,
        )
    assert (out / "config.yaml").is_file()


def test_links_g2o_parses_back(fleet4):
    _, res, out = fleet4
    vertices, edges = read_g2o(out / "links.g2o")
    assert sorted(vertices) == res.placed
    for i, T in vertices.items():
        np.testing.assert_allclose(T, res.T_fleet_robot[i], atol=1e-6)
    kept = [lk for lk in res.links if lk.used in ("tree", "loop")]
    assert len(edges) == len(kept) >= len(res.placed) - 1
    for (a, b, T, cov), lk in zip(edges, kept, strict=True):
        assert (res.names[a], res.names[b]) == (lk.target, lk.query)  # g2o ids: robot indices
        np.testing.assert_allclose(T, lk.transform, atol=1e-6)
        np.testing.assert_allclose(cov, lk.covariance, rtol=1e-5, atol=1e-12)
    import gtsam

    graph, initial = gtsam.readG2o(str(out / "links.g2o"), True)
    assert graph.size() == len(edges) and initial.size() == len(vertices)


def test_same_named_files_do_not_overwrite_each_other(tmp_path):
    graphs = world_fleet(0).graphs[:2]
    paths = []
    for k, g in enumerate(graphs):
        (tmp_path / f"r{k + 1}").mkdir()
        paths.append(str(g.save(tmp_path / f"r{k + 1}" / "map.json")))
    assert robot_names(paths) == ["r1-map", "r2-map"]
    assert robot_names(["a/Map.pcd", "b/map.ply", "c.json"]) == ["a-Map", "b-map", "c"]
    assert robot_names(["x/r 1.pcd", "x/r 1.ply"]) == ["x-r-1", "x-r-1-2"]
    out = tmp_path / "out"
    assert main(["fleet", *paths, "--out", str(out), "--workers", "0"]) == 0
    info = json.loads((out / "fleet.json").read_text())
    assert info["robots"] == ["r1-map", "r2-map"] and len(info["placed"]) == 2
    a = read_kitti_poses(out / "poses" / "r1-map.kitti")[0]
    b = read_kitti_poses(out / "poses" / "r2-map.kitti")[0]
    assert not np.allclose(a, b, atol=1.0)  # two robots, two different poses


def test_root_can_be_chosen(tmp_path):
    scene = world_fleet(0)
    graphs = scene.graphs[:3]
    res = localize_fleet(graphs, workers=0, root="world2")
    assert res.names[res.root] == "world2"
    np.testing.assert_allclose(res.T_fleet_robot[2], np.eye(4), atol=1e-12)
    for dt, dr in fleet_errors(res.T_fleet_robot, scene.T_gt_robot, 2, graphs).values():
        assert dt < 3.0 and dr < 3.0
    paths = [str(g.save(tmp_path / f"{g.name}.json")) for g in graphs]
    out = tmp_path / "out"
    assert main(["fleet", *paths, "--out", str(out), "--workers", "0", "--root", "world1"]) == 0
    assert json.loads((out / "fleet.json").read_text())["root_name"] == "world1"
    np.testing.assert_allclose(read_kitti_poses(out / "poses" / "world1.kitti")[0], np.eye(4),
                               atol=1e-9)
    assert main(["fleet", *paths, "--workers", "0", "--root", "nobody"]) == 2


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


def test_a_failed_write_leaves_no_half_written_fleet_folder(tmp_path, monkeypatch):
    """The outputs are written into a sibling folder renamed into place at the end: a write
    that fails half-way leaves no results folder, and the error names the file."""
    import sgloc.io.fleet_files as fleet_files
    from sgloc.errors import SglocError

    def full_disk(result, folder):
        raise OSError(28, "No space left on device", str(folder / "links.g2o"))

    monkeypatch.setattr(fleet_files, "write_fleet_g2o", lambda result, path: full_disk(
        result, path.parent))
    out = tmp_path / "out"
    with pytest.raises(SglocError, match="links.g2o"):
        localize_fleet(world_fleet(0).graphs[:2], workers=0, out=out)
    assert not out.exists() and not list(tmp_path.iterdir())


def test_negative_workers_are_refused(tmp_path, capsys):
    paths = [str(g.save(tmp_path / f"robot{i}.json"))
             for i, g in enumerate(world_fleet(0).graphs[:2])]
    assert main(["fleet", *paths, "--workers", "-1"]) == 2
    assert "--workers" in capsys.readouterr().err


def _documented_keys() -> set[str]:
    """The keys the tables of docs/fleet_outputs.md name (first column, in backticks)."""
    import re
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "fleet_outputs.md").read_text()
    cells = re.findall(r"^\| ([^|]+) \|", doc, flags=re.M)
    return {k for c in cells for k in re.findall(r"`([a-z_]+)`", c)}


def test_fleet_json_is_versioned_and_every_key_documented(fleet4):
    _, _, out = fleet4
    info = json.loads((out / "fleet.json").read_text())
    assert info["schema"] == "sgloc.online.fleet/1"
    keys = set(info) | {k for lk in info["links"] for k in lk}
    assert keys <= _documented_keys(), keys - _documented_keys()
