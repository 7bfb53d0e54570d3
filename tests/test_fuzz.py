"""Mutation fuzzing through the command line (a bounded run of benchmarks/fuzz.py): no
traceback, crash or hang; every bad input one `error:` line with exit 2; no malformed file read
as data; no valid file refused."""

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
