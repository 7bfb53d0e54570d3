"""Mutation fuzzing of everything a user feeds the command line.

    python benchmarks/fuzz.py [--cases 5000] [--seed 0] [--signal-trials 100] [--update-docs]

Valid seed files (graphs in ascii/binary/binary_compressed PCD, JSON and NPZ from a synthetic
two-robot scene; a tiny Airsim-layout robot folder) are mutated: truncations, byte flips, header
edits, NaN / inf / 1e308 / oversized values, wrong types, FIFOs, folders. Each case runs
`sgloc localize`, `fleet` or `build-graph` in this process (`sgloc.cli.main`) under a time limit,
and its outcome is classed. A case whose mutation certainly breaks the file is "must fail"; one
that may leave a valid file (a flipped digit) is "either"; one that only changes values within
the allowed ranges is "valid". Bad outcomes: a traceback, a MemoryError, a hang, an error not
printed as one line with exit 2, a must-fail file read as data, a valid file refused.
Prints the count of every outcome class; with --update-docs writes docs/robustness.md's table.
Then the command families of benchmarks/fuzz_commands.py run (`--command-family NAME`, or
`--no-commands` to skip them): a signal at random moments of every command (`--signal-trials`
per command), every output option with every extension and a folder, every command twice into
its own output, and inputs of one layout given to a command that reads another.
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

    from sgloc.io.pcd import write_pcd
    from sgloc.maps.classes import AIRSIM_COLORS
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
    files |= write_input_seeds(folder, q, seed)
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


# -- input families: tables and replay layouts (stamps, quaternion order, byte-order marks) ------
BOM = "\ufeff".encode()
#: Stamps that no reader can hold (beyond int64 nanoseconds) or that are neither seconds nor
#: nanoseconds since 1973 (integers between 1e11 and 1e17).
BAD_STAMPS = ["1e30", "-1e30", "1e999999999", "9223372037", "92233720368547758070",
              "1700000000123456789.0", "1700000000123", "1700000000123456"]


def write_input_seeds(folder: Path, query, seed: int = 0) -> dict[str, Path]:
    """A graph table (query.csv) and a small two-robot replay layout whose odometry starts at
    the identity (as odometry does) with epoch stamps, class names and a classes.txt."""
    from sgloc.evaluation.replay_scenarios import world_scenario
    from sgloc.io.keyframes import make_robot_log
    from sgloc.io.plain_layout import write_plain_layout
    from sgloc.io.table import write_table

    write_table(folder / "query.csv", query.positions, query.labels)
    logs = []
    for g in world_scenario(((0.0, 80.0), (40.0, 120.0)), seed=seed, spacing=8.0).logs:
        from scipy.spatial.transform import Rotation

        T = np.linalg.inv(g.poses[0]) @ g.poses
        xyz, quat = T[:, :3, 3], Rotation.from_matrix(T[:, :3, :3]).as_quat()
        xyz[0], quat[0] = 0.0, (0.0, 0.0, 0.0, 1.0)
        logs.append(make_robot_log(g.name, g.stamps_ns + 1_700_000_000_123_456_789, xyz, quat,
                                   g.keyframe, g.positions, g.labels))
    write_plain_layout(folder / "layout", logs, [f"class{k}" for k in range(16)])
    return {"query.csv": folder / "query.csv", "layout": folder / "layout"}


def table_header_only(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """The header line alone: a map without objects."""
    return raw.split(b"\n", 1)[0] + b"\n" * int(rng.integers(0, 3)), "fail"


def table_bom(raw: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """A UTF-8 byte-order mark in front (spreadsheet "CSV UTF-8"), with or without the header."""
    body = raw if rng.random() < 0.5 else raw.split(b"\n", 1)[1]
    return BOM + body, "valid"


MUTATIONS["query.csv"] = [
    ("header-only", table_header_only), ("bom", table_bom), ("flip", flip_bytes),
]  # fmt: skip


def _edit_stamps(path: Path, edit: Callable[[str], str], rows: list[int] | None = None) -> None:
    """Rewrite the stamp (first field) of the data rows `rows` (all when None) of a layout file."""
    lines = path.read_text().splitlines()
    first = 1 if path.suffix == ".csv" else 0
    sep = "," if path.suffix == ".csv" else " "
    for i in range(first, len(lines)) if rows is None else [r + first for r in rows]:
        head, rest = lines[i].split(sep, 1)
        lines[i] = sep.join((edit(head), rest))
    path.write_text("".join(f"{ln}\n" for ln in lines))


def _integer_ns(stamp: str) -> str:
    s, f = stamp.split(".")
    return s + f


def layout_edit(layout: Path, rng: np.random.Generator) -> tuple[str, str]:
    """Change one robot's files of the seed layout in place; return (what, expect)."""
    robot = layout / str(rng.choice(["world0", "world1"]))
    odom, objects = robot / "odometry.tum", robot / "objects.csv"
    file = odom if rng.random() < 0.5 else objects
    kind = str(rng.choice(["integer-ns", "bad-stamp", "w-first", "bom", "class-case",
                           "no-objects", "no-poses"]))
    if kind == "integer-ns":  # integer nanoseconds in one file or all: the same stamps
        for f in [file] if rng.random() < 0.5 else list(layout.glob("*/*.*")):
            _edit_stamps(f, _integer_ns)
        return kind, "valid"
    if kind == "bad-stamp":
        row = int(rng.integers(0, len(file.read_text().splitlines()) - (file == objects)))
        _edit_stamps(file, lambda _: str(rng.choice(BAD_STAMPS)), [row])
        return kind, "fail"
    if kind == "w-first":  # qw moved first: the first pose, the identity, reads `1 0 0 0`
        rows = [ln.split() for ln in odom.read_text().splitlines()]
        odom.write_text("".join(" ".join(r[:4] + r[7:] + r[4:7]) + "\n" for r in rows))
        return kind, "fail"
    if kind == "bom":
        for f in (file, layout / "classes.txt")[: int(rng.integers(1, 3))]:
            f.write_bytes(BOM + f.read_bytes())
        return kind, "valid"
    if kind == "class-case":  # class names in another case: one name
        objects.write_text(objects.read_text().replace(",class", ",CLASS").replace(
            "stamp,x,y,z,CLASS", "stamp,x,y,z,class"))
        return kind, "valid"
    if kind == "no-objects":  # the header only: a robot that saw nothing
        objects.write_text("stamp,x,y,z,class\n")
        return kind, "valid"
    odom.write_text("# stamp tx ty tz qx qy qz qw\n")
    return kind, "fail"


def layout_case(seeds: dict[str, Path], case_dir: Path, rng: np.random.Generator) -> Case:
    """`sgloc replay` of the seed layout with one robot's files changed (`layout_edit`)."""
    import shutil

    layout = case_dir / "layout"
    shutil.copytree(seeds["layout"], layout)
    what, expect = layout_edit(layout, rng)
    argv = ["replay", str(layout), "--out", str(case_dir / "out"), "--quiet"]
    return Case(f"replay layout {what}", expect, argv)


def input_case(seeds: dict[str, Path], work: Path, rng: np.random.Generator, k: int) -> Case:
    """Case k of the input families alone: a replay layout, or a graph table edit."""
    case_dir = work / f"case{k}"
    case_dir.mkdir()
    if rng.random() < 0.6:
        return layout_case(seeds, case_dir, rng)
    mutation, fn = MUTATIONS["query.csv"][int(rng.integers(0, len(MUTATIONS["query.csv"])))]
    raw, expect = fn(seeds["query.csv"].read_bytes(), rng)
    (case_dir / "query.csv").write_bytes(raw)
    target = str(seeds["target.json"])
    argv = ["localize", str(case_dir / "query.csv"), target]
    if rng.random() < 0.3:
        argv = ["fleet", argv[1], target, "--workers", "1", "--out", str(case_dir / "out")]
    return Case(f"{argv[0]} query.csv {mutation}", expect, argv)


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
    elif roll < 0.21:
        return layout_case(seeds, case_dir, rng)
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
    if argv[0] == "demo" and name != "input-file":  # a picture option: a folder gets its file
        expect, written = "valid", (proj / out).resolve() / "aligned_maps.png"
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
    # Drawn alone (--family inputs): "files" already mixes these cases among its own.
    "inputs": (input_case, 0.0, "graph tables and replay layouts: stamps, quaternion order, BOMs"),
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
    total = weights.sum()
    weights = weights / total if total > 0 else np.full(len(chosen), 1 / len(chosen))
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


# -- the online session through the Python API -----------------------------------------------
# Hostile keyframes, links and save files fed to `OnlineSession` directly (no command line). A
# refused call must raise an SglocError and change nothing; whatever one call did, every robot's
# next good keyframe must still be taken; a damaged save file must be one SglocError naming it.
SESSION_BAD = (
    "traceback",
    "hang",
    "bad input accepted",
    "valid input refused",
    "refused call changed the session",
    "session poisoned",
)


@dataclass
class SessionCase:
    """One hostile call: `call(session)` on a fresh copy of the base session (for a save file,
    `call(None)` loads it and returns the session)."""

    name: str
    expect: str  # "fail" | "either" | "valid"
    call: Callable


def _session_base(folder: Path, seed: int = 0) -> tuple[Path, list[tuple], list[tuple]]:
    """A saved session halfway through a two-robot replay, every robot's next keyframe
    (robot, stamp, T_odom_sensor, positions, labels) after it (what the cases spoil), and every
    robot's keyframe after that one (what must still be taken after any case)."""
    from sgloc.evaluation.replay_scenarios import world_scenario
    from sgloc.online import OnlineConfig, OnlineSession
    from sgloc.replay.stream import keyframe_order

    logs = world_scenario(stretches=((0.0, 120.0), (60.0, 180.0)), seed=seed).logs
    obs = [list(g.observations()) for g in logs]
    frames = [(logs[r].name, float(logs[r].stamps[k]), logs[r].poses[k], *obs[r][k][1:])
              for r, k in keyframe_order(logs)]
    s = OnlineSession(online=OnlineConfig(seed=seed, max_attempts=1))
    half = len(frames) // 2
    for f in frames[:half]:
        s.add_keyframe(*f)
    nxt: dict[str, list[tuple]] = {}
    for f in frames[half:]:
        nxt.setdefault(f[0], []).append(f)
    return (s.save(folder / "base.npz"), [v[0] for v in nxt.values()],
            [v[1] for v in nxt.values()])


def _not_rigid(rng: np.random.Generator) -> tuple[str, np.ndarray]:
    T = np.eye(4)
    kind = str(rng.choice(["scaled", "mirrored", "zero", "sheared", "bottom row", "nan",
                           "far", "shape"]))
    if kind == "scaled":
        T[:3, :3] *= rng.choice([2.0, 0.5, 1.001, -1.0])
    elif kind == "mirrored":
        T[int(rng.integers(0, 3)), int(rng.integers(0, 3))] = -1.0
    elif kind == "zero":
        T[:3, :3] = 0.0
    elif kind == "sheared":
        T[0, 1] = rng.uniform(0.01, 1.0)
    elif kind == "bottom row":
        T[3, int(rng.integers(0, 3))] = 1.0
    elif kind == "nan":
        T[int(rng.integers(0, 4)), int(rng.integers(0, 4))] = rng.choice([np.nan, np.inf])
    elif kind == "far":
        T[0, 3] = rng.choice([1e8, -1e12, 1e300])
    else:
        return kind, np.eye(3) if rng.random() < 0.5 else np.eye(4).ravel()
    return kind, T


def hostile_keyframe(rng: np.random.Generator, good: tuple, robots: list[str]) -> SessionCase:
    """One part of a robot's next good keyframe made bad (or a valid variant of it)."""
    robot, stamp, T, pos, lab = good
    part = str(rng.choice(["stamp", "pose", "positions", "labels", "robot", "valid"]))
    pos, lab = np.array(pos), np.array(lab)
    expect = "fail"
    if part == "stamp":
        what, stamp = [("nan", np.nan), ("inf", np.inf), ("1e30", 1e30), ("text", "soon"),
                       ("None", None), ("repeat", -1.0), ("backwards", stamp - 1e3),
                       ("ns in the seconds column", stamp * 1e9 + 1e19)][int(rng.integers(0, 8))]
        if what == "repeat":
            stamp = None  # filled below with the robot's last stamp
    elif part == "pose":
        what, T = _not_rigid(rng)
    elif part == "positions":
        what = str(rng.choice(["nan", "1e8", "beyond after the pose", "shape", "text"]))
        if what == "nan" and len(pos):
            pos[int(rng.integers(0, len(pos))), 0] = np.nan
        elif what == "1e8" and len(pos):
            pos[0, 2] = 1e8
        elif what == "beyond after the pose":
            T = np.eye(4)
            T[0, 3] = 9.99e6
            pos = np.abs(pos) + [1e5, 0.0, 0.0]  # within the limit in the sensor frame
        elif what == "shape":
            pos = pos[:, :2]
        else:
            pos = np.array([["a", "b", "c"]] * max(len(pos), 1))
        expect = "fail" if len(pos) or what in ("shape", "text") else "either"
    elif part == "labels":
        what = str(rng.choice(["negative", "fraction", "huge", "length", "many classes"]))
        if what == "many classes":
            pos = rng.uniform(-30, 30, (80, 3))
            lab = np.arange(80) + 1000
        elif len(lab) == 0:
            expect = "either"
        elif what == "negative":
            lab[0] = -1
        elif what == "fraction":
            lab = lab + 0.5
        elif what == "huge":
            lab[0] = 2**40
        else:
            lab = lab[:-1]
    elif part == "robot":
        what, robot = [("empty", ""), ("None", None), ("number", 5)][int(rng.integers(0, 3))]
    else:
        what = str(rng.choice(["as is", "new robot", "float32 pose", "no detections"]))
        expect = "valid"
        if what == "new robot":
            robot = f"newcomer{int(rng.integers(0, 9))}"
        elif what == "float32 pose":
            T = np.array(T, np.float32).astype(np.float64)
        elif what == "no detections":
            pos, lab = np.zeros((0, 3)), np.zeros(0, np.int64)

    def call(session, robot=robot, stamp=stamp, T=T, pos=pos, lab=lab):
        if stamp is None and what == "repeat":
            stamp = float(session.keyframes(robot)[0][-1])
        return session.add_keyframe(robot, stamp, T, pos, lab)

    return SessionCase(f"session keyframe {part} {what}", expect, call)


def hostile_link(rng: np.random.Generator, good: tuple, robots: list[str]) -> SessionCase:
    """An add_link call with one bad argument (or a valid link)."""
    a, b = robots[0], robots[1]
    T, cov, conf, stamp = np.eye(4), np.eye(6) * 1e-3, 0.9, None
    part = str(rng.choice(["robots", "pose", "covariance", "confidence", "stamp", "valid"]))
    expect = "fail"
    if part == "robots":
        what, (a, b) = [("same robot", (a, a)), ("unknown robot", (a, "nobody")),
                        ("not a name", (a, 3))][int(rng.integers(0, 3))]
    elif part == "pose":
        what, T = _not_rigid(rng)
    elif part == "covariance":
        what = str(rng.choice(["nan", "negative", "asymmetric", "1e300", "shape", "text"]))
        cov = {"nan": np.full((6, 6), np.nan), "negative": -np.eye(6),
               "asymmetric": np.eye(6) + np.triu(np.ones((6, 6)), 1), "1e300": np.eye(6) * 1e300,
               "shape": np.eye(3), "text": "small"}[what]
    elif part == "confidence":
        what = str(rng.choice(["nan", "-1", "2", "text"]))
        conf = {"nan": np.nan, "-1": -1.0, "2": 2.0, "text": "high"}[what]
    elif part == "stamp":
        what = str(rng.choice(["nan", "1e30", "text"]))
        stamp = {"nan": np.nan, "1e30": 1e30, "text": "now"}[what]
    else:
        what, expect = str(rng.choice(["identity", "far", "zero covariance"])), "valid"
        if what == "far":
            T[:3, 3] = rng.uniform(-500, 500, 3)
        elif what == "zero covariance":
            cov = np.zeros((6, 6))

    def call(session):
        return session.add_link(a, b, T, cov, conf, stamp)

    return SessionCase(f"session link {part} {what}", expect, call)


def _meta_edit(raw_path: Path, out: Path, rng: np.random.Generator) -> tuple[str, str]:
    """A saved session with its JSON document or arrays edited; (what, expect)."""
    import json as _json

    with np.load(raw_path) as z:
        arrays = {k: z[k] for k in z.files}
    meta = _json.loads(str(arrays.pop("meta")))
    what = str(rng.choice(["robots shortened", "robots renamed twice", "robots not names",
                           "link robot index", "link scaled", "stamps backwards",
                           "pose scaled", "placed out of range", "no links key",
                           "format", "detail text", "counts zero"]))
    expect = "fail"
    if what == "robots shortened":
        meta["robots"] = meta["robots"][:1]
    elif what == "robots renamed twice":
        meta["robots"] = [meta["robots"][0]] * len(meta["robots"])
    elif what == "robots not names":
        meta["robots"] = list(range(len(meta["robots"])))
    elif what == "link robot index" and meta.get("links"):
        meta["links"][0][1] = 9
    elif what == "link scaled" and meta.get("links"):
        meta["links"][0][2]["T_a_b"][0][0] = 2.0
    elif what == "stamps backwards":
        arrays["map0_stamps"] = arrays["map0_stamps"][::-1].copy()
    elif what == "pose scaled":
        arrays["map1_poses"] = arrays["map1_poses"] * 3.0
    elif what == "placed out of range":
        meta["placed"] = [0, 7]
    elif what == "no links key":  # the back-end's links: "links" ("robots"), "keyframes"
        meta.pop("links" if "links" in meta else "keyframes")
    elif what == "format":
        meta["format"] = "sgloc-online-session-99"
    elif what == "counts zero":
        arrays["map0_counts"] = np.zeros_like(arrays["map0_counts"])
    else:
        expect = "valid"
        for e in meta["events"]:
            e["detail"] = e["detail"] + " (edited)"
    if expect == "fail" and what.startswith("link") and not meta["links"]:
        expect = "valid"
    np.savez(out, meta=np.array(_json.dumps(meta)), **arrays)
    return what, expect


def hostile_save(rng: np.random.Generator, base: Path, folder: Path) -> SessionCase:
    """The base session's file truncated, flipped or edited."""
    out = folder / "edited.npz"
    raw = base.read_bytes()
    part = str(rng.choice(["truncate", "flip", "edit", "edit"]))
    if part == "truncate":
        out.write_bytes(raw[: int(rng.integers(0, len(raw) - 1))])
        what, expect = "truncate", "fail"
    elif part == "flip":
        data = bytearray(raw)
        for _ in range(int(rng.integers(1, 4))):
            data[int(rng.integers(0, len(data)))] ^= int(rng.integers(1, 256))
        out.write_bytes(bytes(data))
        what, expect = "flip", "either"
    else:
        what, expect = _meta_edit(base, out, rng)

    def call(_session):
        from sgloc.online import OnlineSession

        return OnlineSession.load(out)

    return SessionCase(f"session file {part} {what}", expect, call)


SESSION_FAMILIES: dict[str, Callable] = {
    "keyframe": hostile_keyframe,
    "link": hostile_link,
}


def _timed(fn: Callable, timeout: float) -> tuple[object, str]:
    """(fn()'s value, '' | 'SglocError' | 'hang' | the exception class name)."""
    from sgloc.errors import SglocError

    def on_alarm(signum, frame):
        raise CaseTimeout

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        return fn(), ""
    except CaseTimeout:
        return None, "hang"
    except SglocError as e:
        return e, "SglocError"
    except BaseException as e:  # noqa: BLE001 - classifying every escape is the point
        return e, type(e).__name__
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _session_text(session) -> str:
    meta, arrays = session.to_state()
    return json.dumps(meta, sort_keys=True) + repr(sorted((k, v.tobytes())
                                                          for k, v in arrays.items()))


def run_session_case(case: SessionCase, base: Path, good: list[tuple],
                     timeout: float) -> tuple[str, str]:
    """(outcome, detail) of one hostile call on a fresh copy of the base session, followed by
    the good keyframes `good` (one per robot), which must all be taken."""
    from sgloc.online import OnlineSession

    is_file = case.name.startswith("session file")
    session = None if is_file else OnlineSession.load(base)
    before = "" if is_file else _session_text(session)
    value, exc = _timed(lambda: case.call(session), timeout)
    if exc not in ("", "SglocError"):
        return ("hang" if exc == "hang" else "traceback"), f"{exc}: {str(value)[:200]}"
    if exc == "SglocError":
        if case.expect == "valid":
            return "valid input refused", str(value)[:200]
        if not is_file and _session_text(session) != before:
            return "refused call changed the session", str(value)[:200]
        if is_file and not str(value).startswith(str(base.parent / "edited.npz")):
            return "traceback", f"error does not name the file: {str(value)[:200]}"
        outcome = "clean error"
    else:
        if case.expect == "fail":
            return "bad input accepted", case.name
        outcome = "accepted"
        session = value if is_file else session
    if session is None:
        return outcome, ""
    for f in good:
        _, exc = _timed(lambda f=f: session.add_keyframe(*f), timeout)
        if exc:
            return "session poisoned", f"{f[0]}'s next keyframe: {exc}"
    return outcome, ""


def run_session_fuzz(
    cases: int, seed: int = 0, timeout: float = 20.0, by_kind: Counter | None = None
) -> tuple[Counter, list[tuple[str, str, str]]]:
    """Run `cases` hostile keyframes, links and save files through the Python API; (counts
    per outcome, [(case, outcome, detail)] of the bad ones)."""
    rng = np.random.default_rng([seed, 28])
    counts: Counter = Counter()
    bad: list[tuple[str, str, str]] = []
    with tempfile.TemporaryDirectory(prefix="sgloc-fuzz-session-") as tmp:
        base, good, after = _session_base(Path(tmp), seed)
        robots = [g[0] for g in good]
        for _ in range(cases):
            family = str(rng.choice([*SESSION_FAMILIES, "save file"]))
            if family == "save file":
                case = hostile_save(rng, base, Path(tmp))
            else:
                target = good[int(rng.integers(0, len(good)))]
                case = SESSION_FAMILIES[family](rng, target, robots)
            outcome, detail = run_session_case(case, base, after, timeout)
            counts[outcome] += 1
            if by_kind is not None:
                by_kind[(" ".join(case.name.split()[:3]), outcome)] += 1
            if outcome in SESSION_BAD:
                bad.append((case.name, outcome, detail))
    return counts, bad


def session_table(counts: Counter) -> str:
    rows = ["| outcome (Python API) | cases |", "|---|---|"]
    for name in ("clean error", "accepted", *SESSION_BAD):
        rows.append(f"| {name} | {counts.get(name, 0):,} |")
    return "\n".join(rows)


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
    ap.add_argument("--session-cases", type=int, default=400,
                    help="hostile keyframes, links and save files through the Python API")
    ap.add_argument("--update-docs", action="store_true", help="write docs/robustness.md's table")
    ap.add_argument("--family", action="append", choices=list(FAMILIES), metavar="NAME",
                    help="run only this case family (repeatable): " + "; ".join(
                        f"{k}: {FAMILIES[k][2]}" for k in FAMILIES))
    ap.add_argument("--inputs", action="store_true", help="the input families alone (same as "
                    "--family inputs)")
    commands = _commands_module()
    commands.add_arguments(ap, seed=False)
    ap.add_argument("--no-commands", action="store_true",
                    help="skip the command families (signals, outputs, twice, layouts)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    by_kind: Counter = Counter()
    families = ["inputs"] if args.inputs else args.family
    counts, bad = run_fuzz(args.cases, args.seed, args.timeout, progress=True, by_kind=by_kind,
                           families=families)
    elapsed = time.perf_counter() - t0
    print(table(counts))
    print()
    print(kind_table(by_kind))
    print(f"\n{args.cases} cases, seed {args.seed}, {elapsed:.0f} s")
    session_counts, session_bad = run_session_fuzz(args.session_cases, args.seed, args.timeout)
    print()
    print(session_table(session_counts))
    print(f"\n{args.session_cases} Python API cases (keyframes, links, save files)")
    bad += session_bad
    for name, outcome, detail in bad[:30]:
        print(f"BAD {outcome}: {name}: {detail}")
    if args.update_docs:
        write_docs(counts, by_kind, args.cases, args.seed, elapsed)
    if args.no_commands:
        return 1 if bad else 0
    report = commands.run_from_args(args)
    line = " ".join(["python benchmarks/fuzz.py", *[a for a in sys.argv[1:]
                                                    if a != "--update-docs"]])
    rc = commands.print_report(report, line)
    if args.update_docs:
        print(f"wrote {commands.write_doc_block(commands.report_text(report, line))}")
    return 1 if bad or rc else 0


def _commands_module():
    """benchmarks/fuzz_commands.py (the command families), loaded beside this script."""
    import importlib.util

    if "fuzz_commands" not in sys.modules:
        path = Path(__file__).resolve().parent / "fuzz_commands.py"
        spec = importlib.util.spec_from_file_location("fuzz_commands", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules["fuzz_commands"] = module
        spec.loader.exec_module(module)
    return sys.modules["fuzz_commands"]


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
