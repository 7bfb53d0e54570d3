"""The docs' tables of output files and fields against what `sgloc replay` and `sgloc fleet`
write with their default settings.

docs/replay.md and docs/fleet_outputs.md list the files of a results folder (a `| file |` table)
and the keys of `summary.json` / `fleet.json` (`| key |` tables); the first column names them in
backticks (`fleet/<robot>.tum`: one per robot). Checked both ways: every file and key the tables
name is written by a default run, and every file and key written is named. Then the claims that
tell the default keyframe back-end from `--backend robots` (what `links.g2o` holds, `g2o_vertex`,
`g2o_keyframes`, `links_active`, `backend`), counted against the run; CSV headers and event
kinds as the docs give them; schema versions. A cell's clauses (split at `;` outside brackets)
that name `--backend robots` speak of that back-end; the others must hold for the default.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import re
from pathlib import Path

import pytest

from sgloc.cli import main
from sgloc.evaluation.fleet_scenes import world_fleet
from sgloc.evaluation.replay_scenarios import lost_robot, world_scenario
from sgloc.io.files import MANIFEST
from sgloc.io.g2o import read_g2o
from sgloc.io.plain_layout import write_plain_layout
from sgloc.maps.graph import SemanticGraph
from sgloc.online import records
from sgloc.online.fleet import localize_fleet
from sgloc.replay import outputs

DOCS = Path(__file__).resolve().parents[1] / "docs"
REPLAY_DOC, FLEET_DOC = DOCS / "replay.md", DOCS / "fleet_outputs.md"
#: Every kind of row events.csv can hold: the session's event kinds, then the unplaced robots.
EVENT_KINDS = {records.ROBOT_JOINED, records.LINK_ACCEPTED, records.LINK_REVOKED,
               records.LINK_HELD, outputs.NOT_PLACED}


# -- the docs' tables ---------------------------------------------------------------------------
@dataclasses.dataclass
class Table:
    doc: str
    heading: str
    header: list[str]
    rows: list[list[str]]  # cells, the header and the |---| line left out

    def names(self, row: list[str]) -> list[str]:
        """The names the row's first cell gives in backticks."""
        return re.findall(r"`([^`]+)`", row[0])

    def row(self, name: str) -> str:
        """The text (all cells but the first) of the row naming `name`."""
        got = [" | ".join(r[1:]) for r in self.rows if name in self.names(r)]
        assert len(got) == 1, f"{self.doc}, {self.heading!r}: {len(got)} rows name `{name}`"
        return got[0]

    def documented(self) -> set[str]:
        return {n for r in self.rows for n in self.names(r)}


def tables(path: Path) -> list[Table]:
    """The markdown tables of `path`, outside code blocks, each with the heading above it."""
    out, heading, fenced, current = [], "", False, None
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
        if not fenced and line.startswith("#"):
            heading = line.lstrip("#").strip()
        if not fenced and line.startswith("|"):
            cells = [c.strip() for c in re.split(r"\s\|\s", line.strip().strip("|").strip())]
            if current is None:
                current = Table(path.name, heading, cells, [])
                out.append(current)
            elif not set(line) <= set("|-: "):
                current.rows.append(cells)
        else:
            current = None
    return out


def file_table(path: Path) -> Table:
    got = [t for t in tables(path) if t.header[0] == "file"]
    assert len(got) == 1, f"{path.name}: {len(got)} tables of files"
    return got[0]


def key_tables(path: Path, heading: str) -> list[Table]:
    """The `| key |` tables under the heading that contains `heading`, in order."""
    return [t for t in tables(path) if t.header[0] == "key" and heading in t.heading]


def clauses(text: str) -> list[str]:
    """`text` split at the `;` outside brackets and backticks."""
    out, depth, tick, start = [], 0, False, 0
    for i, ch in enumerate(text):
        tick ^= ch == "`"
        depth += (ch in "([{") - (ch in ")]}")
        if ch == ";" and depth == 0 and not tick:
            out.append(text[start:i])
            start = i + 1
    return [c.strip() for c in [*out, text[start:]]]


def default_text(text: str) -> str:
    """The clauses of a cell that speak of the default back-end: all but those naming
    `--backend robots` (or `backend="robots"`)."""
    other = re.compile(r'--backend robots|backend="robots"')
    return "; ".join(c for c in clauses(text) if not other.search(c))


def bullet(path: Path, start: str) -> str:
    """The text of the list item of `path` that starts with `start` (its wrapped lines joined)."""
    got = re.findall(r"^- " + re.escape(start) + r"(.*\n(?:  .*\n)*)", path.read_text(), flags=re.M)
    assert len(got) == 1, f"{path.name}: {len(got)} items start with {start}"
    return " ".join(got[0].split())


def pattern(name: str) -> re.Pattern:
    """A documented file name as a pattern: `<robot>` stands for one robot's file stem."""
    return re.compile(re.escape(name).replace(re.escape("<robot>"), r"(?P<robot>[^/]+)") + "$")


def written_files(folder: Path) -> set[str]:
    """Every file under `folder` (relative, /-separated), the manifest left out."""
    files = {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()}
    assert MANIFEST in files
    return files - {MANIFEST}


def assert_files_match(documented: list[str], folder: Path, placed_stems: set[str], where: str):
    """Each documented file (pattern) is written (for a `<robot>` pattern: exactly one per placed
    robot), and each written file is documented."""
    files = written_files(folder)
    for name in documented:
        hits = [m for f in files if (m := pattern(name).match(f))]
        assert hits, f"{where} names `{name}`, which the default run does not write"
        if "<robot>" in name:
            assert {m["robot"] for m in hits} == placed_stems, (where, name, hits)
    undocumented = {f for f in files if not any(pattern(n).match(f) for n in documented)}
    assert not undocumented, f"written but not named in {where}: {sorted(undocumented)}"


def csv_headers(text: str) -> dict[str, str]:
    """{csv file: the header the text gives it} for each table row or paragraph of `text` that
    names one `*.csv` file and a backticked comma-separated header."""
    got = {}
    for block in re.split(r"\n\s*\n|\n(?=\|)", text):
        files = set(re.findall(r"`([\w/<>.-]+\.csv)`", block))
        headers = [h for h in re.findall(r"`([a-z_]+(?:,[a-z_]+)+)`", block)]
        if headers and len(files) == 1:
            got.setdefault(files.pop(), set()).update(headers)
    return got


# -- the default runs ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def replay(tmp_path_factory):
    """`sgloc replay` with its defaults on the small two-robot world and a robot it cannot
    place: (out folder, summary, logs)."""
    d = tmp_path_factory.mktemp("docs_replay")
    logs = [*world_scenario().logs, lost_robot()]
    write_plain_layout(d / "run", logs)
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["replay", str(d / "run"), "--out", str(d / "out")]) == 0
    summary = json.loads((d / "out" / "summary.json").read_text())
    assert summary["backend"] == "keyframes"  # the default
    placed = [r for r, v in summary["robots"].items() if v["placed"]]
    assert len(placed) == 2 and not summary["robots"]["lost"]["placed"]
    return d / "out", summary, logs


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """`localize_fleet` with its defaults on three robots of the test world, written out:
    (out folder, fleet.json)."""
    out = tmp_path_factory.mktemp("docs_fleet") / "out"
    localize_fleet(world_fleet(0).graphs[:3], workers=0, out=out)
    return out, json.loads((out / "fleet.json").read_text())


# -- files --------------------------------------------------------------------------------------
def test_replay_files_are_those_the_docs_list(replay):
    out, summary, _ = replay
    placed = {Path(v["file"]).stem for v in summary["robots"].values() if v["placed"]}
    table = file_table(REPLAY_DOC)
    assert_files_match(sorted(table.documented()), out, placed, "docs/replay.md's table")
    # docs/fleet_outputs.md lists them again where it describes summary.json
    doc = FLEET_DOC.read_text()
    sentence = re.search(r"`sgloc replay` \(\[replay\.md\]\(replay\.md\)\) writes (.*?`)\.\s",
                         doc, flags=re.S)
    assert sentence, "docs/fleet_outputs.md: the sentence naming sgloc replay's files"
    assert_files_match(re.findall(r"`([^`]+)`", sentence[1]), out, placed,
                       "docs/fleet_outputs.md's list of sgloc replay's files")
    assert MANIFEST in (DOCS / "formats.md").read_text()


def test_fleet_files_are_those_the_docs_list(fleet):
    out, info = fleet
    assert_files_match(sorted(file_table(FLEET_DOC).documented()), out, set(info["placed"]),
                       "docs/fleet_outputs.md's table")


# -- keys ---------------------------------------------------------------------------------------
def _dict_subkeys_documented(table: Table, obj: dict, skip: set[str]):
    """A dict-valued key with fixed keys (latency, events, timings) names them in its row."""
    for key, value in obj.items():
        if isinstance(value, dict) and key not in skip:
            named = set(re.findall(r"`([a-z_0-9]+)`", table.row(key)))
            assert set(value) <= named, (table.doc, key, set(value) - named)


def _keys(objs) -> set[str]:
    return {k for o in objs for k in o}


def test_summary_keys_are_those_the_docs_list(replay):
    _, summary, _ = replay
    top, robot = key_tables(FLEET_DOC, "`summary.json`")  # exactly these two tables
    assert top.documented() == set(summary), top.documented() ^ set(summary)
    entries = list(summary["robots"].values())
    assert robot.documented() == _keys(entries), robot.documented() ^ _keys(entries)
    _dict_subkeys_documented(top, summary, skip={"robots"})
    for entry in entries:
        _dict_subkeys_documented(robot, entry, skip=set())


def test_fleet_json_keys_are_those_the_docs_list(fleet):
    _, info = fleet
    top, link = key_tables(FLEET_DOC, "`fleet.json`")
    assert top.documented() == set(info), top.documented() ^ set(info)
    assert info["links"] and link.documented() == _keys(info["links"])
    _dict_subkeys_documented(top, info, skip={"placed", "unplaced"})


def test_schemas_are_those_the_docs_give(replay, fleet):
    for heading, schema in (("`summary.json`", replay[1]["schema"]),
                            ("`fleet.json`", fleet[1]["schema"])):
        top = key_tables(FLEET_DOC, heading)[0]
        assert f'"schema": "{schema}"' in top.heading, (top.heading, schema)
        assert re.findall(r'"(sgloc\.[\w.]+/\d+)"', top.row("schema")) == [schema], (
            f"docs/fleet_outputs.md's `schema` row under {top.heading!r}: written {schema}")


# -- what the files hold --------------------------------------------------------------------
def test_links_g2o_is_the_keyframe_pose_graph_the_docs_describe(replay):
    """A vertex per keyframe of a placed robot, an edge per odometry step and per link (loop
    closures included), and the co-location factors when the docs say so."""
    out, summary, _ = replay
    row = default_text(file_table(REPLAY_DOC).row("links.g2o"))
    # OnlineSession.write_g2o writes it: docs/online_session.md says what it holds too
    method = default_text(bullet(DOCS / "online_session.md", "`write_g2o(path)`:"))
    for text in (row, method):
        assert "per keyframe" in text and "odometry" in text, text
        assert "per placed robot" not in text, text
    vertices, edges = read_g2o(out / "links.g2o")
    placed = {r: v for r, v in summary["robots"].items() if v["placed"]}
    assert len(vertices) == sum(v["keyframes"] for v in placed.values())
    with (out / summary["g2o_keyframes"]).open() as f:
        kf = {int(r["vertex"]): (r["robot"], int(r["keyframe"])) for r in csv.DictReader(f)}
    assert set(kf) == set(vertices)
    odometry = [e for e in edges
                if kf[e[0]][0] == kf[e[1]][0] and kf[e[1]][1] == kf[e[0]][1] + 1]
    assert len(odometry) == sum(v["keyframes"] - 1 for v in placed.values())
    others = len(edges) - len(odometry)
    assert others >= summary["links_active"] > 0
    if others > summary["links_active"]:  # factors besides the links: the docs must say which
        assert "co-location" in row and "co-location" in method, (
            f"links.g2o holds {others - summary['links_active']} edges besides the odometry and "
            f"the {summary['links_active']} active links; docs/replay.md's row: {row}")


def test_the_docs_say_what_the_default_back_end_writes_in_summary(replay):
    _, summary, _ = replay
    top, robot = key_tables(FLEET_DOC, "`summary.json`")
    # g2o_vertex: null, the vertices are keyframes
    assert all(v["g2o_vertex"] is None for v in summary["robots"].values())
    text = default_text(robot.row("g2o_vertex"))
    assert "null" in text and not re.search(r"vertex id|place in `robots`", text), text
    # g2o_keyframes: the table of vertices
    assert summary["g2o_keyframes"] == outputs.KEYFRAMES
    text = default_text(top.row("g2o_keyframes"))
    assert f"`{summary['g2o_keyframes']}`" in text and not re.search(r"null|empty", text), text
    # backend: the written value is the one called the default
    got = re.search(r"`(\w+)`[^`]*?\bdefault\b", top.row("backend"))
    assert got and got[1] == summary["backend"], top.row("backend")
    # links_active: links between keyframes, several per robot pair
    placed = sum(v["placed"] for v in summary["robots"].values())
    assert summary["links_active"] > placed * (placed - 1) // 2  # more than one per pair here
    text = default_text(top.row("links_active"))
    assert not re.search(r"one per (robot )?pair|at most one", text), text
    # no cell of these pages makes the default back-end look like an option
    for t in tables(REPLAY_DOC) + tables(FLEET_DOC):
        for r in t.rows:
            assert "--backend keyframes" not in " ".join(r), (t.doc, r)


def test_summary_counts_and_files_agree_with_the_folder(replay):
    out, summary, logs = replay
    robots = summary["robots"]
    assert summary["keyframes"] == sum(len(g) for g in logs)
    assert summary["placed"] == sum(v["placed"] for v in robots.values())
    for g in logs:
        v = robots[g.name]
        assert v["keyframes"] == len(g)
        assert (v["file"] is None) == (v["map"] is None) == (not v["placed"])
        assert (v["unplaced_reason"] is None) == v["placed"]
        if v["placed"]:  # a line per keyframe
            assert len((out / v["file"]).read_text().splitlines()) == len(g)
            assert (out / v["map"]).is_file()
    assert len(SemanticGraph.load(out / summary["merged"])) == summary["merged_objects"] > 0
    events = list(csv.DictReader((out / "events.csv").open()))
    assert summary["links_revoked"] == sum(r["kind"] == records.LINK_REVOKED for r in events)


def test_csv_headers_and_event_kinds_are_those_the_docs_give(replay):
    out, _, _ = replay
    for doc in (REPLAY_DOC, FLEET_DOC):
        given = csv_headers(doc.read_text())
        assert {"events.csv", "g2o_keyframes.csv"} <= set(given), (doc.name, given)
        for name, headers in given.items():
            if not (out / name).is_file():  # an input's table (objects.csv)
                continue
            written = (out / name).read_text().splitlines()[0]
            assert headers == {written}, (doc.name, name, headers, written)
    rows = list(csv.DictReader((out / "events.csv").open()))
    assert {r["kind"] for r in rows} <= EVENT_KINDS
    assert outputs.NOT_PLACED in {r["kind"] for r in rows}  # the lost robot
    named = set(re.findall(r"`([a-z_]+)`", file_table(REPLAY_DOC).row("events.csv")))
    assert EVENT_KINDS <= named, f"docs/replay.md's events.csv row misses {EVENT_KINDS - named}"


def test_fleet_links_g2o_is_what_the_docs_describe(fleet):
    """A vertex per placed robot (id = its index in `robots`), an edge per kept link."""
    out, info = fleet
    row = file_table(FLEET_DOC).row("links.g2o")
    assert "per placed robot" in row and "per kept link" in row, row
    vertices, edges = read_g2o(out / "links.g2o")
    assert sorted(vertices) == sorted(info["robots"].index(r) for r in info["placed"])
    kept = [lk for lk in info["links"] if lk["used"] in ("tree", "loop")]
    assert len(edges) == len(kept) >= len(vertices) - 1 > 0
    assert {frozenset(e[:2]) for e in edges} == {
        frozenset((lk["query"], lk["target"])) for lk in kept}
    assert len(SemanticGraph.load(out / "merged.json")) == info["merged_objects"]


def test_the_clause_splitter():
    assert clauses("a (b; c); d `e; f`; g") == ["a (b; c)", "d `e; f`", "g"]
    assert default_text("x; with `--backend robots` y (z; w); v") == "x; v"
    assert default_text('x; with `backend="robots"`, y') == "x"
    assert [n for t in [Table("d", "h", ["file"], [["`a`, `b/<robot>.c`", "x"]])]
            for n in sorted(t.documented())] == ["a", "b/<robot>.c"]
    assert pattern("b/<robot>.c").match("b/r-1.c")["robot"] == "r-1"
    assert not pattern("b/<robot>.c").match("b/x/y.c")
    assert csv_headers("`x.csv`: `a,b`\n\n`y.csv` `c,d`\n| `z.csv` | `e,f` |") == {
        "x.csv": {"a,b"}, "y.csv": {"c,d"}, "z.csv": {"e,f"}}
