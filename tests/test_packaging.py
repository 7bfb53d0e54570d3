"""What a user's machine sees: optional Dask, caches in the cache folder, nothing written
where the user did not say, the top-level API."""

from __future__ import annotations

import sys

import pytest

import sgloc
from sgloc.cli import main
from sgloc.errors import SglocError


def test_localize_fleet_is_top_level():
    from sgloc.online.fleet import localize_fleet

    assert sgloc.localize_fleet is localize_fleet


def test_missing_dask_is_a_one_line_hint(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import fails as if not installed
    from sgloc.optional import require

    with pytest.raises(SglocError, match=r"pip install 'sgloc\[dask\]'"):
        require("distributed", "dask", "--scheduler")
    argv = ["experiment", "table", "--trials", "1", "--scheduler", "tcp://127.0.0.1:1",
            "--descriptors", "fast", "--rejections", "none", "--out", str(tmp_path / "x")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: ") and "sgloc[dask]" in err[-1]


def test_failed_experiment_leaves_no_folder(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["experiment", "table", "--set", "nonsense=1", "--out", str(out)]) == 2
    assert not out.exists()


def test_caches_go_to_the_cache_folder(monkeypatch, tmp_path):
    from sgloc.datasets.downloads import cache_dir
    from sgloc.evaluation.pairs_sim import evaluation_cache_dir

    monkeypatch.setenv("SGLOC_CACHE", str(tmp_path / "c"))
    assert cache_dir() == tmp_path / "c"
    assert evaluation_cache_dir() == tmp_path / "c" / "evaluation"
    monkeypatch.delenv("SGLOC_CACHE")
    assert "site-packages" not in str(cache_dir()) and "sgloc" in cache_dir().name


def test_localize_writes_only_where_told(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["localize", "--example", "--format", "json"]) == 0
    assert list(tmp_path.iterdir()) == []
