"""SemanticGraph.save writes every format load reads; class names in tables through a class
table; reader options that do not apply to a file are refused, not ignored."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc import SemanticGraph
from sgloc.cli import main
from sgloc.errors import SglocError
from sgloc.io.inputs import read_graph_with


@pytest.mark.parametrize("suffix", [".pcd", ".json", ".npz", ".ply", ".csv", ".txt"])
def test_save_writes_what_load_reads(tmp_path, airsim_graphs, suffix):
    g = airsim_graphs[0]
    back = SemanticGraph.load(g.save(tmp_path / f"g{suffix}"))
    assert np.array_equal(back.labels, g.labels)
    np.testing.assert_allclose(back.positions, g.positions, atol=1e-6)


def test_class_names_through_a_class_table(tmp_path):
    table = tmp_path / "classes.txt"
    table.write_text("# id name\n0 car\n1 pole\n2 trunk\n0 Vehicle\n")
    csv = tmp_path / "g.csv"
    csv.write_text("x,y,z,class\n0,0,0,car\n10,0,0,POLE\n0,10,0,trunk\n5,5,0,vehicle\n")
    pos, lab = read_graph_with(csv, class_table=table)
    assert lab.tolist() == [0, 1, 2, 0] and pos.shape == (4, 3)
    with pytest.raises(SglocError, match="--class-table"):
        read_graph_with(csv)
    table.write_text("0 car\n")
    with pytest.raises(SglocError, match="'POLE' is not in the class table"):
        read_graph_with(csv, class_table=table)


def test_localize_reads_class_names(tmp_path, airsim_graphs, capsys):
    names = [f"c{i}" for i in range(11)]
    (tmp_path / "classes.txt").write_text("".join(f"{i} {n}\n" for i, n in enumerate(names)))
    files = []
    for k, g in enumerate(airsim_graphs):
        rows = "".join(
            f"{x},{y},{z},{names[c]}\n" for (x, y, z), c in zip(g.positions, g.labels, strict=True)
        )
        files.append(tmp_path / f"g{k}.csv")
        files[-1].write_text("x,y,z,label\n" + rows)
    argv = ["localize", *map(str, files), "--class-table", str(tmp_path / "classes.txt")]
    assert main(argv) == 0


@pytest.mark.parametrize("option, value", [("--label-field", "nosuch"), ("--class-table", "t.txt")])
def test_options_that_do_not_apply_are_refused(tmp_path, airsim_dir, capsys, option, value):
    (tmp_path / "t.txt").write_text("0 car\n")
    q = str(airsim_dir / "cloud1.pcd")
    assert (
        main(["localize", q, q, option, str(tmp_path / value) if ".txt" in value else value]) == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and option in err[0] and "applies to" in err[0]
