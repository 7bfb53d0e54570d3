"""PLY and CSV/TXT graph readers, the class field choice and colour tables."""

from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from sgloc import SemanticGraph
from sgloc.cli import main
from sgloc.errors import GraphFileError
from sgloc.io.colour_table import read_colour_table
from sgloc.io.inputs import read_graph_with
from sgloc.io.ply import read_ply, write_ply
from sgloc.maps.classes import AIRSIM_COLORS


@pytest.fixture
def objects(rng):
    return rng.uniform(-50, 50, (30, 3)), rng.integers(0, 5, 30)


def _ply(path, fields: dict, text: bool = False):
    dtype = [(k, v.dtype.str) for k, v in fields.items()]
    v = np.empty(len(next(iter(fields.values()))), dtype=dtype)
    for k, a in fields.items():
        v[k] = a
    PlyData([PlyElement.describe(v, "vertex")], text=text).write(str(path))
    return path


def test_ply_round_trip_and_named_field(tmp_path, objects):
    pos, lab = objects
    p = write_ply(tmp_path / "g.ply", pos, lab)
    got_pos, got_lab = read_ply(p)
    np.testing.assert_allclose(got_pos, pos)
    np.testing.assert_array_equal(got_lab, lab)
    q = _ply(tmp_path / "s.ply", {"x": pos[:, 0].astype("f4"), "y": pos[:, 1].astype("f4"),
                                  "z": pos[:, 2].astype("f4"), "sem": lab.astype("u1"),
                                  "intensity": np.ones(30, "f4")}, text=True)
    with pytest.raises(GraphFileError, match="--label-field"):
        read_ply(q)
    np.testing.assert_array_equal(read_graph_with(q, label_field="sem")[1], lab)
    with pytest.raises(GraphFileError, match="no vertex field 'cls'"):
        read_graph_with(q, label_field="cls")


def test_ply_colours_through_a_colour_table(tmp_path, objects):
    pos, lab = objects
    table = np.array([[10, 20, 30], [200, 0, 0], [0, 200, 0], [0, 0, 200], [9, 9, 9]])
    rgb = table[lab].astype("u1")
    q = _ply(tmp_path / "c.ply", {"x": pos[:, 0], "y": pos[:, 1], "z": pos[:, 2],
                                  "red": rgb[:, 0], "green": rgb[:, 1], "blue": rgb[:, 2]})
    with pytest.raises(GraphFileError, match="colour table"):
        read_graph_with(q)  # not the Airsim colours
    (tmp_path / "t.txt").write_text(
        "# class r g b name\n" + "".join(f"{k} {r},{g},{b} c{k}\n" for k, (r, g, b) in
                                         enumerate(table))
    )
    got = read_graph_with(q, colour_table=tmp_path / "t.txt")[1]
    np.testing.assert_array_equal(got, lab)
    colours, names = read_colour_table(tmp_path / "t.txt")
    assert names[3] == "c3" and tuple(colours[1]) == (200, 0, 0)


def test_colour_table_errors(tmp_path):
    (tmp_path / "dup.txt").write_text("0 1 2 3\n1 1 2 3\n")
    with pytest.raises(GraphFileError, match="own colour"):
        read_colour_table(tmp_path / "dup.txt")
    (tmp_path / "bad.txt").write_text("0 1 2\n")
    with pytest.raises(GraphFileError, match="bad.txt:1"):
        read_colour_table(tmp_path / "bad.txt")


def test_csv_with_header_and_positional_txt(tmp_path, objects):
    pos, lab = objects
    rows = "".join(f"{k},{c},{p[0]},{p[1]},{p[2]}\n" for k, (p, c) in enumerate(zip(pos, lab,
                                                                                     strict=True)))
    (tmp_path / "g.csv").write_text("id,class,x,y,z\n" + rows)
    g = SemanticGraph.load(tmp_path / "g.csv")
    np.testing.assert_allclose(g.positions, pos)
    np.testing.assert_array_equal(g.labels, lab)
    (tmp_path / "g.txt").write_text(
        "".join(f"{p[0]} {p[1]} {p[2]} 0.5 {c}\n" for p, c in zip(pos, lab, strict=True))
    )
    with pytest.raises(GraphFileError, match="integer class"):
        read_graph_with(tmp_path / "g.txt")  # column 3 holds 0.5
    np.testing.assert_array_equal(read_graph_with(tmp_path / "g.txt", label_field="4")[1], lab)
    with pytest.raises(GraphFileError, match="column index"):
        read_graph_with(tmp_path / "g.txt", label_field="class")


def test_cli_reads_ply_and_csv_with_label_field(tmp_path, airsim_graphs, capsys):
    c1, c2 = airsim_graphs
    x, y, z = c1.positions.T
    _ply(tmp_path / "a.ply", {"x": x, "y": y, "z": z, "kind": c1.labels.astype("i4")})
    (tmp_path / "b.csv").write_text(
        "x;y;z;kind\n" + "".join(f"{p[0]};{p[1]};{p[2]};{c}\n" for p, c in
                                 zip(c2.positions, c2.labels, strict=True))
    )
    argv = ["localize", str(tmp_path / "a.ply"), str(tmp_path / "b.csv"), "--format", "matrix"]
    assert main(argv) == 2 and "kind" in capsys.readouterr().err  # class column unnamed
    assert main([*argv, "--label-field", "kind"]) == 0
    T = np.loadtxt(capsys.readouterr().out.splitlines())
    assert np.linalg.norm(T[:3, 3]) < 5.0


def test_pcd_with_a_colour_table(tmp_path, airsim_dir):
    table = tmp_path / "airsim.txt"
    table.write_text("".join(f"{k} {r} {g} {b}\n" for k, (r, g, b) in enumerate(AIRSIM_COLORS)))
    ref = SemanticGraph.load(airsim_dir / "cloud1.pcd")
    _, lab = read_graph_with(airsim_dir / "cloud1.pcd", colour_table=table)
    np.testing.assert_array_equal(lab, ref.labels)


def test_build_graph_writes_ply_and_csv(tmp_path, capsys):
    from sgloc.sim import make_synthetic_run

    make_synthetic_run(seed=0, width=96, height=54, length=150, step=5).write(tmp_path / "run")
    graphs = {}
    for suffix in (".npz", ".ply", ".csv", ".txt"):
        out = tmp_path / f"g{suffix}"
        argv = ["build-graph", "airsim", str(tmp_path / "run"), "--robot", "forwardCar",
                "--preset", "paper", "-o", str(out), "-q"]
        assert main(argv) == 0, capsys.readouterr().err
        graphs[suffix] = SemanticGraph.load(out)
    ref = graphs[".npz"]
    assert len(ref) > 5
    for g in graphs.values():
        np.testing.assert_allclose(g.positions, ref.positions, atol=1e-5)
        np.testing.assert_array_equal(g.labels, ref.labels)
    bad = ["build-graph", "airsim", str(tmp_path / "run"), "--robot", "forwardCar",
           "--preset", "nope", "-o", str(tmp_path / "x.json")]
    assert main(bad) == 2 and "preset" in capsys.readouterr().err
