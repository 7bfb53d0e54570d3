"""The output rule every writing command follows (`sgloc.io.files`): an output never replaces,
moves or deletes anything sgloc did not write (the working folder, a home, an input, a folder
holding one, a user's files); results follow the umask; an interruption leaves nothing
half-written; two runs writing one path: the second is refused at once. And a `--scheduler`
that is not a Dask scheduler is one clear line within seconds."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from sgloc.cli import main
from sgloc.errors import OutputPathError
from sgloc.io.files import MANIFEST, staged_folder

SRC = Path(__file__).resolve().parent.parent / "src"


def _snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under `folder` (hidden ones too) with its bytes."""
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}  # fmt: skip


@pytest.fixture()
def proj(tmp_path, monkeypatch):
    """A user's project folder holding two maps and notes, the working folder of the test."""
    from sgloc.sim.object_world import make_two_robot_scene

    folder = tmp_path / "proj"
    (folder / "maps").mkdir(parents=True)
    scene = make_two_robot_scene(seed=0)
    scene.query.save(folder / "maps" / "B.json")
    scene.target.save(folder / "maps" / "A.json")
    (folder / "notes.txt").write_text("keep me\n")
    monkeypatch.chdir(folder)
    return folder


def _outs(proj: Path) -> dict[str, str]:
    return {
        "dot": ".",
        "cwd": str(proj),
        "up-and-back": f"../{proj.name}",
        "parent of cwd": "..",
        "input's folder": "maps",
        "input file": "maps/A.json",
        "home": str(proj.parent / "home"),  # a stand-in home (HOME is set to it)
    }


@pytest.mark.parametrize("kind", ["dot", "cwd", "up-and-back", "parent of cwd",
                                  "input's folder", "input file", "home"])  # fmt: skip
@pytest.mark.parametrize("command", ["localize", "fleet"])
def test_out_over_the_users_folders_is_refused_and_nothing_moves(
    proj, command, kind, capsys, monkeypatch
):
    (proj.parent / "home").mkdir()
    (proj.parent / "home" / ".profile").write_text("mine\n")
    monkeypatch.setenv("HOME", str(proj.parent / "home"))
    out = _outs(proj)[kind]
    before = _snapshot(proj.parent)
    argv = [command, "maps/B.json", "maps/A.json", "--out", out]
    argv += ["--workers", "0"] if command == "fleet" else []
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {out}: "), err
    assert "give a new path for --out" in err[0]
    assert _snapshot(proj.parent) == before  # not a byte moved
    assert sorted(os.listdir(proj.parent)) == ["home", "proj"]  # no hidden sibling


def test_the_root_folder_is_refused():  # checked without a command: nothing could be written
    from sgloc.io.files import check_output_path

    with pytest.raises(OutputPathError, match="is the root folder"):
        check_output_path("/")


@pytest.mark.parametrize("argv", [
    ["experiment", "table", "--trials", "1", "--out", "."],
    ["replay", "--city", "--robots", "2", "--out", ".."],
    ["replay", "maps", "--out", "maps"],
    ["demo", "--objects-only", "--out", "notes.txt"],
    ["build-graph", "airsim", "maps", "-o", "maps"],
    ["localize", "maps/B.json", "maps/A.json", "--json", "maps/A.json"],
    ["localize", "maps/B.json", "maps/A.json", "--out", "r", "--json", "r/full.json"],
    ["replay", "--city", "--robots", "2", "--out", "r", "--out-bag", "r"],
    ["replay", "--city", "--robots", "2", "--out", "b2/res", "--out-bag", "b2"],
    ["replay", "--city", "--robots", "2", "--out", "b2", "--out-bag", "b2/bag"],
])  # fmt: skip
def test_every_writing_command_refuses_before_any_work(proj, argv, capsys):
    before = _snapshot(proj.parent)
    t0 = time.perf_counter()
    assert main(argv) == 2
    assert time.perf_counter() - t0 < 10  # refused at once, not after the work
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    if "--out-bag" in argv:
        assert "would overlap" in err[0], err
    assert _snapshot(proj.parent) == before and sorted(os.listdir(proj.parent)) == ["proj"]


@pytest.mark.parametrize("where, argv", [
    ("run", ["replay", "."]),  # from inside: the default results/replay lies in the input
    (".", ["replay", "run", "--out", "run/results"]),
    (".", ["replay", "--robot", "a=run/world0", "--robot", "b=run/world1", "--out",
           "run/world0/res"]),
])  # fmt: skip
def test_a_results_folder_inside_an_input_folder_is_refused_at_once(proj, where, argv, capsys,
                                                                    monkeypatch):
    from sgloc.evaluation.replay_scenarios import world_scenario
    from sgloc.io.plain_layout import write_plain_layout

    write_plain_layout(proj / "run", world_scenario().logs)
    before = _snapshot(proj.parent)
    monkeypatch.chdir(proj / where)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "lies inside the input folder" in err[0], err
    assert _snapshot(proj.parent) == before


@pytest.mark.parametrize("argv, blocked, says", [
    (["replay", "run", "--out", "A", "--out-bag", "B"], "rosbags", "--out-bag"),
    (["replay", "run", "--out", "A", "--backend", "robot"], None, "--backend"),
])  # fmt: skip
def test_an_option_that_is_refused_is_refused_before_the_replay(proj, argv, blocked, says,
                                                                 capsys, monkeypatch):
    """An output option whose extra is missing (--out-bag without rosbags), a bad back-end:
    one line at once, nothing written."""
    from sgloc.evaluation.replay_scenarios import world_scenario
    from sgloc.io.plain_layout import write_plain_layout

    write_plain_layout(proj / "run", world_scenario().logs)
    if blocked:
        monkeypatch.setitem(sys.modules, blocked, None)
    before = _snapshot(proj.parent)
    calls = []
    monkeypatch.setattr("sgloc.replay.inputs.read_logs", lambda *a, **k: calls.append(a))
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert _snapshot(proj.parent) == before and not calls  # the input not even read


def test_a_folder_of_the_users_files_is_refused_an_empty_one_written_into(proj, capsys):
    (proj / "mine").mkdir()
    (proj / "mine" / "data.csv").write_text("1,2\n")
    argv = ["localize", "maps/B.json", "maps/A.json", "--out"]
    assert main([*argv, "mine"]) == 2
    assert "holds files sgloc did not write (e.g. data.csv)" in capsys.readouterr().err
    assert os.listdir(proj / "mine") == ["data.csv"]
    (proj / "empty").mkdir()
    os.chmod(proj / "empty", 0o750)
    inode = os.stat(proj / "empty").st_ino
    assert main([*argv, "empty"]) in (0, 1)
    assert (proj / "empty" / "result.json").is_file() and (proj / "empty" / MANIFEST).is_file()
    st = os.stat(proj / "empty")
    assert st.st_ino == inode and st.st_mode & 0o777 == 0o750  # the user's folder, kept


def test_an_earlier_results_folder_is_replaced_unless_the_user_added_a_file(proj, capsys):
    argv = ["localize", "maps/B.json", "maps/A.json", "--out", "results/r"]
    assert main([*argv, "--seed", "1"]) in (0, 1)
    listed = json.loads((proj / "results" / "r" / MANIFEST).read_text())["files"]
    assert "result.json" in listed and "config.yaml" in listed
    assert main([*argv, "--seed", "2"]) in (0, 1)
    assert json.loads((proj / "results" / "r" / "result.json").read_text())["seed"] == 2
    (proj / "results" / "r" / "my_notes.md").write_text("mine")
    capsys.readouterr()
    assert main([*argv, "--seed", "3"]) == 2
    err = capsys.readouterr().err
    assert "my_notes.md" in err and "sgloc did not write" in err
    assert (proj / "results" / "r" / "my_notes.md").read_text() == "mine"
    assert json.loads((proj / "results" / "r" / "result.json").read_text())["seed"] == 2
    assert sorted(os.listdir(proj / "results")) == ["r"]


@pytest.fixture()
def umask():
    """Set the process umask for a test; restored after."""
    old = os.umask(0o022)
    yield os.umask
    os.umask(old)


@pytest.mark.parametrize("mask", [0o022, 0o077])
def test_results_follow_the_umask(proj, umask, mask):
    umask(mask)
    folder_mode, file_mode = 0o777 & ~mask, 0o666 & ~mask
    argv = ["localize", "maps/B.json", "maps/A.json", "--out", "results/r", "--json", "r.json"]
    assert main(argv) in (0, 1)
    assert os.stat(proj / "results" / "r").st_mode & 0o777 == folder_mode
    assert os.stat(proj / "results").st_mode & 0o777 == folder_mode
    for p in (proj / "results" / "r").iterdir():
        assert os.stat(p).st_mode & 0o777 == file_mode, p.name
    assert os.stat(proj / "r.json").st_mode & 0o777 == file_mode
    assert main(["fleet", "maps/B.json", "maps/A.json", "--workers", "0", "--out", "f"]) in (0, 1)
    assert os.stat(proj / "f").st_mode & 0o777 == folder_mode


def test_json_replaces_only_an_earlier_result_document(proj, capsys):
    argv = ["localize", "maps/B.json", "maps/A.json", "--json"]
    assert main([*argv, "r.json"]) in (0, 1)
    assert main([*argv, "r.json", "--seed", "4"]) in (0, 1)
    assert json.loads((proj / "r.json").read_text())["seed"] == 4
    (proj / "other.json").write_text('{"mine": 1}')
    assert main([*argv, "other.json"]) == 2
    assert "was not written by sgloc" in capsys.readouterr().err
    assert (proj / "other.json").read_text() == '{"mine": 1}'


def test_an_output_bag_follows_the_same_rule_as_out(proj, capsys):
    pytest.importorskip("rosbags")
    argv = ["replay", "--city", "--robots", "2", "--quiet", "--out", "r", "--out-bag", "bag"]
    assert main(argv) in (0, 1)
    first = _snapshot(proj / "bag")
    assert any(name.endswith(".mcap") for name in first) and MANIFEST in first
    assert main(argv) in (0, 1)  # an earlier bag of sgloc: replaced, like an earlier --out
    (proj / "bag" / "mine.txt").write_text("x")
    assert main(argv) == 2
    assert "mine.txt" in capsys.readouterr().err and (proj / "bag" / "mine.txt").exists()


def test_library_writers_follow_the_rule(proj):
    from sgloc.maps.graph import SemanticGraph
    from sgloc.online.fleet import localize_fleet

    graphs = [SemanticGraph.load(proj / "maps" / f) for f in ("B.json", "A.json")]
    with pytest.raises(OutputPathError, match="working folder"):
        localize_fleet(graphs, workers=0, out=proj)
    with pytest.raises(OutputPathError, match="sgloc did not write"):
        localize_fleet(graphs, workers=0, out=proj / "maps")
    assert sorted(os.listdir(proj)) == ["maps", "notes.txt"]


# -- interruptions and concurrent runs (subprocesses) -------------------------------------------
#: A localize run whose results folder is slow to write (it sleeps in the staging folder).
SLOW_WRITER = """
import sys, time
import sgloc.io.results as results
real = results.write_results_into
def slow(out, *a, **k):
    files = real(out, *a, **k)
    print("writing", flush=True)
    time.sleep(float(sys.argv[2]))
    return files
results.write_results_into = slow
from sgloc.cli import main
sys.exit(main(["localize", "--example", "--out", sys.argv[1]]))
"""


def _slow_writer(out: Path, seconds: float) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    proc = subprocess.Popen([sys.executable, "-c", SLOW_WRITER, str(out), str(seconds)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()  # blocks until the writer is inside its staging folder
    assert line.strip() == "writing", proc.stderr.read()
    return proc


@pytest.mark.parametrize("sig, code, word", [(signal.SIGTERM, 143, "terminated"),
                                             (signal.SIGINT, 130, "interrupted")])
def test_a_signal_while_writing_leaves_nothing(tmp_path, sig, code, word):
    out = tmp_path / "res"
    proc = _slow_writer(out, 60)
    try:
        assert any(p.name.startswith(".res.partial-") for p in tmp_path.iterdir())
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == code
    lines = [ln for ln in err.strip().splitlines() if ln.strip() and "compil" not in ln]
    assert lines == [f"{word} ({sig.name}); nothing was written."]
    assert os.listdir(tmp_path) == []  # no staging folder, no lock file, no results folder


def test_a_killed_writers_leftovers_are_removed_by_the_next(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    pid = int(dead.stdout)
    stale = tmp_path / f".res.partial-{pid}-abc123"
    (stale / "sub").mkdir(parents=True)
    (tmp_path / f".res.tmp-{pid}").mkdir()  # an older writer's name
    keep = tmp_path / f".other.partial-{pid}-abc123"  # another output's: not ours to touch
    keep.mkdir()
    with staged_folder(tmp_path / "res") as stage:
        (stage / "a.txt").write_text("a")
    assert sorted(os.listdir(tmp_path)) == [keep.name, "res"]


def test_two_runs_writing_one_out_the_second_is_refused_at_once(tmp_path, capsys):
    out = tmp_path / "res"
    first = _slow_writer(out, 3)
    try:
        t0 = time.perf_counter()
        assert main(["localize", "--example", "--out", str(out)]) == 2
        assert time.perf_counter() - t0 < 10
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "another sgloc run is writing it now" in err[0]
        first.communicate(timeout=60)
    finally:
        first.kill()
    assert first.returncode == 0
    assert sorted(os.listdir(tmp_path)) == ["res"]  # the lock file removed
    assert (out / "result.json").is_file()


# -- --scheduler ---------------------------------------------------------------------------------
@contextlib.contextmanager
def _service(kind: str):
    """A loopback TCP service that is not a Dask scheduler: `garbage` sends random bytes at
    once, `silent` reads and never answers (an HTTP server waiting for a request), `close`
    hangs up."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    server.settimeout(0.2)
    stop = threading.Event()
    conns = []

    def run():
        rng = __import__("random").Random(0)
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            conns.append(conn)
            if kind == "garbage":
                conn.sendall(bytes(rng.randrange(256) for _ in range(4096)))
            elif kind == "http":
                conn.sendall(b"HTTP/1.0 200 OK\r\nContent-Length: 2\r\n\r\nhi")
            elif kind == "close":
                conn.close()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    finally:
        stop.set()
        thread.join(5)
        for c in conns:
            c.close()
        server.close()


@contextlib.contextmanager
def _time_limit(seconds: float):
    def on_alarm(signum, frame):
        raise TimeoutError(f"no answer within {seconds} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize("kind", ["garbage", "http", "silent", "close"])
def test_a_scheduler_that_is_not_dask_is_one_line_within_seconds(proj, kind, capsys):
    pytest.importorskip("distributed")
    with _service(kind) as address, _time_limit(30):
        t0 = time.perf_counter()
        rc = main(["fleet", "maps/B.json", "maps/A.json", "--out", "f", "--scheduler", address])
        elapsed = time.perf_counter() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and address in err[0], err
    assert "not a Dask scheduler" in err[0] or "does not answer" in err[0]
    assert elapsed < 10
    assert not (proj / "f").exists()


def test_a_real_dask_scheduler_passes_the_check():
    distributed = pytest.importorskip("distributed")
    from sgloc.runtime.tasks import check_scheduler

    with distributed.LocalCluster(n_workers=0, processes=False, host="127.0.0.1",
                                  scheduler_kwargs={"protocol": "tcp"}) as cluster:
        assert cluster.scheduler_address.startswith("tcp://")
        check_scheduler(cluster.scheduler_address)  # raises if refused
