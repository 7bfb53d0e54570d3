"""What the CLI tells a user to do is in CLI form, and a recorded run's keyframe table
(`objects.csv` of the plain layout) is refused as a map with the command that reads it."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest

from sgloc.cli import main
from sgloc.errors import GraphFileError
from sgloc.evaluation.replay_scenarios import world_scenario
from sgloc.io.plain_layout import write_plain_layout
from sgloc.io.table import read_table

SRC = Path(__file__).resolve().parents[1] / "src" / "sgloc"

#: Advice in Python's form: a verb, then `name='text'`, `name=None|True|False` or `name=<...>`.
PYTHON_ADVICE = re.compile(
    r"(?<![\w-])(?:try|use|set|give|pass|e\.g\.)\s+(?!--)[a-z][a-z_0-9]*="
    r"(?:'[^']*'|None|True|False|<[a-z ]+>|\{[^}]*!r\})"
)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("advice") / "run"
    write_plain_layout(d, world_scenario().logs)
    return d


@pytest.mark.parametrize("extra", [[], ["--set", "scale=auto"]])
def test_a_replays_objects_table_is_refused_as_a_map(run, extra, capsys):
    q, t = run / "world0" / "objects.csv", run / "world1" / "objects.csv"
    assert main(["localize", str(q), str(t), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert str(q) in err[0] and "`stamp` column" in err[0]
    assert f"sgloc replay {run}" in err[0]


def test_fleet_refuses_it_too_and_a_lone_table_names_the_run_placeholder(run, tmp_path, capsys):
    lone = tmp_path / "sightings.csv"
    lone.write_text((run / "world0" / "objects.csv").read_text())
    with pytest.raises(GraphFileError, match=r"sgloc replay RUN"):
        read_table(lone)
    assert main(["fleet", str(lone), str(run / "world1" / "objects.csv"), "--workers", "0",
                 "--out", str(tmp_path / "f")]) == 2
    assert "`stamp` column" in capsys.readouterr().err
    assert not (tmp_path / "f").exists()


def test_a_map_table_without_stamps_still_reads(tmp_path):
    p = tmp_path / "map.csv"
    p.write_text("x,y,z,class\n1,2,3,4\n5,6,7,1\n")
    pos, lab = read_table(p)
    np.testing.assert_array_equal(lab, [4, 1])
    assert pos.shape == (2, 3)


def _message_strings(tree: ast.AST):
    """(line, text) of every string and f-string that is not a docstring."""
    docs = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                and isinstance(body[0].value, ast.Constant):  # fmt: skip
            docs.add(id(body[0].value))
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):
            yield node.lineno, "".join(
                str(v.value) if isinstance(v, ast.Constant)
                else "{" + ast.unparse(v.value) + ("!r" if v.conversion == 114 else "") + "}"
                for v in node.values
            )
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and id(node) not in docs:  # fmt: skip
            yield node.lineno, node.value


def test_advice_in_messages_is_in_cli_form():
    """A setting a message tells the user to change reads `--set name=value` or `--preset
    name`; Python's spelling may follow only inside `(Python: ...)`."""
    bad = []
    for path in sorted(SRC.rglob("*.py")):
        for line, text in _message_strings(ast.parse(path.read_text())):
            text = re.sub(r"Python: [^)]*", "", text)
            bad += [f"{path.relative_to(SRC)}:{line}: {m.group(0)}"
                    for m in PYTHON_ADVICE.finditer(text)]
    assert not bad, bad


def test_the_scene_hint_says_both_forms():
    from sgloc.maps.graph import SemanticGraph
    from sgloc.maps.scale import STREET_UNIT, scene_hint

    rng = np.random.default_rng(0)
    g = SemanticGraph(rng.uniform(0, 15, (200, 3)) * [1, 1, 0.01], rng.integers(0, 4, 200))
    hint = " ".join(scene_hint(g, g, STREET_UNIT).split())
    assert "try --preset room" in hint and "--set scale=auto" in hint
    assert "--set scale=<metres>" in hint and "Python: preset='room'" in hint
