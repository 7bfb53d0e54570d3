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

import contextlib
import importlib.util
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
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


# -- family: signals -------------------------------------------------------------------------------
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
#: Python's own start-up (before sgloc's first line) raising KeyboardInterrupt: its traceback
#: names no file of sgloc's; reported apart (sgloc cannot handle a signal before it runs).
SIGNAL_RESIDUAL = ("KeyboardInterrupt in Python's start-up, nothing written",)
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
    env["PYTHONPATH"] = os.pathsep.join([str(SRC), *filter(None, [env.get("PYTHONPATH")])])
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


def _startup_interrupt(stderr: str) -> bool:
    """True for Python's KeyboardInterrupt traceback from before any file of sgloc ran."""
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    return bool(lines) and lines[-1] == "KeyboardInterrupt" and "/sgloc/" not in stderr


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
    if run.rc == 1 and absent and _startup_interrupt(run.stderr):
        return "KeyboardInterrupt in Python's start-up, nothing written"
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
    detail)] of the bad ones). Two unsignalled runs per command come first; the second (caches
    warm, as in the trials) gives the command's duration and its complete output. Signals are
    then sent uniformly over 0-110 % of that duration."""
    with _default_dispositions():
        return _signal_family(work, template, trials, seed, timeout, commands, progress)


@contextlib.contextmanager
def _default_dispositions():
    """SIGINT and SIGTERM not ignored in this process while it starts the children (a shell
    starts a background job with SIGINT ignored, and a child inherits that until its first
    line; a terminal's foreground command has the defaults)."""
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for s, handler in previous.items():
        if handler == signal.SIG_IGN:
            signal.signal(s, signal.default_int_handler if s == signal.SIGINT else signal.SIG_DFL)
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _signal_family(work: Path, template: Path, trials: int, seed: int, timeout: float,
                   commands: list[str] | None, progress: bool
                   ) -> tuple[dict[str, Counter], list[tuple]]:
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


# -- the in-process families: outputs, twice, layouts ----------------------------------------------
@dataclass
class Outcome:
    """One in-process case's result."""

    rc: int | None
    stderr: str
    exc: str
    seconds: float
    changed: list[str] = field(default_factory=list)  # the user's files changed (not the output)
    new: list[str] = field(default_factory=list)  # entries that appeared (relative names)


def run_in(proj: Path, argv: list[str], out: str | None, timeout: float,
           other: str | None = None) -> Outcome:
    """`sgloc argv` in-process in the user's folder `proj`; what it changed besides its outputs
    `out` and `other`."""
    fz = _fuzz()
    before = snapshot(proj)
    t0 = time.perf_counter()
    with _in(proj):
        rc, _stdout, err, exc = fz.run_case(argv, timeout)
    seconds = time.perf_counter() - t0
    after = snapshot(proj)
    new = sorted(n for n in after if n not in before or after[n] != before[n])
    changed = [n for n in changes(before, after, out) if n in changes(before, after, other)]
    return Outcome(rc, err, exc, seconds, changed, new)


def _one_error_line(stderr: str) -> bool:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    if lines and lines[0].lstrip().startswith("Usage: sgloc"):
        lines = lines[1:]
    return len(lines) == 1 and lines[0].startswith("error: ")


def _broken(o: Outcome) -> str:
    """The bad outcome every family shares ("" when none)."""
    if o.exc == "hang":
        return "hang"
    if o.exc or "Traceback" in o.stderr:
        return "traceback"
    if o.changed:
        return "user files moved or changed"
    if o.rc == 2 and not _one_error_line(o.stderr):
        return "error not one line"
    if o.rc not in (0, 1, 2):
        return "wrong exit code"
    return ""


#: Output options: name -> (argv before the option, the option, "folder" | "file"); the other
#: output a case writes besides it, if any, is OTHER_OUTPUT's.
OUTPUT_OPTIONS: dict[str, tuple[list[str], str, str]] = {
    "localize --out": (["localize", "--example"], "--out", "folder"),
    "localize --json": (["localize", "--example"], "--json", "file"),
    "localize --rerun": (["localize", "--example"], "--rerun", "file"),
    "fleet --out": (["fleet", "maps/query.json", "maps/target.json", "--workers", "0"], "--out",
                    "folder"),
    "replay --out": (["replay", "layout", "--quiet"], "--out", "folder"),
    "replay --out-bag": (["replay", "layout", "--quiet", "--out", "results/fleet"], "--out-bag",
                         "folder"),
    "demo --out": (["demo", "--objects-only"], "--out", "file"),
    "build-graph -o": (["build-graph", "airsim", "robot", "-q"], "-o", "file"),
    "experiment --out": (["experiment", "table", "--dataset", "synthetic", "--trials", "1",
                          "--workers", "1"], "--out", "folder"),
}  # fmt: skip
OTHER_OUTPUT = {"replay --out-bag": "results/fleet"}
#: The extensions of sgloc's writers and readers besides matplotlib's picture formats.
WRITER_EXTENSIONS = ["json", "npz", "npy", "pcd", "ply", "csv", "txt", "tum", "kitti", "g2o",
                     "yaml", "md", "rrd", "mcap", "db3", "xyz", "JSON", "PNG"]


def output_forms() -> list[tuple[str, str]]:
    """(form, output path in the user's folder): every extension, none, an empty folder and a
    new folder named with a trailing slash."""
    from matplotlib.backend_bases import FigureCanvasBase

    exts = sorted(FigureCanvasBase.get_supported_filetypes()) + WRITER_EXTENSIONS
    forms = [(f".{e}", f"results/out.{e}") for e in exts]
    return forms + [("no extension", "results/out"), ("empty folder", "results/empty"),
                    ("new folder/", "results/newdir/")]


def classify_output(o: Outcome, out: str, kind: str, refusal_limit: float) -> str:
    """The outcome of an output case: written where named, or refused before the work."""
    bad = _broken(o)
    if bad:
        return bad
    if o.rc == 2:
        if o.new:
            return "refused but something written"
        return "refused after the work" if o.seconds > refusal_limit else "refused (one line)"
    named = out.rstrip("/")
    folder_given = out.endswith("/") or named == "results/empty"
    placed = [n for n in o.new if n == named or n.startswith(named + "/")]
    if not placed:
        return "written elsewhere than named"
    if kind == "file" and folder_given and placed == [named]:  # no named file inside it
        return ("a file at a new folder's name (trailing /)" if out.endswith("/")
                else "written elsewhere than named")
    return "written"


def run_output_family(work: Path, template: Path, timeout: float = 120.0,
                      options: list[str] | None = None, forms: list[str] | None = None,
                      rng: np.random.Generator | None = None, cases: int | None = None,
                      ) -> tuple[Counter, list[tuple]]:
    """Every output option x every output form (or `cases` of them drawn by `rng`)."""
    all_cases = [(name, form, out) for name in options or list(OUTPUT_OPTIONS)
                 for form, out in output_forms() if forms is None or form in forms]
    if cases is not None and rng is not None and cases < len(all_cases):
        all_cases = [all_cases[i] for i in sorted(rng.choice(len(all_cases), cases, False))]
    done: dict[str, list[float]] = {}
    results: list[tuple[str, str, Outcome, str]] = []
    for name, form, out in all_cases:
        argv, option, kind = OUTPUT_OPTIONS[name]
        proj = _fresh(work, template)
        (proj / "results" / "empty").mkdir()
        o = run_in(proj, [*argv, option, out], out.rstrip("/"), timeout, OTHER_OUTPUT.get(name))
        if o.rc in (0, 1) and not o.exc:
            done.setdefault(name, []).append(o.seconds)
        results.append((name, form, o, out))
    counts: Counter = Counter()
    bad: list[tuple] = []
    for name, form, o, out in results:
        # A refusal that took as long as half a full run came after the work.
        limit = max(1.0, 0.5 * float(np.median(done[name]))) if name in done else float("inf")
        outcome = classify_output(o, out, OUTPUT_OPTIONS[name][2], limit)
        counts[outcome] += 1
        if outcome not in ("written", "refused (one line)"):
            bad.append((f"{name} {form}", outcome, f"{o.exc} {o.stderr.strip()[-300:]}"))
    return counts, bad


#: Commands run twice into their own output: name -> (argv, the output).
TWICE: dict[str, tuple[list[str], str]] = {
    "localize --out": (["localize", "--example", "--out", "results/a"], "results/a"),
    "localize --json": (["localize", "--example", "--json", "results/a.json"], "results/a.json"),
    "fleet --out": (["fleet", "maps/query.json", "maps/target.json", "--workers", "0",
                     "--out", "results/a"], "results/a"),
    "replay --out": (["replay", "layout", "--quiet", "--out", "results/a"], "results/a"),
    "demo --out (default)": (["demo", "--objects-only"], "results/demo/aligned_maps.png"),
    "experiment --out": (["experiment", "table", "--dataset", "synthetic", "--trials", "1",
                          "--workers", "1", "--out", "results/a"], "results/a"),
    **{f"demo --out .{e}": (["demo", "--objects-only", "--out", f"results/a.{e}"],
                            f"results/a.{e}") for e in ("png", "pdf", "svg", "jpg")},
    "demo --out folder/": (["demo", "--objects-only", "--out", "results/d/"], "results/d"),
    **{f"build-graph -o .{e}": (["build-graph", "airsim", "robot", "-q", "-o", f"results/a.{e}"],
                                f"results/a.{e}") for e in ("json", "pcd", "npz", "ply", "csv")},
}  # fmt: skip
FALSE_NOT_OURS = ("not written by sgloc", "sgloc did not write")


def classify_twice(first: Outcome, second: Outcome, same: bool) -> str:
    """The outcome of a second run into the first's output (`same`: the output holds the same
    entries after it)."""
    bad = _broken(first) or _broken(second)
    if bad:
        return bad
    if first.rc not in (0, 1):
        return "first run refused" if first.rc == 2 else "wrong exit code"
    if second.rc == 2:
        if any(s in second.stderr for s in FALSE_NOT_OURS):
            return "false 'not written by sgloc'"
        return "refused clearly" if not second.new else "refused but something written"
    return "replaced" if same else "replaced, different entries"


def run_twice_family(work: Path, template: Path, timeout: float = 120.0,
                     names: list[str] | None = None) -> tuple[Counter, list[tuple]]:
    """Every command twice into its own output."""
    counts: Counter = Counter()
    bad: list[tuple] = []
    for name in names or list(TWICE):
        argv, out = TWICE[name]
        proj = _fresh(work, template)
        first = run_in(proj, argv, out, timeout)
        entries = _entries(proj / out)
        second = run_in(proj, argv, out, timeout)
        outcome = classify_twice(first, second, _entries(proj / out) == entries)
        counts[outcome] += 1
        if outcome not in ("replaced", "refused clearly"):
            bad.append((name, outcome, f"{first.exc}{second.exc} {second.stderr.strip()[-300:]}"))
    return counts, bad


#: Inputs of one layout given to a command that reads another: (name, argv, expect), expect
#: "fail" (must be one clear error) or "either" (a valid input of that command too).
LAYOUTS: list[tuple[str, list[str], str]] = [
    ("replay run folder as a map", ["localize", "layout", "maps/target.json"], "fail"),
    ("robot folder of a run as a map", ["localize", "layout/world0", "maps/target.json"], "fail"),
    ("keyframe table (objects.csv) as maps",
     ["localize", "layout/world0/objects.csv", "layout/world1/objects.csv"], "fail"),
    ("keyframe tables with --set scale=auto", ["localize", "layout/world0/objects.csv",
                                               "layout/world1/objects.csv", "--set",
                                               "scale=auto"], "fail"),
    ("odometry.tum as a map", ["localize", "layout/world0/odometry.tum", "maps/target.json"],
     "fail"),
    ("classes.txt as a map", ["localize", "layout/classes.txt", "maps/target.json"], "fail"),
    ("replay results folder as a map", ["localize", "made/replay", "maps/target.json"], "fail"),
    ("replay events.csv as a map", ["localize", "made/replay/events.csv", "maps/target.json"],
     "fail"),
    ("replay g2o_keyframes.csv as a map",
     ["localize", "made/replay/g2o_keyframes.csv", "maps/target.json"], "fail"),
    ("replay summary.json as a map", ["localize", "made/replay/summary.json", "maps/target.json"],
     "fail"),
    ("replay fleet trajectory as a map",
     ["localize", "made/replay/fleet/world0.tum", "maps/target.json"], "fail"),
    ("replay's robot map as a map",
     ["localize", "made/replay/maps/world0.json", "maps/target.json"], "either"),
    ("fleet results folder as a map", ["localize", "made/fleet", "maps/target.json"], "fail"),
    ("fleet.json as a map", ["localize", "made/fleet/fleet.json", "maps/target.json"], "fail"),
    ("fleet merged.json as a map", ["localize", "made/fleet/merged.json", "maps/target.json"],
     "either"),
    ("fleet poses.tum as a map", ["localize", "made/fleet/poses.tum", "maps/target.json"], "fail"),
    ("fleet links.g2o as a map", ["localize", "made/fleet/links.g2o", "maps/target.json"], "fail"),
    ("localize result.json as a map", ["localize", "made/result.json", "maps/target.json"],
     "fail"),
    ("T_target_query.txt as a map",
     ["localize", "made/localize/T_target_query.txt", "maps/target.json"], "fail"),
    ("config.yaml as a map", ["localize", "made/localize/config.yaml", "maps/target.json"],
     "fail"),
    ("experiment trials.csv as a map",
     ["localize", "made/experiment/trials.csv", "maps/target.json"], "fail"),
    ("session file as a map", ["localize", "made/session.npz", "maps/target.json"], "fail"),
    ("rosbag2 folder as a map", ["localize", "made/bag", "maps/target.json"], "fail"),
    ("mcap bag as a map", ["localize", "made/run.mcap", "maps/target.json"], "fail"),
    ("airsim robot folder as a map", ["localize", "robot", "maps/target.json"], "fail"),
    ("a picture as a map", ["localize", "made/localize/aligned_maps.png", "maps/target.json"],
     "fail"),
    ("graph json to replay", ["replay", "maps/query.json", "--out", "results/r", "--quiet"],
     "fail"),
    ("graph table to replay", ["replay", "maps/query.csv", "--out", "results/r", "--quiet"],
     "fail"),
    ("folder of graphs to replay", ["replay", "maps", "--out", "results/r", "--quiet"], "fail"),
    ("replay results folder to replay", ["replay", "made/replay", "--out", "results/r",
                                         "--quiet"], "fail"),
    ("fleet results folder to replay", ["replay", "made/fleet", "--out", "results/r", "--quiet"],
     "fail"),
    ("odometry.tum to replay", ["replay", "layout/world0/odometry.tum", "--out", "results/r",
                                "--quiet"], "fail"),
    ("objects.csv to replay", ["replay", "layout/world0/objects.csv", "--out", "results/r",
                               "--quiet"], "fail"),
    ("airsim robot folder to replay", ["replay", "robot", "--out", "results/r", "--quiet"],
     "fail"),
    ("session file to replay", ["replay", "made/session.npz", "--out", "results/r", "--quiet"],
     "fail"),
    ("one robot folder to replay", ["replay", "layout/world0", "--out", "results/r", "--quiet"],
     "either"),
    ("keyframe tables to fleet", ["fleet", "layout/world0/objects.csv",
                                  "layout/world1/objects.csv", "--workers", "0", "--out",
                                  "results/f"], "fail"),
    ("replay run folders to fleet", ["fleet", "layout/world0", "layout/world1", "--workers", "0",
                                     "--out", "results/f"], "fail"),
    ("results files to fleet", ["fleet", "made/result.json", "made/fleet/fleet.json",
                                "--workers", "0", "--out", "results/f"], "fail"),
    ("bag to fleet", ["fleet", "made/run.mcap", "maps/target.json", "--workers", "0", "--out",
                      "results/f"], "fail"),
    ("replay run folder to build-graph", ["build-graph", "airsim", "layout", "-o",
                                          "results/g.json", "-q"], "fail"),
    ("folder of graphs to build-graph", ["build-graph", "airsim", "maps", "-o", "results/g.json",
                                         "-q"], "fail"),
    ("airsim robot as kitti", ["build-graph", "kitti", "robot", "-o", "results/g.json", "-q"],
     "fail"),
    ("airsim robot as synthia", ["build-graph", "synthia", "robot", "-o", "results/g.json", "-q"],
     "fail"),
    ("replay results to build-graph", ["build-graph", "airsim", "made/replay", "-o",
                                       "results/g.json", "-q"], "fail"),
    ("replay run folder as an experiment data set",
     ["experiment", "table", "--dataset", "layout", "--trials", "1", "--workers", "1", "--out",
      "results/e"], "fail"),
    ("a graph table as trials.csv", ["experiment", "table", "--from-csv", "maps/query.csv",
                                     "--out", "results/e"], "fail"),
    ("replay events.csv as trials.csv", ["experiment", "table", "--from-csv",
                                         "made/replay/events.csv", "--out", "results/e"], "fail"),
    ("a graph as settings", ["localize", "--example", "--config", "maps/query.json"], "fail"),
    ("result.json as settings", ["localize", "--example", "--config", "made/result.json"],
     "fail"),
    ("summary.json as settings", ["replay", "layout", "--config", "made/replay/summary.json",
                                  "--out", "results/r", "--quiet"], "fail"),
    ("a graph as a colour table", ["localize", "--example", "--colour-table", "maps/query.json"],
     "fail"),
    ("a graph as a class table", ["replay", "layout", "--classes", "maps/query.csv", "--out",
                                  "results/r", "--quiet"], "fail"),
    ("a session file to serve as state", ["serve", "--state", "made/result.json", "--seconds",
                                          "0.5", "--quiet"], "fail"),
    ("a graph to stream", ["stream", "maps/query.json", "--rate", "0", "--quiet"], "fail"),
]  # fmt: skip


def classify_layout(o: Outcome, expect: str) -> str:
    bad = _broken(o)
    if bad:
        return bad
    if o.rc == 2:
        return "clean error, exit 2"
    return "malformed file read as data" if expect == "fail" else "read as data"


def run_layout_family(work: Path, template: Path, timeout: float = 120.0,
                      names: list[str] | None = None) -> tuple[Counter, list[tuple]]:
    """Every cross-layout input."""
    counts: Counter = Counter()
    bad: list[tuple] = []
    for name, argv, expect in LAYOUTS:
        if names is not None and name not in names:
            continue
        proj = _fresh(work, template)
        out = next((argv[i + 1] for i, a in enumerate(argv[:-1]) if a in ("--out", "-o")), None)
        o = run_in(proj, argv, out, timeout)
        outcome = classify_layout(o, expect)
        counts[outcome] += 1
        if outcome not in ("clean error, exit 2", "read as data"):
            bad.append((name, outcome, f"exit {o.rc} {o.exc} {o.stderr.strip()[-300:]}"))
    return counts, bad


# -- the run: every family, its tables -------------------------------------------------------------
FAMILY_NAMES = ("signal", "outputs", "twice", "layouts")
#: Bad outcomes counted in the summary, by the words in their names.
SUMMARY = {"tracebacks": ("traceback",), "lost signals": ("lost signal",),
           "user files moved or changed": ("user files moved or changed",), "hangs": ("hang",)}


def run_command_families(trials: int = 100, seed: int = 0, timeout: float = 120.0,
                         families: tuple[str, ...] = FAMILY_NAMES, progress: bool = False,
                         output_cases: int | None = None,
                         signal_commands: list[str] | None = None) -> dict:
    """Run the chosen families in a fresh user's folder; {"signal": {command: Counter},
    "outputs" | "twice" | "layouts": Counter, "bad": [(family, case, outcome, detail)],
    "seconds": {family: s}}. `trials` signalled runs per command; `output_cases` (None: all)
    output cases drawn from every option x form."""
    import matplotlib

    matplotlib.use("Agg")
    report: dict = {"bad": [], "seconds": {}}
    with tempfile.TemporaryDirectory(prefix="sgloc-fuzz-commands-") as tmp:
        work = Path(tmp)
        template = make_template(work, seed)
        for family in families:
            t0 = time.perf_counter()
            if family == "signal":
                counts, bad = run_signal_family(work, template, trials, seed, timeout,
                                                signal_commands, progress=progress)
            elif family == "outputs":
                counts, bad = run_output_family(work, template, timeout, cases=output_cases,
                                                rng=np.random.default_rng([seed, 38]))
            elif family == "twice":
                counts, bad = run_twice_family(work, template, timeout)
            else:
                counts, bad = run_layout_family(work, template, timeout)
            report[family] = counts
            report["bad"] += [(family, *b) for b in bad]
            report["seconds"][family] = time.perf_counter() - t0
            if progress:
                print(f"  {family}: {report['seconds'][family]:.0f} s", file=sys.stderr)
    return report


def summary_counts(report: dict) -> Counter:
    """Tracebacks, lost signals, user files moved or changed and hangs over every family."""
    total: Counter = Counter()
    for family in FAMILY_NAMES:
        counts = report.get(family)
        if counts is None:
            continue
        merged = sum(counts.values(), Counter()) if family == "signal" else counts
        for label, names in SUMMARY.items():
            total[label] += sum(merged.get(n, 0) for n in names)
    return total


def signal_table(per_command: dict[str, Counter]) -> str:
    cols = [*SIGNAL_GOOD, *SIGNAL_RESIDUAL, *SIGNAL_BAD]
    rows = ["| command | trials | " + " | ".join(cols) + " |", "|---" * (len(cols) + 2) + "|"]
    for name, c in per_command.items():
        rows.append(f"| `{name}` | {sum(c.values())} | "
                    + " | ".join(str(c.get(k, 0)) for k in cols) + " |")
    return "\n".join(rows)


def outcome_table(counts: Counter, head: str) -> str:
    rows = [f"| {head} | cases |", "|---|---|"]
    rows += [f"| {k} | {v} |" for k, v in sorted(counts.items(), key=lambda kv: -kv[1])]
    return "\n".join(rows)


def report_text(report: dict, command: str) -> str:
    """The Markdown block of docs/robustness.md for a run of `command`."""
    seconds = sum(report["seconds"].values())
    total = summary_counts(report)
    parts = [f"`{command}` ({seconds / 60:.0f} min):", "",
             "Over every family: " + ", ".join(f"{v} {k}" for k, v in total.items()) + "."]
    titles = {"outputs": ("Every output option with every extension and a folder", "outcome"),
              "twice": ("Every command run twice into its own output", "second run"),
              "layouts": ("Inputs of one layout given to a command that reads another",
                          "outcome")}
    if "signal" in report:
        parts += ["", "A signal at a random moment of every command:", "",
                  signal_table(report["signal"])]
    for family, (title, head) in titles.items():
        if family in report:
            parts += ["", f"{title}:", "", outcome_table(report[family], head)]
    return "\n".join(parts)


def write_doc_block(text: str) -> Path:
    """Put `text` between the commands-table markers of docs/robustness.md."""
    doc = HERE.parent / "docs" / "robustness.md"
    body = doc.read_text()
    begin, end = "<!-- fuzz-commands:begin -->", "<!-- fuzz-commands:end -->"
    block = f"{begin}\n{text}\n{end}"
    if begin in body and end in body:
        body = body[: body.index(begin)] + block + body[body.index(end) + len(end):]
    else:
        body = body.rstrip() + "\n\n" + block + "\n"
    doc.write_text(body)
    return doc


def print_report(report: dict, command: str) -> int:
    """Print the tables and the bad cases; 1 if any."""
    print(report_text(report, command))
    for family, name, outcome, detail in report["bad"][:40]:
        print(f"BAD {family} {outcome}: {name}: {detail}")
    return 1 if report["bad"] else 0


def main() -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(ap)
    ap.add_argument("--update-docs", action="store_true", help="write docs/robustness.md's table")
    args = ap.parse_args()
    report = run_from_args(args)
    command = " ".join(["python benchmarks/fuzz_commands.py",
                        *[a for a in sys.argv[1:] if a != "--update-docs"]])
    rc = print_report(report, command)
    if args.update_docs:
        print(f"wrote {write_doc_block(report_text(report, command))}")
    return rc


def add_arguments(ap, seed: bool = True) -> None:
    """The command families' options (also benchmarks/fuzz.py's, which has its own --seed)."""
    ap.add_argument("--signal-trials", type=int, default=100,
                    help="signalled runs per command (family signal)")
    ap.add_argument("--output-cases", type=int, default=None,
                    help="output option x form cases (default: every one)")
    ap.add_argument("--command-family", action="append", choices=FAMILY_NAMES, metavar="NAME",
                    help="run only this command family (repeatable): " + ", ".join(FAMILY_NAMES))
    ap.add_argument("--signal-command", action="append", choices=list(SIGNAL_COMMANDS),
                    metavar="NAME", help="family signal: only this command (repeatable): "
                    + ", ".join(SIGNAL_COMMANDS))
    ap.add_argument("--command-timeout", type=float, default=120.0,
                    help="seconds before a command's run is a hang")
    if seed:
        ap.add_argument("--seed", type=int, default=0)


def run_from_args(args) -> dict:
    families = tuple(args.command_family or FAMILY_NAMES)
    return run_command_families(args.signal_trials, args.seed, args.command_timeout, families,
                                progress=True, output_cases=args.output_cases,
                                signal_commands=args.signal_command)


if __name__ == "__main__":
    sys.exit(main())
