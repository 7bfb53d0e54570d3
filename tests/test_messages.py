"""Messages in the user's language: command-line syntax for settings, close names suggested,
a units hint for maps that are not in metres."""

from __future__ import annotations

import pytest

from sgloc import SemanticGraph, localize
from sgloc.cli import main


def _err(capsys) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:")
    return lines[0]


def test_misspelt_setting_gets_the_close_name_and_no_python_class(capsys):
    assert main(["localize", "--example", "--set", "tua=3"]) == 2
    err = _err(capsys)
    assert "did you mean 'tau'?" in err and "LocalizerConfig" not in err


@pytest.mark.parametrize("text", ["none", "None", "null"])
def test_none_is_written_as_python_users_write_it(text, capsys):
    assert main(["localize", "--example", "--set", f"distinct_ratio={text}", "--format",
                 "json"]) == 0  # fmt: skip


def test_maps_in_millimetres_get_a_units_hint(airsim_graphs):
    q, t = airsim_graphs
    mm = [SemanticGraph(g.positions * 1000.0, g.labels) for g in (q, t)]
    r = localize(*mm)
    assert (
        not r.success
        and "expects metres" in r.reason
        and "divide its positions by 1000" in (r.reason)
    )
    assert "expects metres" not in localize(q, SemanticGraph(q.positions[:5], q.labels[:5])).reason


def test_not_localized_reasons_give_the_command_line_syntax(airsim_graphs):
    q, t = airsim_graphs
    far = SemanticGraph(t.positions[:40] + [5000.0, 0.0, 0.0], t.labels[:40])
    r = localize(q, far, min_similarity=0.99)
    assert not r.success and "--set min_similarity=0.5" in r.reason
    r = localize(q, SemanticGraph(t.positions[:60], t.labels[:60]))
    assert not r.success and "0 inliers lie within" not in r.reason
    assert "agree with the best alignment" in r.reason
