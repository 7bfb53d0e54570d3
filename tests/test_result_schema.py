"""One versioned result document for `--json FILE`, result.json and `--format json`; results
folders and files written atomically, errors naming the file."""

from __future__ import annotations

import errno
import json
import os

import numpy as np
import pytest

from sgloc.cli import main
from sgloc.errors import OutputPathError, SglocError
from sgloc.io.files import MANIFEST, staged_folder, write_text_atomic
from sgloc.io.results import SCHEMA, is_result_document, summary

COMMON = ["schema", "accepted", "reason", "confidence", "T_target_query", "covariance",
          "n_candidates", "n_survivors", "n_matches", "timings_ms", "scale", "query",
          "target", "seed"]  # fmt: skip


def test_three_outputs_share_one_schema(tmp_path, capsys):
    assert main(["localize", "--example", "--out", str(tmp_path / "r"),
                 "--json", str(tmp_path / "full.json")]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["localize", "--example", "--format", "json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    folder = json.loads((tmp_path / "r" / "result.json").read_text())
    full = json.loads((tmp_path / "full.json").read_text())
    assert SCHEMA == "sgloc.result/2"
    for d in (printed, folder, full):
        assert list(d)[: len(COMMON)] == COMMON and d["schema"] == SCHEMA
    assert printed == folder | {"timings_ms": printed["timings_ms"]}  # timings vary
    assert printed["scale"] == {"unit_m": 5.0, "estimated": False}  # the street's, given
    assert {k: v for k, v in full.items() if k in COMMON and k != "timings_ms"} == {
        k: v for k, v in folder.items() if k != "timings_ms"
    }
    assert set(full) - set(COMMON) == {"matches", "survivors", "candidates", "scores", "config"}
    assert len(full["matches"]) == full["n_matches"] and len(full["matches"][0]) == 2
    assert np.array(full["T_target_query"]).shape == (4, 4)
    assert len(json.dumps(full, indent=2).splitlines()) > 3 * len(full["matches"])
    assert len((tmp_path / "full.json").read_text().splitlines()) < 2 * len(full["candidates"])


def test_python_to_dict_is_the_full_document(airsim_graphs):
    from sgloc import localize

    res = localize(*airsim_graphs, seed=0)
    d = res.to_dict()
    assert d["schema"] == SCHEMA and d["T_target_query"] == summary(res)["T_target_query"]
    json.dumps(d)  # JSON-ready


def test_a_failed_folder_write_leaves_nothing_and_names_the_file(tmp_path, monkeypatch, capsys):
    from pathlib import Path

    real = Path.write_text

    def full_disk(self, data, *a, **k):
        if self.name == "config.yaml":  # opened (a 0-byte file), then the disk is full
            real(self, "")
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, data, *a, **k)

    monkeypatch.setattr(Path, "write_text", full_disk)
    out = tmp_path / "res"
    assert main(["localize", "--example", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(out / "config.yaml") in err[0] and "No space" in err[0]
    assert not out.exists() and os.listdir(tmp_path) == []


def test_too_long_path_is_named(tmp_path, capsys):
    out = tmp_path / ("x" * 300) / "res"
    assert main(["localize", "--example", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "xxxx" in err[0] and "shorter" in err[0]


def test_an_earlier_results_folder_is_replaced_whole_or_kept(tmp_path):
    out = tmp_path / "res"
    with staged_folder(out) as stage:
        (stage / "old.txt").write_text("kept")
    with pytest.raises(SglocError, match="new.txt"):
        with staged_folder(out) as stage:
            (stage / "new.txt").write_text("half")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert sorted(os.listdir(out)) == [MANIFEST, "old.txt"] and len(os.listdir(tmp_path)) == 1
    with staged_folder(out) as stage:
        (stage / "new.txt").write_text("whole")
    assert sorted(os.listdir(out)) == [MANIFEST, "new.txt"] and len(os.listdir(tmp_path)) == 1


def test_a_folder_of_files_sgloc_did_not_write_is_never_replaced(tmp_path):
    out = tmp_path / "res"
    out.mkdir()
    (out / "old.txt").write_text("mine")
    with pytest.raises(OutputPathError, match="did not write"):
        with staged_folder(out) as stage:
            (stage / "new.txt").write_text("whole")
    assert os.listdir(out) == ["old.txt"] and os.listdir(tmp_path) == ["res"]


def test_out_naming_a_file_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "result.json").write_text("{}")
    assert main(["localize", "--example", "--out", str(tmp_path / "result.json")]) == 2
    err = capsys.readouterr().err
    assert "File exists" not in err and "not a folder" in err


def test_json_file_written_atomically(tmp_path, monkeypatch):
    p = tmp_path / "a.json"
    p.write_text('{"schema": "sgloc.result/1"}')  # an earlier result: sgloc may replace it
    monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(OSError(errno.EIO, "I/O")))
    with pytest.raises(SglocError, match="a.json: cannot write"):
        write_text_atomic(p, "after", ours=is_result_document)
    assert p.read_text() == '{"schema": "sgloc.result/1"}' and os.listdir(tmp_path) == ["a.json"]
    monkeypatch.undo()
    write_text_atomic(p, "after", ours=is_result_document)
    assert p.read_text() == "after"
    with pytest.raises(OutputPathError, match="not written by sgloc"):
        write_text_atomic(p, "again", ours=is_result_document)  # "after" is no result document


def test_experiment_folder_appears_complete_or_not_at_all(tmp_path, monkeypatch, capsys):
    from pathlib import Path

    real = Path.write_text

    def full_disk(self, data, *a, **k):
        if self.name == "table.md":
            real(self, "")
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, data, *a, **k)

    out = tmp_path / "exp"
    argv = ["experiment", "table", "--trials", "1", "--workers", "1", "--descriptors",
            "histogram", "--rejections", "none", "--out", str(out)]  # fmt: skip
    monkeypatch.setattr(Path, "write_text", full_disk)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert str(out / "table.md") in err[-1] and "No space" in err[-1]
    assert os.listdir(tmp_path) == []  # no trials.csv beside a 0-byte table.md
    monkeypatch.setattr(Path, "write_text", real)
    assert main(argv) == 0
    assert {"trials.csv", "table.md", "config.yaml"} <= set(os.listdir(out))
    assert os.listdir(tmp_path) == ["exp"]


def test_success_is_a_read_only_alias_of_accepted(tmp_path):
    from sgloc import localize
    from sgloc.datasets.downloads import airsim_guo

    res = localize(*airsim_guo(), seed=0)
    assert res.accepted is True and res.success is res.accepted
    with pytest.raises(AttributeError):
        res.success = False  # one flag: the alias cannot drift from `accepted`
    assert res.to_dict()["accepted"] is True and "success" not in res.to_dict()
    for version in ("1", "2"):  # a document of either version is one sgloc may replace
        p = tmp_path / f"v{version}.json"
        p.write_text(f'{{"schema": "sgloc.result/{version}", "accepted": true}}')
        assert is_result_document(p)
