"""Mutation fuzzing of everything a user feeds the command line.

    python benchmarks/fuzz.py [--cases 5000] [--seed 0] [--update-docs]

Valid seed files (graphs in ascii/binary/binary_compressed PCD, JSON and NPZ from a synthetic
two-robot scene; a tiny Airsim-layout robot folder) are mutated: truncations, byte flips, header
edits, NaN / inf / 1e308 / oversized values, wrong types, FIFOs, folders. Each case runs
`sgloc localize`, `fleet` or `build-graph` in this process (`sgloc.cli.main`) under a time limit,
and its outcome is classed. A case whose mutation certainly breaks the file is "must fail"; one
that may leave a valid file (a flipped digit) is "either"; one that only changes values within
the allowed ranges is "valid". Bad outcomes: a traceback, a MemoryError, a hang, an error not
printed as one line with exit 2, a must-fail file read as data, a valid file refused.
Prints the count of every outcome class; with --update-docs writes docs/robustness.md's table.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import signal
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

BAD_OUTCOMES = (
    "traceback",
    "memory error",
    "hang",
    "error not one line / wrong exit code",
    "malformed file read as data",
    "valid file refused",
    "user files moved or changed",
)


class CaseTimeout(Exception):
    """A case ran past its time limit (a hang)."""


@dataclass
class Case:
    """One fuzz case: a command line over the files of `folder`, and what the input is."""

    name: str
    expect: str  # "fail" | "either" | "valid"
    argv: list[str]
    cwd: Path | None = None  # the working folder the command runs in (default: unchanged)
    around: Callable[[], contextlib.AbstractContextManager] | None = None  # e.g. a service
    check: Callable[[], str] | None = None  # after the run: "" or a bad outcome


# -- seed files ---------------------------------------------------------------------------------
def write_seeds(folder: Path, seed: int = 0) -> dict[str, Path]:
    """Valid files to mutate: graphs in every format, plus a tiny Airsim robot folder."""
    from PIL import Image

    from sgloc.classes import AIRSIM_COLORS
    from sgloc.io.pcd import write_pcd
    from sgloc.sim.object_world import make_two_robot_scene

    scene = make_two_robot_scene(seed=seed, stretch=150)
    q, t = scene.query, scene.target
    files = {
        "target.json": folder / "target.json",
        "query.pcd": folder / "query.pcd",
        "query_bin.pcd": folder / "query_bin.pcd",
        "query_cmp.pcd": folder / "query_cmp.pcd",
        "query.json": folder / "query.json",
        "query.npz": folder / "query.npz",
    }
    t.save(files["target.json"])
    write_pcd(files["query.pcd"], q.positions, q.labels)
    write_pcd(files["query_bin.pcd"], q.positions, q.labels, data="binary")
    write_pcd(files["query_cmp.pcd"], q.positions, q.labels, data="binary_compressed")
    q.save(files["query.json"])
    np.savez(files["query.npz"], positions=q.positions, labels=q.labels)
    robot = folder / "robot"
    (robot / "depth").mkdir(parents=True, exist_ok=True)
    (robot / "segmentation").mkdir(exist_ok=True)
    (robot / "airsim.txt").write_text("2\n0 0 0 1 0 0 0\n1 0 0 1 0 0 0\n")
    (robot / "intrinsics.txt").write_text("32 32 32 18 64 36\n")
    for i in range(2):
        seg = np.zeros((36, 64, 3), np.uint8)
        seg[10:26, 20:44] = AIRSIM_COLORS[5]
        dep = np.full((36, 64), 255, np.uint8)
        dep[10:26, 20:44] = 20
        Image.fromarray(seg).save(robot / "segmentation" / f"segmentation_{i}.png")
        Image.fromarray(dep).save(robot / "depth" / f"depth_{i}.png")
    files["robot"] = robot
    return files


# -- mutations ----------------------------------------------------------------------------------
Mutation = Callable[[bytes, np.random.Generator], tuple[bytes, str]]
BAD_NUMBERS = ["nan", "NaN", "inf", "-inf", "1e308", "-1e308", "1e200", "1e20", "abc", "0x1F", ""]


def truncate(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """Cut the file so that at least one non-blank byte is lost (always malformed)."""
    body = raw.rstrip()
    cut = int(rng.integers(0, len(body)))
    return raw[:cut], "fail"


def flip_bytes(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    out = bytearray(raw)
    for _ in range(int(rng.integers(1, 4))):
        out[int(rng.integers(0, len(out)))] = int(rng.integers(0, 256))
    return bytes(out), "either"


def append_bytes(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    extra = raw[-int(rng.integers(1, 40)) :]
    return raw + extra, "fail" if extra.strip() else "either"


def _pcd_parts(raw: bytes) -> tuple[list[str], bytes]:
    end = raw.index(b"DATA")
    end = raw.index(b"\n", end) + 1
    return raw[:end].decode().splitlines(), raw[end:]


def pcd_header_edit(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """A header line made inconsistent with the others or with the data."""
    lines, data = _pcd_parts(raw)
    n = int(next(ln.split()[1] for ln in lines if ln.startswith("POINTS")))
    edits = [
        ("POINTS", f"POINTS {n + int(rng.integers(1, 5))}"),
        ("POINTS", f"POINTS {max(n - int(rng.integers(1, 5)), 0)}"),
        ("POINTS", "POINTS -1"),
        ("POINTS", "POINTS abc"),
        ("WIDTH", f"WIDTH {n + 1}"),
        ("HEIGHT", "HEIGHT 2"),
        ("TYPE", "TYPE F F F U"),
        ("SIZE", "SIZE 4 4 4"),
        ("COUNT", "COUNT 1 1 1 1 1 1"),
        ("COUNT", "COUNT 2 1 1 1 1"),
        ("SIZE", "SIZE 4 4 3 4 4"),
        ("TYPE", "TYPE F F F Q U"),
        ("VERSION", "VERSION 9.1"),
        ("FIELDS", "FIELDS x y z rgb label extra"),
        ("FIELDS", "FIELDS x y y rgb label"),
        ("FIELDS", "FIELDS a b c rgb label"),
        ("DATA", "DATA binary_lz4"),
        ("POINTS", f"POINTS {n}\nPOINTS {n}"),
        ("WIDTH", f"WIDTH {n}\nWIDTH {n}"),
        ("VIEWPOINT", "VIEWPOINT 0 0 0"),
        ("VIEWPOINT", "COLOR 1 2 3"),
    ]
    key, new = edits[int(rng.integers(0, len(edits)))]
    out = [new if ln.split()[:1] == [key] else ln for ln in lines]
    if key == "DATA" or new.startswith("FIELDS a"):  # must not look valid by accident
        pass
    return ("\n".join(out) + "\n").encode() + data, "fail"


def _ascii_rows(raw: bytes) -> tuple[list[str], list[list[str]]]:
    lines, data = _pcd_parts(raw)
    return lines, [r.split() for r in data.decode().splitlines() if r.strip()]


def _join_pcd(lines: list[str], rows: list[list[str]]) -> bytes:
    return ("\n".join(lines) + "\n" + "".join(" ".join(r) + "\n" for r in rows)).encode()


def pcd_value(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """A coordinate or label token replaced by a bad number, a fraction or a wrong type."""
    lines, rows = _ascii_rows(raw)
    r = int(rng.integers(0, len(rows)))
    col = int(rng.integers(0, 5))
    if col < 3:
        rows[r][col] = str(rng.choice(BAD_NUMBERS))
    elif col == 3:
        rows[r][col] = str(rng.choice(["-1", "2.5", "99999999999", "abc", "nan"]))
    else:
        rows[r][col] = str(rng.choice(["-1", "2.5", "4294967296", "x", "1e30", "nan"]))
    if rows[r][col] == "":
        rows[r].pop(col)
    return _join_pcd(lines, rows), "fail"


def pcd_rows(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """A row added, dropped, shortened or lengthened without updating the header."""
    lines, rows = _ascii_rows(raw)
    r = int(rng.integers(0, len(rows)))
    kind = int(rng.integers(0, 4))
    if kind == 0:
        rows.insert(r, list(rows[r]))
    elif kind == 1:
        rows.pop(r)
    elif kind == 2:
        rows[r] = rows[r][:-1]
    else:
        rows[r] = rows[r] + ["0"]
    return _join_pcd(lines, rows), "fail"


def pcd_valid_edit(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """Values changed within the allowed ranges: a large class id, a moved object."""
    lines, rows = _ascii_rows(raw)
    r = int(rng.integers(0, len(rows)))
    if rng.random() < 0.5:
        rows[r][4] = str(int(rng.choice([1000, 65535, 2**31 - 1])))
    else:
        rows[r][0] = f"{float(rows[r][0]) + rng.normal(0, 3):.6f}"
    return _join_pcd(lines, rows), "valid"


def _json_edit(raw: bytes, rng: np.random.Generator, valid: bool) -> tuple[bytes, str]:
    data = json.loads(raw)
    n = len(data["labels"])
    i = int(rng.integers(0, n))
    if valid:
        data["labels"][i] = int(rng.choice([1000, 2**31 - 1, 0]))
        return json.dumps(data).encode(), "valid"
    text_edits = [
        ("label", "true"), ("label", '"7"'), ("label", "1.5"), ("label", "-1"), ("label", "null"),
        ("label", "1" + "0" * 400), ("label", "[1]"), ("label", "2147483648"),
        ("pos", "NaN"), ("pos", "Infinity"), ("pos", "1e400"), ("pos", "1e308"), ("pos", '"3"'),
        ("pos", "true"), ("pos", "null"), ("pos", "1" + "0" * 400), ("pos", "[]"),
    ]  # fmt: skip
    where, token = text_edits[int(rng.integers(0, len(text_edits)))]
    marker = "__MARK__"
    if where == "label":
        data["labels"][i] = marker
    else:
        data["positions"][i][int(rng.integers(0, 3))] = marker
    return json.dumps(data).replace(f'"{marker}"', token).encode(), "fail"


def json_value(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    return _json_edit(raw, rng, valid=False)


def json_valid_edit(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    return _json_edit(raw, rng, valid=True)


def json_structure(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    data = json.loads(raw)
    kind = int(rng.integers(0, 7))
    if kind == 6:  # a key given twice
        text = json.dumps(data)
        return text[:-1].encode() + b', "labels": ' + json.dumps(
            data["labels"]
        ).encode() + b"}", "fail"
    if kind == 0:
        depth = int(rng.choice([50, 5000, 200000]))
        return ("[" * depth + json.dumps(data) + "]" * depth).encode(), "fail"
    if kind == 1:
        data["positions"][0] = data["positions"][0][:2]
    elif kind == 2:
        data["labels"] = data["labels"][:-1]
    elif kind == 3:
        del data["labels"]
    elif kind == 4:
        data = [data]
    else:
        data["positions"] = {"x": 1}
    return json.dumps(data).encode(), "fail"


def _npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def npz_arrays(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    with np.load(io.BytesIO(raw)) as z:
        pos, lab = z["positions"], z["labels"]
    kind = int(rng.integers(0, 11))
    if kind == 0:
        return _npz_bytes(positions=pos, labels=lab.astype(bool)), "fail"
    if kind == 1:
        return _npz_bytes(positions=pos.astype(complex), labels=lab), "fail"
    if kind == 2:
        return _npz_bytes(positions=pos.astype(str), labels=lab), "fail"
    if kind == 3:
        return _npz_bytes(positions=pos.astype("datetime64[s]"), labels=lab), "fail"
    if kind == 4:
        return _npz_bytes(positions=pos.T.copy(), labels=lab), "fail"
    if kind == 5:
        return _npz_bytes(positions=pos), "fail"
    if kind == 6:
        bad = pos.copy()
        bad[int(rng.integers(0, len(bad))), int(rng.integers(0, 3))] = rng.choice(
            [np.nan, np.inf, 1e308, 1e200]
        )
        return _npz_bytes(positions=bad, labels=lab), "fail"
    if kind == 7:
        buf = io.BytesIO()
        np.save(buf, pos)
        return buf.getvalue(), "fail"  # a .npy renamed .npz
    if kind == 8:
        return _npz_bytes(positions=pos, labels=lab.astype(float) + 0.5), "fail"
    if kind == 9:
        return _npz_bytes(positions=pos, labels=np.append(lab, 1)), "fail"
    big = lab.copy()
    big[0] = 2**31 - 1
    return _npz_bytes(positions=pos, labels=big), "valid"


MUTATIONS: dict[str, list[tuple[str, Mutation]]] = {
    "query.pcd": [
        ("truncate", truncate), ("flip", flip_bytes), ("append", append_bytes),
        ("header", pcd_header_edit), ("value", pcd_value), ("rows", pcd_rows),
        ("valid", pcd_valid_edit),
    ],
    "query_bin.pcd": [
        ("truncate", truncate), ("flip", flip_bytes), ("append", append_bytes),
        ("header", pcd_header_edit),
    ],
    "query_cmp.pcd": [
        ("truncate", truncate), ("flip", flip_bytes), ("append", append_bytes),
        ("header", pcd_header_edit),
    ],
    "query.json": [
        ("truncate", truncate), ("flip", flip_bytes), ("value", json_value),
        ("structure", json_structure), ("valid", json_valid_edit),
    ],
    "query.npz": [
        ("truncate", truncate), ("flip", flip_bytes), ("append", append_bytes),
        ("arrays", npz_arrays),
    ],
}  # fmt: skip


def airsim_edit(robot: Path, rng: np.random.Generator) -> tuple[str, str]:
    """Damage one file of the Airsim robot folder in place; return (what, expect)."""
    kind = int(rng.integers(0, 9))
    poses, intr = robot / "airsim.txt", robot / "intrinsics.txt"
    png = robot / ("depth" if rng.random() < 0.5 else "segmentation")
    png = sorted(png.iterdir())[int(rng.integers(0, 2))]
    if kind == 0:
        poses.write_text("2\n0 0 0 1 0 0 0\n1 0 " + str(rng.choice(BAD_NUMBERS[:8])) + " 1 0 0 0\n")
        return "poses value", "fail"
    if kind == 1:
        poses.write_text("5\n0 0 0 1 0 0 0\n1 0 0 1 0 0 0\n")
        return "poses count", "fail"
    if kind == 2:
        poses.write_bytes(poses.read_bytes()[: int(rng.integers(0, 20))])
        return "poses truncate", "fail"
    if kind == 3:
        intr.write_text(str(rng.choice(["-32 32 32 18 64 36", "nan 32 32 18 64 36", "32 32"])))
        return "intrinsics value", "fail"
    if kind == 4:
        raw = png.read_bytes()
        png.write_bytes(raw[: int(rng.integers(0, len(raw) - 13))])  # keep no IEND chunk
        return "png truncate", "fail"
    if kind == 5:
        png.write_bytes(flip_bytes(png.read_bytes(), rng)[0])
        return "png flip", "either"
    if kind == 6:
        png.write_text("not an image")
        return "png text", "fail"
    if kind == 7:
        png.unlink()
        os.mkfifo(png)
        return "png fifo", "fail"
    poses.unlink()
    poses.mkdir()
    return "poses folder", "fail"


# -- running a case -----------------------------------------------------------------------------
def run_case(argv: list[str], timeout: float) -> tuple[int | None, str, str, str]:
    """(exit code or None, stdout, stderr, exception class or '') of `sgloc argv` in-process."""
    from sgloc.cli import main

    out, err = io.StringIO(), io.StringIO()

    def on_alarm(signum, frame):
        raise CaseTimeout

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main(argv)
        return rc, out.getvalue(), err.getvalue(), ""
    except CaseTimeout:
        return None, out.getvalue(), err.getvalue(), "hang"
    except MemoryError:
        return None, out.getvalue(), err.getvalue(), "MemoryError"
    except BaseException as e:  # noqa: BLE001 - classifying every escape is the point
        return None, out.getvalue(), err.getvalue(), type(e).__name__
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


_USAGE = re.compile(r"^Usage: sgloc")


def classify(expect: str, rc: int | None, stderr: str, exc: str) -> str:
    """The outcome class of one case."""
    if exc == "hang":
        return "hang"
    if exc == "MemoryError":
        return "memory error"
    if exc:
        return "traceback"
    lines = [ln for ln in stderr.strip().splitlines() if ln.strip()]
    if rc == 2:
        if lines and _USAGE.match(lines[0]):
            lines = lines[1:]
        if len(lines) != 1 or not lines[0].startswith("error: "):
            return "error not one line / wrong exit code"
        return "valid file refused" if expect == "valid" else "clean error, exit 2"
    if rc in (0, 1):
        if expect == "fail":
            return "malformed file read as data"
        return (
            "read as data: localized, exit 0" if rc == 0 else "read as data: not localized, exit 1"
        )
    return "error not one line / wrong exit code"


def make_case(seeds: dict[str, Path], work: Path, rng: np.random.Generator, k: int) -> Case:
    """Case k: mutate one seed (or make a FIFO / folder / missing file) and build its argv."""
    case_dir = work / f"case{k}"
    case_dir.mkdir()
    command = str(rng.choice(["localize"] * 8 + ["fleet"] + ["build-graph"]))
    if command == "build-graph":
        import shutil

        robot = case_dir / "robot"
        shutil.copytree(seeds["robot"], robot)
        what, expect = airsim_edit(robot, rng)
        out = case_dir / "g.json"
        return Case(
            f"build-graph {what}",
            expect,
            ["build-graph", "airsim", str(robot), "-o", str(out), "-q"],
        )
    roll = rng.random()
    if roll < 0.08:
        return option_case(seeds, case_dir, rng, command)
    if roll < 0.12:
        path = case_dir / str(rng.choice(["pipe.pcd", "pipe.json", "pipe.npz"]))
        os.mkfifo(path)
        name, expect = "fifo", "fail"
    elif roll < 0.15:
        path = case_dir / str(rng.choice(["dir.pcd", "dir.json", "dir.npz"]))
        path.mkdir()
        name, expect = "folder", "fail"
    elif roll < 0.17:
        path = case_dir / str(rng.choice(["empty.pcd", "empty.json", "empty.npz", "g.ply"]))
        path.write_bytes(b"")
        name, expect = "empty", "fail"
    else:
        source = str(rng.choice(list(MUTATIONS)))
        mutation, fn = MUTATIONS[source][int(rng.integers(0, len(MUTATIONS[source])))]
        raw, expect = fn(seeds[source].read_bytes(), rng)
        path = case_dir / source
        path.write_bytes(raw)
        name = f"{source} {mutation}"
    target = str(seeds["target.json"])
    if command == "fleet":
        argv = ["fleet", str(path), target, "--workers", "1", "--out", str(case_dir / "out")]
    else:
        argv = (
            ["localize", str(path), target]
            if rng.random() < 0.5
            else ["localize", target, str(path)]
        )
    return Case(f"{command} {name}", expect, argv)


BAD_OPTIONS = {
    "localize": [
        ("--ransac-threshold", "nan"), ("--ransac-threshold", "-5"), ("--ransac-threshold", "inf"),
        ("--ransac-threshold", "abc"), ("--edge-radius", "0"), ("--edge-radius", "-1e308"),
        ("--seed", "-1"), ("--seed", "1.5"), ("--descriptor", "nope"), ("--rejection", "nope"),
        ("--bogus", "1"),
    ],
    "fleet": [
        ("--min-confidence", "1.5"), ("--min-confidence", "nan"), ("--edge-radius", "inf"),
        ("--seed", "-3"), ("--workers", "two"), ("--scheduler", "nonsense"), ("--bogus", "1"),
    ],
}  # fmt: skip
GOOD_OPTIONS = {
    "localize": [
        ("--ransac-threshold", "3"), ("--descriptor", "random_walk"), ("--rejection", "none"),
        ("--descriptor", "fast"), ("--edge-radius", "25"), ("--seed", "7"),
    ],
    "fleet": [("--min-confidence", "0.5"), ("--seed", "2")],
}  # fmt: skip


def option_case(seeds: dict[str, Path], case_dir: Path, rng: np.random.Generator, command: str):
    """Valid files with one bad (or one valid) option value."""
    query, target = str(seeds["query.json"]), str(seeds["target.json"])
    valid = rng.random() < 0.3
    options = (GOOD_OPTIONS if valid else BAD_OPTIONS)[command]
    option, value = options[int(rng.integers(0, len(options)))]
    argv = [command, query, target]
    if command == "fleet":
        argv += ["--workers", "1", "--out", str(case_dir / "out")]
    argv += [option, value]  # last, so that it wins over the defaults above
    return Case(f"{command} option {option} {value}", "valid" if valid else "fail", argv)


# -- output paths: --out at the working folder, an input's folder, an input ----------------------
#: (name, output path inside the user's folder proj/ ({proj}: its absolute path), expectation).
OUT_TARGETS = [
    ("working-folder", ".", "fail"), ("working-folder-absolute", "{proj}", "fail"),
    ("working-folder-by-parent", "../proj", "fail"), ("parent-of-working-folder", "..", "fail"),
    ("input-folder", "maps", "fail"), ("input-file", "maps/query.json", "fail"),
    ("folder-of-user-files", "docs", "fail"), ("new-folder", "results/new", "valid"),
    ("empty-folder", "empty", "valid"),
]  # fmt: skip
#: Commands writing an output, each as argv before the output option, and that option.
OUT_COMMANDS = [
    (["localize", "maps/query.json", "maps/target.json"], "--out"),
    (["localize", "maps/query.json", "maps/target.json"], "--json"),
    (["fleet", "maps/query.json", "maps/target.json", "--workers", "1"], "--out"),
    (["experiment", "table", "--trials", "1", "--workers", "1"], "--out"),
    (["demo", "--objects-only"], "--out"),
    (["build-graph", "airsim", "robot"], "-o"),
]


def out_path_case(seeds: dict[str, Path], work: Path, rng: np.random.Generator, k: int) -> Case:
    """A user's folder (maps, notes, docs, an empty folder) as the working folder; a command
    writing its output at a path that names the user's folder, an input, or a new path."""
    import shutil

    proj = work / f"case{k}" / "proj"
    (proj / "maps").mkdir(parents=True)
    (proj / "docs").mkdir()
    (proj / "empty").mkdir()
    (proj / "notes.txt").write_text("keep me\n")
    (proj / "docs" / "plan.md").write_text("mine\n")
    shutil.copy(seeds["query.json"], proj / "maps" / "query.json")
    shutil.copy(seeds["target.json"], proj / "maps" / "target.json")
    shutil.copytree(seeds["robot"], proj / "robot")
    name, target, expect = OUT_TARGETS[int(rng.integers(0, len(OUT_TARGETS)))]
    commands = OUT_COMMANDS if expect == "fail" else [  # an empty folder takes a folder only
        c for c in OUT_COMMANDS[:3] if name != "empty-folder" or c[1] == "--out"]
    argv, option = commands[int(rng.integers(0, len(commands)))]
    out = target.format(proj=proj)
    before = _snapshot(proj.parent)
    written = (proj / out).resolve() if expect == "valid" else None
    return Case(f"--out {name} ({argv[0]} {option})", expect, [*argv, option, out], cwd=proj,
                check=lambda: _unchanged(proj.parent, before, written))


def _snapshot(folder: Path) -> dict[str, bytes]:
    """Every file and folder under `folder` (hidden ones too): bytes, or b"/" for a folder."""
    return {p.relative_to(folder).as_posix(): b"/" if p.is_dir() else p.read_bytes()
            for p in sorted(folder.rglob("*"))}  # fmt: skip


def _unchanged(folder: Path, before: dict[str, bytes], written: Path | None) -> str:
    """"" when every file of `before` is as it was and nothing new appeared but under the
    command's own output `written`; the bad outcome otherwise."""
    after = _snapshot(folder)

    def ours(name: str) -> bool:  # the output, what is in it, or a folder made to hold it
        where = (folder / name).resolve()
        return written is not None and (where == written or written in where.parents
                                        or where in written.parents)

    new = [n for n in after if n not in before and not ours(n)]
    changed = [n for n, b in before.items() if after.get(n) != b]
    return "user files moved or changed" if new or changed else ""


# -- --scheduler: services that are not a Dask scheduler -------------------------------------------
SCHEDULER_KINDS = ["garbage", "http", "silent", "close", "refused", "bad-port", "no-port",
                   "http-scheme", "nonsense"]  # fmt: skip


def scheduler_case(seeds: dict[str, Path], work: Path, rng: np.random.Generator, k: int) -> Case:
    """`fleet` or `experiment` with --scheduler at a loopback service that is not a Dask
    scheduler (random bytes, an HTTP reply, silence, a hang-up, a closed port) or at a
    malformed address: one clear error within the time limit."""
    import socket

    kind = SCHEDULER_KINDS[int(rng.integers(0, len(SCHEDULER_KINDS)))]
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    port = server.getsockname()[1]
    address = {"bad-port": "tcp://127.0.0.1:99999", "no-port": "tcp://127.0.0.1",
               "http-scheme": f"http://127.0.0.1:{port}", "nonsense": "not an address"}.get(
        kind, f"tcp://127.0.0.1:{port}")  # fmt: skip
    if kind == "refused":
        server.close()
    else:
        server.listen(8)
    case_dir = work / f"case{k}"
    case_dir.mkdir()
    if rng.random() < 0.8:
        argv = ["fleet", str(seeds["query.json"]), str(seeds["target.json"]),
                "--out", str(case_dir / "out")]  # fmt: skip
    else:
        argv = ["experiment", "table", "--trials", "1", "--out", str(case_dir / "out")]
    noise_seed = int(rng.integers(0, 2**31))
    return Case(f"--scheduler {kind} ({argv[0]})", "fail", [*argv, "--scheduler", address],
                around=lambda: _service(server, kind, noise_seed))


@contextlib.contextmanager
def _service(server, kind: str, seed: int) -> Iterator[None]:
    """Answer connections on the listening `server` as `kind` while the block runs."""
    import threading

    stop = threading.Event()
    conns: list = []

    def serve() -> None:
        server.settimeout(0.1)
        noise = np.random.default_rng(seed).integers(0, 256, 4096, dtype=np.uint8).tobytes()
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            conns.append(conn)
            with contextlib.suppress(OSError):
                if kind == "garbage":
                    conn.sendall(noise)
                elif kind in ("http", "http-scheme"):
                    conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
                elif kind == "close":
                    conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    if kind not in ("refused", "bad-port", "no-port", "nonsense"):
        thread.start()
    try:
        yield
    finally:
        stop.set()
        if thread.is_alive():
            thread.join(5)
        for c in conns:
            c.close()
        server.close()


@contextlib.contextmanager
def case_setting(case: Case) -> Iterator[None]:
    """Run a case in its working folder, with its service (if any) answering."""
    here = os.getcwd()
    with contextlib.ExitStack() as stack:
        if case.around is not None:
            stack.enter_context(case.around())
        if case.cwd is not None:
            os.chdir(case.cwd)
            stack.callback(os.chdir, here)
        yield


#: Case families: name -> (case maker(seeds, work, rng, k), weight in a mixed run, what).
FAMILIES: dict[str, tuple[Callable[..., Case], float, str]] = {
    "files": (make_case, 0.9, "mutated graph files, bad options, FIFOs, folders"),
    "out": (out_path_case, 0.06, "--out at the working folder, an input's folder, an input"),
    "scheduler": (scheduler_case, 0.04, "--scheduler services that are not Dask schedulers"),
}


def run_fuzz(
    cases: int,
    seed: int = 0,
    timeout: float = 20.0,
    progress: bool = False,
    by_kind: Counter | None = None,
    families: Sequence[str] | None = None,
) -> tuple[Counter, list[tuple[str, str, str]]]:
    """Run `cases` fuzz cases; (counts per outcome class, [(case, outcome, detail)] of the bad).
    `by_kind`, when given, is filled with counts per (input kind, outcome). `families`: the
    case families to draw from (FAMILIES; default all), each case's by their weights."""
    import matplotlib

    matplotlib.use("Agg")
    chosen = list(families or FAMILIES)
    unknown = [f for f in chosen if f not in FAMILIES]
    if unknown:
        raise SystemExit(f"unknown families {unknown}; choose from {', '.join(FAMILIES)}")
    weights = np.array([FAMILIES[f][1] for f in chosen], dtype=float)
    weights /= weights.sum()
    rng = np.random.default_rng(seed)
    counts: Counter = Counter()
    bad: list[tuple[str, str, str]] = []
    with tempfile.TemporaryDirectory(prefix="sgloc-fuzz-") as tmp:
        work = Path(tmp)
        seeds = write_seeds(work / "seeds", seed)
        for k in range(cases):
            family = chosen[int(rng.choice(len(chosen), p=weights))]
            case = FAMILIES[family][0](seeds, work, rng, k)
            with case_setting(case):
                rc, _out, err, exc = run_case(case.argv, timeout)
            outcome = classify(case.expect, rc, err, exc)
            if outcome not in BAD_OUTCOMES and case.check is not None:
                outcome = case.check() or outcome
            counts[outcome] += 1
            if by_kind is not None:
                by_kind[(case_kind(case.name), outcome)] += 1
            if outcome in BAD_OUTCOMES:
                bad.append((case.name, outcome, (exc + " " + err.strip())[:300]))
            if progress and (k + 1) % 500 == 0:
                print(f"  {k + 1}/{cases} cases", file=sys.stderr)
    return counts, bad


def case_kind(name: str) -> str:
    """The input kind of a case name: the mutated file type and mutation, or the option."""
    words = name.split()
    if words[0] in ("--out", "--scheduler"):
        return " ".join(words[:2])
    if words[1] == "option":
        return f"{words[0]} option value"
    if words[0] == "build-graph":
        return f"build-graph {words[1]} file"
    return (
        " ".join(words[1:3])
        .replace("query_bin.pcd", "binary .pcd")
        .replace("query_cmp.pcd", "compressed .pcd")
        .replace("query.pcd", "ascii .pcd")
        .replace("query.", ".")
    )


def kind_table(by_kind: Counter) -> str:
    """Cases per input kind: clean errors, read as data (exit 0/1), bad outcomes."""
    rows = ["| input | cases | clean error | read as data | bad |", "|---|---|---|---|---|"]
    for kind in sorted({k for k, _ in by_kind}):
        got = {o: n for (k, o), n in by_kind.items() if k == kind}
        data = sum(n for o, n in got.items() if o.startswith("read as data"))
        bad = sum(n for o, n in got.items() if o in BAD_OUTCOMES)
        clean = got.get("clean error, exit 2", 0)
        rows.append(f"| {kind} | {sum(got.values())} | {clean} | {data} | {bad} |")
    return "\n".join(rows)


def table(counts: Counter) -> str:
    rows = ["| outcome | cases |", "|---|---|"]
    order = [
        "clean error, exit 2",
        "read as data: localized, exit 0",
        "read as data: not localized, exit 1",
        *BAD_OUTCOMES,
    ]
    rows += [f"| {name} | {counts.get(name, 0):,} |" for name in order]
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds before a case is a hang")
    ap.add_argument("--update-docs", action="store_true", help="write docs/robustness.md's table")
    ap.add_argument("--family", action="append", choices=list(FAMILIES), metavar="NAME",
                    help="run only this case family (repeatable): " + "; ".join(
                        f"{k}: {FAMILIES[k][2]}" for k in FAMILIES))
    args = ap.parse_args()
    t0 = time.perf_counter()
    by_kind: Counter = Counter()
    counts, bad = run_fuzz(args.cases, args.seed, args.timeout, progress=True, by_kind=by_kind,
                           families=args.family)
    elapsed = time.perf_counter() - t0
    print(table(counts))
    print()
    print(kind_table(by_kind))
    print(f"\n{args.cases} cases, seed {args.seed}, {elapsed:.0f} s")
    for name, outcome, detail in bad[:30]:
        print(f"BAD {outcome}: {name}: {detail}")
    if args.update_docs:
        write_docs(counts, by_kind, args.cases, args.seed, elapsed)
    return 1 if bad else 0


def write_docs(counts: Counter, by_kind: Counter, cases: int, seed: int, elapsed: float) -> None:
    doc = Path(__file__).resolve().parent.parent / "docs" / "robustness.md"
    text = doc.read_text() if doc.exists() else ""
    begin, end = "<!-- fuzz-table:begin -->", "<!-- fuzz-table:end -->"
    block = (
        f"{begin}\n`python benchmarks/fuzz.py --cases {cases} --seed {seed}` "
        f"({elapsed:.0f} s):\n\n{table(counts)}\n\nBy input kind:\n\n{kind_table(by_kind)}\n{end}"
    )
    if begin in text and end in text:
        text = text[: text.index(begin)] + block + text[text.index(end) + len(end) :]
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    doc.write_text(text)
    print(f"wrote {doc}")


if __name__ == "__main__":
    sys.exit(main())
