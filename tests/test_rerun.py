"""`sgloc localize --rerun FILE.rrd`: the recording read back (needs sgloc[rerun])."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from sgloc.cli import main


def test_missing_rerun_is_a_one_line_hint(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "rerun", None)
    assert main(["localize", "--example", "--rerun", str(tmp_path / "a.rrd")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sgloc[rerun]" in err[0]
    assert not (tmp_path / "a.rrd").exists()


def test_recording_holds_both_maps_the_transform_and_the_matches(tmp_path, capsys):
    pytest.importorskip("rerun", reason="optional: pip install 'sgloc[rerun]'")
    from rerun.chunk import RrdReader

    from sgloc.datasets.downloads import airsim_guo

    out = tmp_path / "res"
    path = tmp_path / "loc.rrd"
    assert main(["localize", "--example", "--rerun", str(path), "--out", str(out)]) == 0
    T = np.loadtxt(out / "T_target_query.txt")
    cloud1, cloud2 = airsim_guo()
    got = {}
    for chunk in RrdReader(path).stream():
        got[str(chunk.entity_path)] = chunk.to_record_batch().to_pydict()
    target = np.array(got["/world/target"]["Points3D:positions"][0])
    query = np.array(got["/world/query/objects"]["Points3D:positions"][0])
    np.testing.assert_allclose(target, cloud2.positions, atol=1e-3)  # float32 in the file
    np.testing.assert_allclose(query, cloud1.positions, atol=1e-3)
    assert got["/world/target"]["Points3D:class_ids"][0] == cloud2.labels.tolist()
    tr = got["/world/query"]
    np.testing.assert_allclose(tr["Transform3D:translation"][0][0], T[:3, 3], atol=1e-5)
    R = np.array(tr["Transform3D:mat3x3"][0][0]).reshape(3, 3).T  # column-major
    np.testing.assert_allclose(R, T[:3, :3], atol=1e-5)
    import json

    n_matches = json.loads((out / "result.json").read_text())["n_matches"]
    assert len(got["/world/matches"]["LineStrips3D:strips"][0]) == n_matches
