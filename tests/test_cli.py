"""The command line: results, one-line errors with exit code 2, help with examples."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from sgloc import SemanticGraph
from sgloc.cli import app, main
from sgloc.cli.app import EXIT_NOT_LOCALIZED


def test_localize_writes_json(airsim_dir, tmp_path, capsys):
    d = airsim_dir
    out = tmp_path / "res.json"
    rc = main(["localize", str(d / "cloud1.pcd"), str(d / "cloud2.pcd"), "--json", str(out)])
    assert rc == 0
    res = json.loads(out.read_text())
    assert res["accepted"] and res["n_matches"] > 10
    T = np.array(res["T_target_query"])
    assert np.linalg.norm(T[:3, 3]) < 5.0  # ground truth is the identity
    printed = capsys.readouterr().out
    assert "T_target_query" in printed and "ransac" in printed


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ")
    return err[0]


def test_missing_file_is_one_line_exit_2(tmp_path, capsys):
    rc = main(["localize", str(tmp_path / "a.pcd"), str(tmp_path / "b.pcd")])
    assert rc == 2
    assert "no such file" in one_line_error(capsys)


def test_malformed_file_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2")
    rc = main(["localize", str(bad), str(bad)])
    assert rc == 2
    assert "bad.json" in one_line_error(capsys)


def test_unknown_descriptor_is_one_line_exit_2(airsim_dir, capsys):
    d = airsim_dir
    rc = main(["localize", str(d / "cloud1.pcd"), str(d / "cloud2.pcd"), "--descriptor", "x"])
    assert rc == 2
    assert "unknown descriptor" in one_line_error(capsys)


def test_not_localized_is_its_own_exit_code(tmp_path, capsys):
    rng = np.random.default_rng(0)
    SemanticGraph(rng.uniform(0, 60, (12, 3)), np.zeros(12, int)).save(tmp_path / "q.json")
    SemanticGraph(rng.uniform(0, 60, (12, 3)), np.ones(12, int)).save(tmp_path / "t.json")
    rc = main(["localize", str(tmp_path / "q.json"), str(tmp_path / "t.json")])
    assert rc == EXIT_NOT_LOCALIZED == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("not localized: ")


def test_nan_in_file_is_one_line_exit_2(tmp_path, capsys):
    p = tmp_path / "nan.json"
    p.write_text(
        json.dumps(
            {"positions": [[0, 0, 0], [1, "NaN", 0], [2, 2, 2]], "labels": [0, 0, 0]}
        ).replace('"NaN"', "NaN")
    )
    rc = main(["localize", str(p), str(p)])
    assert rc == 2
    assert "NaN" in one_line_error(capsys)


@pytest.mark.parametrize("command", [c.name for c in app.registered_commands])
def test_every_command_help_has_an_example(command, capsys):
    assert main([command, "--help"]) == 0
    assert "Example" in capsys.readouterr().out


@pytest.mark.parametrize("command", [c.name for c in app.registered_commands])
def test_usage_lines_read_as_usual(command, capsys):
    """`QUERY`, `[SOURCE]...`, `GRAPH...`: no braces, no doubled brackets or dots."""
    assert main([command, "--help"]) == 0
    usage = next(ln for ln in capsys.readouterr().out.splitlines() if "Usage:" in ln).strip()
    assert re.fullmatch(r"Usage: sgloc [\w-]+ \[OPTIONS\]( \[?[A-Z][A-Z0-9_]*\]?(\.\.\.)?)*",
                        usage), usage


def usage_error(capsys) -> str:
    """Assert the usage line plus one error line on stderr; return the error line."""
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 2, captured.err
    assert err[0].startswith("Usage: sgloc") and err[1].startswith("error: ")
    assert "Traceback" not in captured.err + captured.out
    return err[1]


@pytest.mark.parametrize(
    "args, expected",
    [
        (["localize", "{d}/cloud1.pcd"], "Missing argument"),
        (["localize"], "Missing argument"),
        (["localize", "--bogus", "{d}/cloud1.pcd", "{d}/cloud2.pcd"], "--bogus"),
        (["localize", "{d}/cloud1.pcd", "{d}/cloud2.pcd", "--seed", "-1"], "--seed"),
        (["localize", "{d}/cloud1.pcd", "{d}/cloud2.pcd", "--ransac-threshold", "x"], "--ransac"),
        (["fleet", "{d}/cloud1.pcd", "{d}/cloud2.pcd", "--workers", "two"], "--workers"),
        (["experiment", "table", "--trials", "abc"], "--trials"),
        (["build-graph", "airsim"], "Missing"),
        (["no-such-command"], "no-such-command"),
    ],
)
def test_usage_errors_are_usage_plus_one_line_exit_2(data_dir, capsys, args, expected):
    d = str(data_dir / "airsim_guo")
    rc = main([a.replace("{d}", d) for a in args])
    assert rc == 2
    assert expected in usage_error(capsys)


def test_version(capsys):
    assert main(["--version"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith("sgloc ") and len(out.splitlines()) == 1


def test_click_is_not_imported_by_sgloc():
    """click is not a declared dependency (typer may bundle its own copy)."""
    import sgloc

    src = Path(sgloc.__file__).parent
    pattern = re.compile(r"^\s*(import|from) click\b", re.M)
    offenders = [p.name for p in src.rglob("*.py") if pattern.search(p.read_text())]
    assert offenders == []


def test_unwritable_output_is_one_line_exit_2(data_dir, capsys):
    d = data_dir / "airsim_guo"
    args = [str(d / "cloud1.pcd"), str(d / "cloud2.pcd"), "--json", "/dev/null/out.json"]
    assert main(["localize", *args]) == 2
    assert "/dev/null" in one_line_error(capsys)


def test_fifo_graph_is_refused_without_blocking(tmp_path, data_dir, capsys):
    import os

    fifo = tmp_path / "pipe.pcd"
    os.mkfifo(fifo)
    assert main(["localize", str(fifo), str(data_dir / "airsim_guo" / "cloud2.pcd")]) == 2
    assert "not a regular file" in one_line_error(capsys)


def test_experiment_help_names_every_experiment():
    """The help's names are written out in the command module (importing the experiments
    would slow every command's start); they are the experiments'."""
    from sgloc.cli.experiment_cmd import NAMES
    from sgloc.experiments import EXPERIMENTS

    assert tuple(NAMES) == tuple(EXPERIMENTS)


def test_command_line_import_leaves_other_commands_work_alone():
    """`import sgloc.cli` (every command's start) loads no other command's machinery: numba
    and the kernels load on first use; the experiments, simulator, fleet layer, extraction,
    scipy.spatial / ndimage / special, YAML and image libraries only when a command uses them."""
    import subprocess
    import sys

    heavy = ("numba", "sgloc.maps.canonical_kernels", "sgloc.evaluation", "sgloc.experiments.job",
             "sgloc.sim.demo", "sgloc.online.fleet", "sgloc.extraction", "scipy.spatial",
             "scipy.ndimage", "scipy.special", "yaml", "PIL", "matplotlib", "dask")
    code = f"import sys, sgloc.cli; print([m for m in {heavy!r} if m in sys.modules])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_main_called_from_python_leaves_the_collector_alone(data_dir, capsys):
    """Only the `sgloc` program tunes the garbage collector (a short-lived process); a caller
    of `main(argv)` keeps its own settings and nothing of its is frozen."""
    import gc

    before = (gc.get_threshold(), gc.get_freeze_count(), gc.isenabled())
    d = data_dir / "airsim_guo"
    assert main(["localize", str(d / "cloud1.pcd"), str(d / "cloud2.pcd")]) == 0
    assert (gc.get_threshold(), gc.get_freeze_count(), gc.isenabled()) == before


def test_program_exit_codes_are_the_commands(data_dir):
    """`python -m sgloc` (the program path: collector tuned, objects frozen at exit) exits with
    the command's code and prints as `main(argv)` does."""
    import subprocess
    import sys

    d = data_dir / "airsim_guo"
    ok = subprocess.run([sys.executable, "-m", "sgloc", "localize", str(d / "cloud1.pcd"),
                         str(d / "cloud2.pcd"), "--format", "json"],
                        capture_output=True, text=True)  # fmt: skip
    assert ok.returncode == 0 and json.loads(ok.stdout)["accepted"] is True
    bad = subprocess.run([sys.executable, "-m", "sgloc", "localize", str(d / "missing.pcd"),
                          str(d / "cloud2.pcd")], capture_output=True, text=True)  # fmt: skip
    assert bad.returncode == 2 and bad.stderr.startswith("error: ")
