"""Ctrl-C and SIGTERM are never lost: a signal landing in a finaliser, a compiled library's
callback, the program's start-up or a commit still ends the run with 130 / 143, one line, and
nothing written."""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sgloc.io.files import staged_folder
from sgloc.runtime import interrupts
from sgloc.runtime.interrupts import Interrupted

pytestmark = pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signals")


@pytest.fixture
def installed():
    previous = interrupts.install()
    yield
    interrupts.uninstall(previous)


def _signal_self(signum: int = signal.SIGINT) -> None:
    """Send `signum` to this process and spin until its Python handler has run (here)."""
    os.kill(os.getpid(), signum)
    end = time.monotonic() + 2.0
    while not interrupts.received() and time.monotonic() < end:
        pass


class _Finalised:
    """An object whose finaliser is where the signal lands."""

    def __del__(self) -> None:
        _signal_self()


def _spin(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


def test_a_signal_swallowed_by_a_finaliser_stops_the_commit(tmp_path, installed, capfd):
    out = tmp_path / "out"
    with pytest.raises(Interrupted):
        with staged_folder(out) as stage:
            (stage / "a.txt").write_text("x")
            _Finalised()  # dropped at once: the signal lands in its __del__
    assert not out.exists() and list(tmp_path.iterdir()) == []
    assert "Exception ignored" not in capfd.readouterr().err


def test_a_signal_in_a_compiled_callback_is_raised_after_it(installed, capfd):
    libc = ctypes.CDLL(None)
    compare_type = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_int),
                                    ctypes.POINTER(ctypes.c_int))
    calls = []

    def compare(a, b):
        calls.append(1)
        if len(calls) == 1:
            _signal_self()  # the handler raises inside the callback: C swallows it
        return a[0] - b[0]

    values = (ctypes.c_int * 8)(5, 3, 7, 1, 8, 2, 6, 4)
    with pytest.raises(Interrupted):
        libc.qsort(values, len(values), ctypes.sizeof(ctypes.c_int), compare_type(compare))
        _spin(2.0)  # raised again here, outside the callback
    assert len(calls) > 1  # the sort went on after the signal
    assert "Exception ignored" not in capfd.readouterr().err


def test_a_signal_while_held_raises_as_the_block_ends(installed):
    done = []
    with pytest.raises(Interrupted):
        with interrupts.held():
            os.kill(os.getpid(), signal.SIGTERM)
            _spin(0.05)
            done.append(1)  # the block is not cut short
    assert done == [1] and interrupts.received() == signal.SIGTERM


def test_a_swallowed_signal_still_ends_the_command_with_130_and_nothing_written(
    tmp_path, monkeypatch, capfd
):
    import sgloc.io.files
    from sgloc.cli import main

    checked = sgloc.io.files.check_output_path

    def check_then_signal(*args, **kwargs):
        result = checked(*args, **kwargs)
        _Finalised()
        return result

    monkeypatch.setattr(sgloc.io.files, "check_output_path", check_then_signal)
    out = tmp_path / "results" / "y"
    rc = main(["localize", "--example", "--out", str(out)])
    err = capfd.readouterr().err.strip().splitlines()
    assert rc == 130
    assert err == ["interrupted (SIGINT); nothing was written."]
    assert not out.exists() and not (tmp_path / "results").exists()


def test_a_signal_recorded_before_the_command_starts_ends_it_at_once(tmp_path, capfd):
    from sgloc.cli import main

    interrupts.install_early()
    try:
        os.kill(os.getpid(), signal.SIGTERM)
        _spin(0.05)
        rc = main(["localize", "--example", "--out", str(tmp_path / "y")])
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    assert rc == 143
    assert capfd.readouterr().err.strip() == "terminated (SIGTERM); nothing was written."
    assert list(tmp_path.iterdir()) == []


def _sgloc() -> list[str]:
    script = Path(sys.executable).with_name("sgloc")
    return [str(script)] if script.exists() else [sys.executable, "-m", "sgloc"]


def _loading_numpy(pid: int) -> bool:
    try:
        return "_multiarray_umath" in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs /proc")
@pytest.mark.parametrize("signum, code, line", [
    (signal.SIGINT, 130, "interrupted (SIGINT); nothing was written."),
    (signal.SIGTERM, 143, "terminated (SIGTERM); nothing was written."),
])  # fmt: skip
def test_a_signal_while_the_program_imports_its_modules(tmp_path, signum, code, line):
    proc = subprocess.Popen([*_sgloc(), "localize", "--example", "--out", "results/y"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    end = time.monotonic() + 30
    while not _loading_numpy(proc.pid) and proc.poll() is None and time.monotonic() < end:
        time.sleep(0.002)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert (proc.returncode, err.strip()) == (code, line)
    assert list(tmp_path.iterdir()) == []


def test_import_sgloc_loads_no_numeric_library():
    code = "import sys, sgloc; print(sorted(m for m in ('numpy', 'scipy', 'numba') " \
           "if m in sys.modules)); print(sgloc.SemanticGraph.__name__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["[]", "SemanticGraph"]
