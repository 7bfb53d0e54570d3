"""Values that used to escape as raw exceptions or be read as data: each is now an SglocError
naming the input (the command line prints one line and exits 2)."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc import localize, register
from sgloc.cli.app import main
from sgloc.errors import SglocError
from sgloc.io.graph_files import read_graph
from sgloc.io.poses import write_kitti_poses

HEADER = "VERSION 0.7\nFIELDS x y z label\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\n"


@pytest.mark.parametrize("seed", [-1, 1.5, True, "3", 2**70 * -1])
def test_bad_seeds_are_refused(airsim_graphs, seed):
    q, t = airsim_graphs
    with pytest.raises(SglocError, match="seed="):
        localize(q, t, seed=seed)
    pts = np.random.default_rng(0).uniform(0, 50, (10, 3))
    with pytest.raises(SglocError, match="seed="):
        register(pts, pts, seed=seed)


def test_good_seeds_are_taken(airsim_graphs):
    q, t = airsim_graphs
    a = localize(q, t, seed=np.int64(5))
    b = localize(q, t, seed=5)
    assert np.array_equal(a.transform, b.transform)


def _pcd(tmp_path, rows: bytes):
    p = tmp_path / "g.pcd"
    p.write_bytes(HEADER.encode() + b"WIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n" + rows)
    return p


@pytest.mark.parametrize(
    "rows, message",
    [
        (b"0 0 0 1\n1_0 0 0 2\n0 10 0 3\n", "non-numeric character '_'"),
        (b"0 0 0 1\n1\x1c0 0 0 2\n0 10 0 3\n", "non-numeric character"),
        (b"0 0 0 1\n10 0\x0b5 0 2\n0 10 0 3\n", "non-numeric character"),
        (b"0 0 0 1\n10 0 0 1e-400\n0 10 0 3\n", "'1e-400'"),
        (b"0 0 0 1\n10 0 0 5.\n0 10 0 3\n", "'5.'"),
        (b"0 0 0 1\n10 0 0 1_0\n0 10 0 3\n", "non-numeric character '_'"),
        (b"0 0 0 1\n10 0 0 2e0\n0 10 0 3\n", "'2e0'"),
    ],
)
def test_ascii_pcd_values_must_be_plain_numbers(tmp_path, rows, message):
    with pytest.raises(SglocError, match=message) as err:
        read_graph(_pcd(tmp_path, rows))
    assert "g.pcd" in str(err.value)


def test_ascii_pcd_plain_numbers_still_read(tmp_path):
    pos, lab = read_graph(_pcd(tmp_path, b"0 0 0 1\r\n1.5e1 -2. +.5 2\r\n0 10 0 +3\r\n"))
    assert lab.tolist() == [1, 2, 3] and pos[1].tolist() == [15.0, -2.0, 0.5]


@pytest.mark.parametrize("count", ["99999999999999999999999", "9223372036854775807", "1_0"])
def test_huge_kitti_object_count_is_a_clean_error(tmp_path, capsys, count):
    seq = tmp_path / "objects"
    (seq / "00" / "centroids").mkdir(parents=True)
    (seq / "00" / "bow.txt").write_text(f"{count},0,0\n")
    (seq / "00" / "centroids" / "000000.txt").write_text("1 2 3\n")
    write_kitti_poses(seq / "poses_00.txt", np.eye(4)[None])
    rc = main(["build-graph", "kitti_objects", str(seq), "-o", str(tmp_path / "g.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "bow.txt" in err
