"""Mutation fuzzing through the command line (a bounded run of benchmarks/fuzz.py): no
traceback, crash or hang; every bad input one `error:` line with exit 2; no malformed file read
as data; no valid file refused. And a few cases of each command family
(benchmarks/fuzz_commands.py): signals at random moments, every output form, a command twice
into its own output, inputs of another layout; none moves or changes a file of the user's."""

import pytest


@pytest.fixture(scope="module")
def fuzz(benchmark_module):
    """benchmarks/fuzz.py."""
    return benchmark_module("fuzz")


@pytest.mark.parametrize("seed", [11, 12])
def test_fuzzed_inputs_fail_cleanly_or_read_as_data(seed, fuzz):
    counts, bad = fuzz.run_fuzz(cases=150, seed=seed, timeout=20.0)
    assert bad == []
    assert sum(counts.values()) == 150
    # Both kinds of outcome occur, so the oracle is exercised in both directions.
    assert counts["clean error, exit 2"] > 50
    assert (
        counts["read as data: localized, exit 0"] + counts["read as data: not localized, exit 1"]
        > 5
    )


def test_classification_catches_bad_outcomes(fuzz):
    assert fuzz.classify("fail", 0, "", "") == "malformed file read as data"
    assert fuzz.classify("valid", 2, "error: x\n", "") == "valid file refused"
    assert fuzz.classify("fail", 2, "error: a\nerror: b\n", "") == (
        "error not one line / wrong exit code"
    )
    assert fuzz.classify("fail", None, "", "KeyError") == "traceback"
    assert fuzz.classify("either", None, "", "hang") == "hang"
    assert fuzz.classify("fail", 2, "Usage: sgloc localize [OPTIONS]\nerror: x\n", "") == (
        "clean error, exit 2"
    )


def test_a_hang_is_caught_by_the_time_limit(monkeypatch, fuzz):
    import time

    import sgloc.cli

    monkeypatch.setattr(sgloc.cli, "main", lambda argv: time.sleep(5))
    rc, _out, _err, exc = fuzz.run_case(["localize"], timeout=0.2)
    assert rc is None and exc == "hang"


def test_hostile_keyframes_links_and_save_files_through_the_python_api(fuzz):
    counts, bad = fuzz.run_session_fuzz(cases=80, seed=11, timeout=20.0)
    assert bad == []
    assert sum(counts.values()) == 80
    assert counts["clean error"] > 40 and counts["accepted"] > 3


# -- the command families (benchmarks/fuzz_commands.py), a few cases of each ---------------------
@pytest.fixture(scope="module")
def commands(benchmark_module):
    """benchmarks/fuzz_commands.py."""
    return benchmark_module("fuzz_commands")


@pytest.fixture(scope="module")
def user_folder(commands, tmp_path_factory):
    """(work folder, the user's folder template with sgloc's own earlier outputs in it)."""
    import matplotlib

    matplotlib.use("Agg")
    work = tmp_path_factory.mktemp("fuzz-commands")
    return work, commands.make_template(work)


def test_signals_at_random_moments_are_never_lost_and_leave_nothing(commands, user_folder):
    work, template = user_folder
    per_command, bad = commands.run_signal_family(
        work, template, trials=4, seed=3, commands=["localize --json", "build-graph", "fleet"])
    assert bad == []
    assert all(sum(c.values()) == 4 for c in per_command.values())
    interrupted = sum(c["interrupted, nothing written"] for c in per_command.values())
    assert interrupted >= 4  # most signals land while the command works


def test_every_output_form_is_written_where_named_or_refused_in_one_line(commands, user_folder):
    import numpy as np

    work, template = user_folder
    counts, bad = commands.run_output_family(
        work, template, options=["localize --json", "build-graph -o", "replay --out-bag",
                                 "localize --rerun"],
        rng=np.random.default_rng(5), cases=12)
    assert bad == []
    assert counts["written"] >= 1 and counts["refused (one line)"] >= 1


def test_a_command_twice_into_its_own_output(commands, user_folder):
    work, template = user_folder
    counts, bad = commands.run_twice_family(
        work, template, names=["localize --out", "localize --json", "build-graph -o .json"])
    assert bad == []
    assert sum(counts.values()) == 3


def test_inputs_of_another_layout_are_one_clear_error(commands, user_folder):
    work, template = user_folder
    names = [n for n, _argv, expect in commands.LAYOUTS if expect == "fail"][::4]
    counts, bad = commands.run_layout_family(work, template, names=names)
    assert bad == []
    assert counts["clean error, exit 2"] == len(names)


def test_signal_classes_catch_lost_signals_and_leftovers(commands):
    import signal

    run = commands.SignalRun
    sigint, sigterm = signal.SIGINT, signal.SIGTERM
    line = "interrupted (SIGINT); nothing was written."
    assert commands.classify_signal(run(0, "", True, False, 3.0), sigint, True, False, []) == (
        "lost signal")
    assert commands.classify_signal(run(0, "", True, True, 3.0), sigint, True, False, []) == (
        "finished before the signal")
    assert commands.classify_signal(run(130, line, True, False, 1.0), sigint, False, True,
                                    []) == "interrupted, nothing written"
    assert commands.classify_signal(run(130, line, True, False, 1.0), sigint, False, False,
                                    []) == "written though interrupted"
    assert commands.classify_signal(run(130, line, True, False, 1.0), sigterm, False, True,
                                    []) == "wrong exit code or message"
    assert commands.classify_signal(run(130, line, True, False, 1.0), sigint, False, True,
                                    ["notes.txt"]) == "user files moved or changed"
    assert commands.classify_signal(run(130, line, True, False, 1.0, left=True), sigint, False,
                                    True, []) == "workers left running"
    assert commands.classify_signal(run(None, "", True, False, 99.0), sigint, False, True,
                                    []) == "hang"
    early = 'Traceback (most recent call last):\n  File "<frozen io>", line 53\nKeyboardInterrupt\n'
    assert commands.classify_signal(run(1, early, True, False, 0.1), sigint, False, True,
                                    []) == "KeyboardInterrupt in Python's start-up, nothing written"
    late = early.replace("<frozen io>", "/x/src/sgloc/cli/app.py")
    assert commands.classify_signal(run(1, late, True, False, 0.1), sigint, False, True,
                                    []) == "traceback"
    tb = "Traceback (most recent call last):\n" + line
    assert commands.classify_signal(run(130, tb, True, False, 1.0), sigint, False, True,
                                    []) == "traceback"


def test_a_false_not_written_by_sgloc_is_caught(commands):
    o = commands.Outcome
    first = o(0, "", "", 1.0, [], ["results/a.pdf"])
    second = o(2, "error: results/a.pdf: exists and was not written by sgloc; give a new path.\n",
               "", 0.1)
    assert commands.classify_twice(first, second, True) == "false 'not written by sgloc'"
    clear = o(2, "error: results/a.json: exists; --json writes a new file only.\n", "", 0.1)
    assert commands.classify_twice(first, clear, True) == "refused clearly"
    assert commands.classify_output(o(2, "error: x\n", "", 9.0), "results/x.svg", "file",
                                    2.0) == "refused after the work"
