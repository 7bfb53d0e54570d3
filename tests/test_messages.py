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
        not r.accepted
        and "expects metres" in r.reason
        and "divide its positions by 1000" in (r.reason)
    )
    assert "expects metres" not in localize(q, SemanticGraph(q.positions[:5], q.labels[:5])).reason


def test_not_localized_reasons_give_the_command_line_syntax(airsim_graphs):
    q, t = airsim_graphs
    far = SemanticGraph(t.positions[:40] + [5000.0, 0.0, 0.0], t.labels[:40])
    r = localize(q, far, min_similarity=0.99)
    assert not r.accepted and "--set min_similarity=0.5" in r.reason
    r = localize(q, SemanticGraph(t.positions[:60], t.labels[:60]))
    assert not r.accepted and "0 inliers lie within" not in r.reason
    assert "agree with the best alignment" in r.reason


def test_several_robots_name_the_command_line_flag(tmp_path, capsys):
    for robot in ("A", "B"):
        (tmp_path / robot).mkdir()
        (tmp_path / robot / "airsim.txt").write_text("")
    assert main(["build-graph", "airsim", str(tmp_path), "-o", str(tmp_path / "g.json")]) == 2
    err = _err(capsys)
    assert "--robot NAME" in err


def test_build_graph_help_example_runs(kitti_dir, tmp_path, capsys, monkeypatch):
    import re
    import shlex

    assert main(["build-graph", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.replace("│", " ").split())
    example = re.search(r"Example: (sgloc build-graph .*?-o A\.json)", text).group(1)
    argv = shlex.split(example.replace('"$(sgloc data path kitti00)"', str(kitti_dir)))[1:]
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 0 and (tmp_path / "A.json").is_file()


@pytest.mark.parametrize("command", [[], ["localize"], ["experiment"], ["demo"]])
def test_help_shows_no_python_types_for_flags_and_lists(command, capsys):
    assert main([*command, "--help"]) == 0
    out = capsys.readouterr().out
    assert "<bool>" not in out and "list[" not in out


def test_command_list_summaries_are_whole_sentences(capsys):
    """Rich help keeps a docstring's line breaks: the summaries are its first paragraph joined."""
    from sgloc.cli import app

    assert main(["--help"]) == 0
    summaries = {info.name: info.short_help for info in app.registered_commands}
    assert all(text and "\n" not in text for text in summaries.values())
    assert "localize one in the other and compare" in summaries["demo"]


def test_from_csv_refuses_trial_options_it_would_ignore(tmp_path, capsys):
    out = tmp_path / "t"
    base = ["experiment", "table", "--descriptors", "histogram", "--rejections", "none",
            "--workers", "1", "--out", str(out)]  # fmt: skip
    assert main([*base, "--trials", "1"]) == 0
    capsys.readouterr()
    again = ["experiment", "table", "--from-csv", str(out / "trials.csv"), "--out",
             str(tmp_path / "again")]  # a new folder: `out` holds the input trials.csv
    assert main([*again, "--trials", "50"]) == 2
    assert "--trials: --from-csv runs no trials (its trials.csv holds 1 per setting" in _err(capsys)
    assert main(again) == 0


@pytest.mark.parametrize("content", [
    b"x,y,z,class\n1,2,3,4\n",  # a graph table
    b"stamp,robot,event,detail\n1.0,a,placed,b\n",  # a replay's events.csv
    b"seed,descriptor,rejection,ransac_threshold,localized,failed\n",  # the header alone
    b"seed,descriptor,rejection,ransac_threshold,localized,failed\nabc,h,none,5,True,False\n",
    b"PK\x03\x04\xb8\xff\x00",  # not text
])  # fmt: skip
def test_from_csv_refuses_a_file_that_is_not_trials_csv_before_any_work(content, tmp_path,
                                                                        capsys):
    src = tmp_path / "t.csv"
    src.write_bytes(content)
    out = tmp_path / "out"
    assert main(["experiment", "table", "--from-csv", str(src), "--out", str(out)]) == 2
    err = _err(capsys)
    assert err.startswith(f"error: {src}") and "trials.csv" in err
    assert not out.exists()


def test_random_walk_localizes_the_shipped_example_with_its_defaults(airsim_graphs):
    r = localize(*airsim_graphs, descriptor="random_walk", seed=0)
    assert r.accepted, r.reason


def test_docs_speak_of_the_software_not_of_the_machine_they_ran_on():
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    pattern = re.compile(r"agents|this (?:2-core )?machine|shared machine|machine (?:is|was) "
                         r"shared|2-core machine", re.IGNORECASE)  # fmt: skip
    for doc in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        hits = pattern.findall(doc.read_text())
        assert not hits, f"{doc.name}: {hits}"
    assert "SGLOC_DATA_URL" in (root / "README.md").read_text()


@pytest.mark.parametrize("workers", ["0", "-1"])
def test_workers_below_one_are_refused(workers, capsys):
    assert main(["experiment", "table", "--workers", workers]) == 2
    assert "--workers" in capsys.readouterr().err


def test_help_paragraphs_are_not_cut_mid_sentence(capsys):
    assert main(["localize", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "each --set NAME=VALUE, then --descriptor / --rejection" in out
    from sgloc.cli import app

    info = next(i for i in app.registered_commands if i.name == "localize")
    assert all("\n" not in p for p in info.help.split("\n\n"))


@pytest.mark.parametrize("argv", [
    ["localize", "--example", "--json"], ["localize", "--example", "--rerun"],
    ["build-graph", "airsim", "robot", "-o"], ["serve", "--seconds", "0.1", "--state"],
])  # fmt: skip
def test_a_file_option_given_a_folder_name_with_a_slash_is_refused(argv, tmp_path, capsys,
                                                                   monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main([*argv, "new/"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[0].startswith("Usage: sgloc") and len(lines) == 2
    assert "new/ ends with a slash, which names a folder" in lines[1]
    assert list(tmp_path.iterdir()) == []  # no file named `new` (the path type drops the /)
