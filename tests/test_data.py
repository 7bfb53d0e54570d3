"""Data on demand: where data sets are found, and `sgloc data fetch` against a local server
(127.0.0.1, serving a folder laid out like the data folder; no test reaches the internet)."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import shutil
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest

import sgloc.datasets.downloads as sd
from sgloc.cli import main
from sgloc.errors import DatasetError, UnknownNameError


class _Quiet(SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # keep the test output clean
        pass


@pytest.fixture
def serve():
    """serve(folder) -> base URL of a local HTTP server on 127.0.0.1 serving `folder`."""
    servers = []

    def start(folder: Path) -> str:
        handler = functools.partial(_Quiet, directory=str(folder))
        srv = ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=srv.serve_forever, daemon=True).start()
        servers.append(srv)
        return f"http://127.0.0.1:{srv.server_address[1]}"

    yield start
    for srv in servers:
        srv.shutdown()
        srv.server_close()


@pytest.fixture
def no_data(tmp_path, monkeypatch):
    """No SGLOC_DATA, an empty per-user data folder, no checkout data folder."""
    monkeypatch.delenv("SGLOC_DATA", raising=False)
    monkeypatch.setattr(sd, "user_data_dir", lambda: tmp_path / "user-data")
    monkeypatch.setattr(sd, "checkout_data_dir", lambda: None)
    return tmp_path / "user-data"


def test_airsim_sample_ships_with_the_package(no_data):
    c1, c2 = sd.airsim_guo()
    assert (len(c1), len(c2)) == (318, 328)
    p1, p2 = sd.airsim_guo_paths()
    assert p1.parent == sd.sample_dir("airsim_guo")
    for f, p in zip(sd.dataset("airsim_guo").files, (p1, p2), strict=True):
        assert hashlib.sha256(p.read_bytes()).hexdigest() == f.sha256
    assert (p1.parent / "LICENSE").read_text().startswith("MIT License")


def test_missing_set_names_the_fetch_command(no_data):
    assert sd.find_dataset("kitti00") is None
    with pytest.raises(DatasetError, match="sgloc data fetch kitti00"):
        sd.data_path("kitti00", "poses_00.txt")
    with pytest.raises(UnknownNameError, match="kitti00"):
        sd.dataset("kitti01")


def test_sgloc_data_wins_over_the_user_folder(tmp_path, monkeypatch, no_data):
    (no_data / "kitti00").mkdir(parents=True)
    assert sd.find_dataset("kitti00") == no_data / "kitti00"
    (tmp_path / "mine" / "kitti00").mkdir(parents=True)
    monkeypatch.setenv("SGLOC_DATA", str(tmp_path / "mine"))
    assert sd.find_dataset("kitti00") == tmp_path / "mine" / "kitti00"
    assert sd.fetch_dir() == tmp_path / "mine"


def test_installed_package_points_nowhere_near_the_venv(monkeypatch):
    monkeypatch.delenv("SGLOC_DATA", raising=False)
    site = Path("/opt/venv/lib/python3.11/site-packages")
    monkeypatch.setattr(sd, "__file__", str(site / "sgloc" / "datasets" / "downloads.py"))
    monkeypatch.setattr(sd, "PROJECT_ROOT", site.parent)
    assert sd.checkout_data_dir() is None
    assert all("venv" not in str(r) for r in sd.data_roots())


def test_fetch_airsim_from_local_server_checks_hashes(serve, no_data, capsys, monkeypatch):
    base = serve(sd.sample_dir("airsim_guo").parent)
    monkeypatch.setenv("SGLOC_DATA_URL", base)
    assert main(["data", "fetch", "airsim_guo"]) == 0
    out, err = capsys.readouterr()
    assert out.strip() == str(no_data / "airsim_guo")
    assert "licence: MIT" in err
    assert sd.find_dataset("airsim_guo") == no_data / "airsim_guo"
    assert sd.is_complete("airsim_guo")


def test_fetch_refuses_a_file_whose_hash_differs(serve, tmp_path, no_data, monkeypatch, capsys):
    mirror = tmp_path / "mirror" / "airsim_guo"
    shutil.copytree(sd.sample_dir("airsim_guo"), mirror)
    with open(mirror / "cloud2.pcd", "a") as fh:
        fh.write("0 0 0 0\n")
    monkeypatch.setenv("SGLOC_DATA_URL", serve(mirror.parent))
    assert main(["data", "fetch", "airsim_guo"]) == 2
    err = capsys.readouterr().err
    assert "sha256" in err and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("error: ")
    assert not (no_data / "airsim_guo" / "cloud2.pcd").exists()
    assert not sd.is_complete("airsim_guo", no_data / "airsim_guo")


def test_published_superset_keeps_one_sequence(serve, tmp_path, no_data, monkeypatch):
    """A published file holding every sequence is checked against its own hash, then cut to
    the kept sequence, which is checked against the set's hash."""
    upstream = "seq i seq_db j\n0 1 0 9 1.0\n5 2 5 7 2.0\n0 3 0 8 3.0\n"
    kept = "seq i seq_db j\n0 1 0 9 1.0\n0 3 0 8 3.0\n"
    sha = lambda s: hashlib.sha256(s.encode()).hexdigest()  # noqa: E731
    (tmp_path / "gh").mkdir()
    (tmp_path / "gh" / "lc.txt").write_text(upstream)
    f = sd.RemoteFile("lc.txt", "o/r", "c" * 40, "lc.txt", sha(kept), sha(upstream), "0")
    fake = sd.DataSet("fake", "", "MIT", (f,))
    monkeypatch.setitem(sd.DOWNLOADS, "fake", fake)
    base = serve(tmp_path / "gh")
    monkeypatch.setattr(sd.RemoteFile, "source",
                        lambda self, ds: (f"{base}/{self.path}", self.upstream_sha256))
    folder = sd.fetch("fake")
    assert (folder / "lc.txt").read_text() == kept
    bad = dataclasses.replace(f, sha256=sha("other rows"))  # the kept rows do not match
    monkeypatch.setitem(sd.DOWNLOADS, "fake", dataclasses.replace(fake, files=(bad,)))
    (folder / "lc.txt").unlink()
    with pytest.raises(DatasetError, match="sequence 0"):
        sd.fetch("fake")


def test_fetch_kitti00_from_local_server(serve, data_dir, no_data, monkeypatch):
    """The real KITTI 00 files, served from the data folder, fetched and loaded."""
    monkeypatch.setenv("SGLOC_DATA_URL", serve(data_dir))
    folder = sd.fetch("kitti00")
    assert folder == no_data / "kitti00" and sd.is_complete("kitti00")
    from sgloc.datasets import make_dataset

    ds = make_dataset("kitti_objects", folder, scans=(0, 5))
    assert len(ds) == 6 and np.isfinite(ds.poses).all()


def test_data_list_and_path(capsys, no_data):
    assert main(["data", "list"]) == 0
    out = capsys.readouterr().out
    assert "sgloc data fetch kitti00" in out and "shipped" in out
    assert main(["data", "path", "airsim_guo"]) == 0
    assert capsys.readouterr().out.strip() == str(sd.sample_dir("airsim_guo"))


def test_fetch_uses_a_verified_copy_already_in_a_data_folder(tmp_path, no_data, monkeypatch):
    # A copy beside the checkout whose hashes match: nothing to download (the URL is dead).
    checkout = tmp_path / "checkout-data"
    shutil.copytree(sd.sample_dir("airsim_guo"), checkout / "airsim_guo")
    monkeypatch.setattr(sd, "checkout_data_dir", lambda: checkout)
    monkeypatch.setenv("SGLOC_DATA_URL", "http://127.0.0.1:9/")
    assert sd.fetch("airsim_guo") == checkout / "airsim_guo"
    assert not (no_data / "airsim_guo").exists()
    # A copy whose file differs is not used: fetch tries to download (and fails here).
    (checkout / "airsim_guo" / "cloud1.pcd").write_text("changed")
    with pytest.raises(DatasetError):
        sd.fetch("airsim_guo")


def test_failed_fetch_leaves_no_folder_and_path_checks_completeness(no_data, monkeypatch, capsys):
    monkeypatch.setenv("SGLOC_DATA_URL", "http://127.0.0.1:9/")  # nothing listens there
    assert main(["data", "fetch", "kitti00"]) == 2
    assert not (no_data / "kitti00").exists()
    capsys.readouterr()
    (no_data / "kitti00").mkdir(parents=True)  # what an interrupted download used to leave
    assert main(["data", "path", "kitti00"]) == 2
    err = capsys.readouterr().err
    assert "incomplete" in err and "sgloc data fetch kitti00" in err
    argv = ["experiment", "overlap", "--dataset", "kitti00", "--trials", "1", "--workers", "1",
            "--out", str(no_data / "exp")]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "sgloc data fetch kitti00" in err and "pose file" not in err


def test_benchmarks_leave_out_a_missing_set_and_say_so(no_data, capsys):
    assert not sd.present_or_say("kitti00", "the KITTI 00 pairs")
    err = capsys.readouterr().err
    assert "the KITTI 00 pairs is left out" in err and "sgloc data fetch kitti00" in err
    with pytest.raises(SystemExit, match="sgloc data fetch kitti00"):
        sd.present_or_say("kitti00", "the KITTI 00 pairs", required=True)
    assert sd.present_or_say("airsim_guo", "the Airsim pairs")  # shipped
