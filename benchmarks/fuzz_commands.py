"""Command-line families of the fuzz harness (run by benchmarks/fuzz.py, or alone):

    python benchmarks/fuzz_commands.py [--signal-trials 100] [--family signal ...] [--seed 0]

- `signal`: every command run as the `sgloc` program in a child process, sent SIGINT (to its
  process group, as a terminal's Ctrl-C) or SIGTERM (to the process, as `kill` or `timeout`)
  at a random moment of its run. Each outcome must be exit 130 (SIGINT) or 143 (SIGTERM) with
  one line and nothing written, or exit 130/143 after the output was complete (the line names
  it), or the normal exit with a complete output when the output was already in place when the
  signal was sent. A normal exit when the output was not yet in place is a lost signal.
- `outputs`: every output option of every command given every extension matplotlib or sgloc's
  writers know, no extension, an empty folder and a new folder (a trailing `/`): written where
  named, or one `error:` line before any work with nothing written.
- `twice`: every command run twice into its own output: the second replaces sgloc's own output
  or is refused clearly, never as a file "not written by sgloc".
- `layouts`: inputs of one layout given to a command that reads another (a replay's run folder
  or results folder to localize, a keyframe table as a map, a graph file to replay, a bag to
  localize, a results file as settings): one clear error, never read as data.

Every case runs in a user's folder (maps, notes, a replay layout, an Airsim robot, sgloc's own
earlier results) snapshotted before and after: a file of the user's moved or changed is a bad
outcome in every family.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SRC = HERE.parent / "src"


def _fuzz():
    """benchmarks/fuzz.py (its seed files, in-process runner and classes)."""
    if "fuzz" in sys.modules:
        return sys.modules["fuzz"]
    spec = importlib.util.spec_from_file_location("fuzz", HERE / "fuzz.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["fuzz"] = module
    spec.loader.exec_module(module)
    return module


# -- the user's folder -----------------------------------------------------------------------------
def make_template(work: Path, seed: int = 0) -> Path:
    """A user's folder: maps/ (two graphs), notes.txt, layout/ (a two-robot replay layout),
    robot/ (a tiny Airsim robot), results/ (empty), and made/ with sgloc's own outputs (a
    replay's, a fleet's and a localization's results, a saved online session, a fake bag)."""
    fz = _fuzz()
    seeds = fz.write_seeds(work / "seeds", seed)
    proj = work / "template"
    (proj / "maps").mkdir(parents=True)
    (proj / "results").mkdir()
    (proj / "notes.txt").write_text("keep me\n")
    shutil.copy(seeds["query.json"], proj / "maps" / "query.json")
    shutil.copy(seeds["target.json"], proj / "maps" / "target.json")
    shutil.copy(seeds["query.csv"], proj / "maps" / "query.csv")
    shutil.copytree(seeds["layout"], proj / "layout")
    shutil.copytree(seeds["robot"], proj / "robot")
    made = proj / "made"
    for argv in (["replay", "layout", "--out", "made/replay", "--quiet"],
                 ["fleet", "maps/query.json", "maps/target.json", "--workers", "0",
                  "--out", "made/fleet"],
                 ["localize", "maps/query.json", "maps/target.json", "--out", "made/localize",
                  "--json", "made/result.json"],
                 ["experiment", "table", "--dataset", "synthetic", "--trials", "1",
                  "--workers", "1", "--out", "made/experiment"]):
        with _in(proj):
            rc, _o, err, exc = fz.run_case(argv, 300.0)
        if rc not in (0, 1):
            raise SystemExit(f"setting up the user's folder: sgloc {' '.join(argv)}: {exc} {err}")
    base, _good, _after = fz._session_base(work, seed)
    shutil.copy(base, made / "session.npz")
    bag = made / "bag"  # a rosbag2 folder's layout (what a user's recorder leaves)
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 5\n"
                                       "  storage_identifier: sqlite3\n")
    (bag / "bag_0.db3").write_bytes(b"SQLite format 3\x00" + bytes(84))
    (made / "run.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(32))
    return proj


@contextlib.contextmanager
def _in(folder: Path):
    here = os.getcwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(here)


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file and folder under `folder` (hidden ones too): bytes, or b"/" for a folder."""
    return _fuzz()._snapshot(folder)


def changes(before: dict[str, bytes], after: dict[str, bytes], out: str | None) -> list[str]:
    """What changed between two snapshots, except the output `out` (a relative path), what is
    in it and the folders made to hold it."""
    def ours(name: str) -> bool:
        return out is not None and (name == out or name.startswith(out.rstrip("/") + "/")
                                    or out.startswith(name + "/"))

    new = [n for n in after if n not in before and not ours(n)]
    changed = [n for n, b in before.items() if after.get(n) != b and not ours(n)]
    return new + changed


def _entries(path: Path) -> list[str]:
    """The names under `path` (a folder: every entry; a file: [""]); [] when absent."""
    if path.is_dir():
        return sorted(p.relative_to(path).as_posix() for p in path.rglob("*"))
    return [""] if path.exists() else []


# -- family: signals ---------------------------------------------------------------------------------
#: name -> (argv with {out}, the output (relative to the user's folder)).
SIGNAL_COMMANDS: dict[str, tuple[list[str], str]] = {
    "localize --out": (["localize", "--example", "--out", "{out}"], "results/run"),
    "localize --json": (["localize", "--example", "--json", "{out}"], "results/run.json"),
    "fleet": (["fleet", "maps/query.json", "maps/target.json", "--workers", "1", "--out", "{out}"],
              "results/run"),
    "replay": (["replay", "layout", "--out", "{out}", "--quiet"], "results/run"),
    "demo": (["demo", "--objects-only", "--out", "{out}"], "results/demo.png"),
    "build-graph": (["build-graph", "airsim", "robot", "-o", "{out}", "-q"], "results/g.json"),
    "experiment": (["experiment", "table", "--dataset", "synthetic", "--trials", "1",
                    "--workers", "1", "--out", "{out}"], "results/run"),
}  # fmt: skip
SIGNAL_GOOD = ("interrupted, nothing written", "interrupted after the output was complete",
               "finished before the signal", "killed in Python's start-up, nothing written")
SIGNAL_BAD = ("lost signal", "traceback", "hang", "written though interrupted",
              "incomplete output", "wrong exit code or message", "user files moved or changed",
              "workers left running")
CONSOLE_SCRIPT = "import sys\nfrom sgloc.cli import main\nif __name__ == '__main__':\n" \
                 "    sys.exit(main())\n"  # what pip writes for the `sgloc` entry point


def program(work: Path, how: str) -> list[str]:
    """The `sgloc` program: `python -m sgloc` or the console script (written under `work`)."""
    if how == "module":
        return [sys.executable, "-m", "sgloc"]
    script = work / "bin" / "sgloc"
    if not script.exists():
        script.parent.mkdir(parents=True, exist_ok=True)
        script.write_text(CONSOLE_SCRIPT)
    return [sys.executable, str(script)]


def child_env(work: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(SRC), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.setdefault("SGLOC_CACHE", str(work / "cache"))
    env["MPLBACKEND"] = "Agg"
    return env


@dataclass
class SignalRun:
    """One run of a command under a signal: what was sent when, and what came out."""

    rc: int | None
    stderr: str
    sent: bool  # the process was alive when the signal was due
    done_before: bool  # the output was in place when the signal was sent
    seconds: float
    left: bool = False  # processes of its group still running after it ended


def run_signalled(argv: list[str], cwd: Path, env: dict, signum: int, delay: float | None,
                  out: Path, timeout: float) -> SignalRun:
    """Run `argv` in `cwd`; after `delay` s (None: never) send `signum` (SIGINT to the process
    group, SIGTERM to the process) unless it has ended."""
    t0 = time.monotonic()
    with tempfile.TemporaryFile("w+") as err:
        p = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=err,
                             stdin=subprocess.DEVNULL, start_new_session=True)
        sent = done_before = False
        if delay is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(delay)
            if p.poll() is None:
                done_before = out.exists()
                (os.killpg if signum == signal.SIGINT else os.kill)(p.pid, signum)
                sent = True
        try:
            rc = p.wait(timeout)
        except subprocess.TimeoutExpired:
            rc = None
        seconds = time.monotonic() - t0
        left = _group_alive(p.pid)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        err.seek(0)
        return SignalRun(rc, err.read(), sent, done_before, seconds, left)


def _group_alive(pgid: int, wait: float = 2.0) -> bool:
    """True if a process of group `pgid` still runs `wait` s after its leader ended."""
    end = time.monotonic() + wait
    while True:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        if time.monotonic() > end:
            return True
        time.sleep(0.05)


def classify_signal(run: SignalRun, signum: int, complete: bool, absent: bool,
                    changed: list[str]) -> str:
    """The outcome of one signalled run. `complete`: the output holds what a normal run writes;
    `absent`: the output is not there; `changed`: the user's files changed besides it."""
    if run.rc is None:
        return "hang"
    if changed:
        return "user files moved or changed"
    if run.left:
        return "workers left running"
    if run.rc == -signum:  # the default handler: Python had not run sgloc's first line yet
        return "killed in Python's start-up, nothing written" if absent else \
            "written though interrupted"
    if "Traceback" in run.stderr or "Exception ignored" in run.stderr:
        return "traceback"
    code = 143 if signum == signal.SIGTERM else 130
    lines = [ln for ln in run.stderr.splitlines() if ln.strip()]
    if run.rc == code:
        how = "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted (SIGINT)"
        if not lines or not lines[-1].startswith(how):
            return "wrong exit code or message"
        if absent:
            return "interrupted, nothing written"
        if complete and "nothing was written" not in lines[-1]:
            return "interrupted after the output was complete"
        return "written though interrupted"
    if run.rc in (0, 1):
        if run.sent and not run.done_before:
            return "lost signal"
        return "finished before the signal" if complete else "incomplete output"
    return "wrong exit code or message"


def run_signal_family(work: Path, template: Path, trials: int, seed: int = 0,
                      timeout: float = 120.0, commands: list[str] | None = None,
                      progress: bool = False) -> tuple[dict[str, Counter], list[tuple]]:
    """`trials` signalled runs of each command; (counts per command, [(command, outcome,
    detail)] of the bad ones). A first unsignalled run per command gives its duration and its
    complete output; signals are then sent uniformly over 0-110 % of that duration."""
    rng = np.random.default_rng([seed, 37])
    env = child_env(work)
    results: dict[str, Counter] = {}
    bad: list[tuple] = []
    for name in commands or list(SIGNAL_COMMANDS):
        argv, out = SIGNAL_COMMANDS[name]
        args = [a.replace("{out}", out) for a in argv]
        for _ in range(2):  # the second run's duration: caches warm, as in the trials
            proj = _fresh(work, template)
            ref = run_signalled(program(work, "module") + args, proj, env, 0, None,
                                proj / out, timeout)
        if ref.rc not in (0, 1):
            raise SystemExit(f"sgloc {' '.join(args)}: exit {ref.rc}: {ref.stderr[-500:]}")
        expected = _entries(proj / out)
        counts: Counter = Counter()
        for k in range(trials):
            signum = signal.SIGINT if k % 2 == 0 else signal.SIGTERM
            how = "module" if (k // 2) % 2 == 0 else "script"
            delay = float(rng.uniform(0.0, 1.1 * ref.seconds))
            proj = _fresh(work, template)
            before = snapshot(proj)
            run = run_signalled(program(work, how) + args, proj, env, signum, delay, proj / out,
                                timeout)
            got = _entries(proj / out)
            outcome = classify_signal(run, signum, got == expected, not got,
                                      changes(before, snapshot(proj), out))
            counts[outcome] += 1
            if outcome in SIGNAL_BAD:
                bad.append((name, outcome, f"{signal.Signals(signum).name} at {delay:.2f} s "
                            f"({how}), exit {run.rc}: {run.stderr.strip()[-300:]}"))
        results[name] = counts
        if progress:
            print(f"  signal {name}: {dict(counts)} (a run {ref.seconds:.1f} s)", file=sys.stderr)
    return results, bad


def _fresh(work: Path, template: Path) -> Path:
    """A new copy of the user's folder."""
    proj = work / "proj"
    if proj.exists():
        shutil.rmtree(proj)
    shutil.copytree(template, proj, symlinks=True)
    return proj
