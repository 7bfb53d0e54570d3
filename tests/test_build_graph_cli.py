"""`sgloc build-graph`: graph files from loaders; user errors exit 2 with one line."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from sgloc import SemanticGraph
from sgloc.cli import main
from sgloc.maps.classes import AIRSIM_COLORS


def test_build_graph_kitti_objects_scan_range_start_frame(kitti_dir, tmp_path, capsys):
    out = tmp_path / "a.json"
    rc = main(
        ["build-graph", "kitti_objects", str(kitti_dir), "--scans", "100-200",
         "--start-frame", "--association-radius", "3", "-o", str(out), "-q"]
    )  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    g = SemanticGraph.load(out)
    assert 10 < len(g) < 400 and set(np.unique(g.labels)) <= {0, 1, 2}
    # robot-local: objects lie around the first scan's LiDAR (within ~150 m over 100 scans)
    assert np.median(np.linalg.norm(g.positions[:, :2], axis=1)) < 150
    assert "vertices per class" in capsys.readouterr().out


def test_build_graph_airsim_robot_folder(tmp_path, capsys):
    robot = tmp_path / "run" / "forwardCar"
    (robot / "depth").mkdir(parents=True)
    (robot / "segmentation").mkdir()
    (robot / "airsim.txt").write_text("2\n0 0 0 1 0 0 0\n1 0 0 1 0 0 0\n")
    (robot / "intrinsics.txt").write_text("32 32 32 18 64 36\n")
    for i in range(2):
        seg = np.zeros((36, 64, 3), np.uint8)
        seg[10:26, 20:44] = AIRSIM_COLORS[5]
        dep = np.full((36, 64), 255, np.uint8)
        dep[10:26, 20:44] = 20  # 7.8 m
        Image.fromarray(seg).save(robot / "segmentation" / f"segmentation_{i}.png")
        Image.fromarray(dep).save(robot / "depth" / f"depth_{i}.png")
    out = tmp_path / "g.npz"
    rc = main(["build-graph", "airsim", str(tmp_path / "run"), "--robot", "forwardCar",
               "--min-pixels", "100", "-o", str(out), "-q"])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    g = SemanticGraph.load(out)
    assert g.labels.tolist() == [5]  # the same block seen twice, 1 m apart: one vertex
    assert abs(g.positions[0, 0] - (20 / 255 * 100 + 0.5)) < 0.5


def test_build_graph_output_is_checked_before_the_extraction(tmp_path, capsys, monkeypatch):
    """An unknown format and an existing file (its own earlier graph too) are refused before
    any frame is read, naming the path given, with a message that is true."""
    import sgloc.extraction.graph_job as graph_job

    monkeypatch.setattr(graph_job.GraphJob, "run", lambda *a, **k: pytest.fail("work started"))
    (tmp_path / "run").mkdir()
    argv = ["build-graph", "airsim", str(tmp_path / "run"), "-q", "-o"]
    assert main([*argv, str(tmp_path / "A.xyz")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {tmp_path / 'A.xyz'}: unknown graph format") and "\n" not in err
    (tmp_path / "A.json").write_text('{"positions": [[0, 0, 0]], "labels": [1]}')
    assert main([*argv, str(tmp_path / "A.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "exists; --out writes a new file only" in err and "not written by sgloc" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["A.json", "run"]


def test_build_graph_user_errors_exit_2(tmp_path, capsys):
    cases = [
        ["build-graph", "kitty", str(tmp_path), "-o", str(tmp_path / "x.json")],
        ["build-graph", "kitti", str(tmp_path), "--robot", "A", "-o", str(tmp_path / "x.json")],
        ["build-graph", "kitti_objects", str(tmp_path / "none"), "-o", str(tmp_path / "x.json")],
        ["build-graph", "airsim", str(tmp_path), "--position", "middle", "-o", "x.json"],
    ]
    messages = []
    for argv in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("error:") and "\n" not in err, err
        messages.append(err)
    assert "unknown dataset" in messages[0]
    assert "no option --robot" in messages[1]
    assert "none" in messages[2]
    assert "position" in messages[3]
