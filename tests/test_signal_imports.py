"""A signal during an import is raised after the import (a raise inside a compiled module's
initialisation becomes an ImportError and can abort the interpreter at exit); an interruption
that a compiled library turned into its own error (SystemError, ImportError) still ends the
command with 130 and its one line."""

from __future__ import annotations

import signal
import sys
import time

import pytest

import sgloc.cli.localize_cmd
from sgloc.cli import main
from sgloc.runtime import interrupts
from sgloc.runtime.interrupts import Interrupted

pytestmark = pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signals")

SLOW_MODULE = """import os, signal, time
os.kill(os.getpid(), signal.SIGINT)
end = time.monotonic() + 0.3
while time.monotonic() < end:
    pass
DONE = True
"""


@pytest.fixture
def installed():
    previous = interrupts.install()
    yield
    interrupts.uninstall(previous)


def test_a_signal_during_an_import_is_raised_after_it(tmp_path, installed, monkeypatch):
    (tmp_path / "sgloc_slow_import.py").write_text(SLOW_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        with pytest.raises(Interrupted):
            import sgloc_slow_import  # noqa: F401
            end = time.monotonic() + 2.0
            while time.monotonic() < end:  # the raise comes here, once the import is done
                pass
        assert sys.modules["sgloc_slow_import"].DONE  # imported whole
    finally:
        sys.modules.pop("sgloc_slow_import", None)


def test_an_interruption_turned_into_a_library_error_exits_130(monkeypatch, capsys):
    def interrupted_inside_a_compiled_call(*args, **kwargs):
        raise SystemError("CPUDispatcher returned a result with an exception set") from (
            Interrupted(signal.SIGINT))

    monkeypatch.setattr(sgloc.cli.localize_cmd, "localize_files",
                        interrupted_inside_a_compiled_call)
    assert main(["localize", "--example"]) == 130
    assert capsys.readouterr().err.strip() == "interrupted (SIGINT); nothing was written."


def test_a_finalisers_error_is_printed_before_a_signal_and_not_after():
    """After a signal, the error of a finaliser (an object the signal left half-built in a
    compiled library) is not printed: the run is being abandoned with its one line."""
    code = """
import os, signal, time
from sgloc.runtime import interrupts
class Half:
    def __del__(self):
        raise AttributeError("half-built " + self.name)
def drop(name):
    h = Half(); h.name = name; del h
interrupts.install()
drop("before")
try:
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(5)
except interrupts.Interrupted:
    pass
drop("after")
print("received", interrupts.received())
"""
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert "received 2" in p.stdout, p.stderr
    assert "half-built before" in p.stderr and "half-built after" not in p.stderr, p.stderr


def test_a_signal_during_a_kernel_compile_is_raised_after_it(tmp_path):
    """A signal that arrives while numba compiles (or loads from its cache) one of sgloc's
    kernels is raised as the compile ends, not inside numba's or LLVM's code (whose objects,
    left half-built, can crash the interpreter when freed)."""
    (tmp_path / "sgloc_signal_kernel.py").write_text(
        "from sgloc.kernels.dispatch import kernel\n\n"
        "@kernel\ndef twice(x):\n    return 2.0 * x\n")
    code = """
import os, signal, sys, traceback
from numba.core import event
from sgloc.runtime import interrupts
import sgloc_signal_kernel

class SignalOnCompile(event.Listener):
    def on_start(self, ev):
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(100000):  # bytecodes for the handler to run on
            pass
    def on_end(self, ev):
        pass

interrupts.install()
event.register("numba:compile", SignalOnCompile())
try:
    sgloc_signal_kernel.twice(1.5)
    print("not raised")
except interrupts.Interrupted as e:
    files = [f.filename for f in traceback.extract_tb(e.__traceback__)]
    print("compiled", len(sgloc_signal_kernel.twice.overloads))
    print("raised after" if files[-1].endswith("interrupts.py") else "raised in " + files[-1])
"""
    import subprocess

    env = {**__import__("os").environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
           "PYTHONPATH": f"{tmp_path}:{__import__('os').environ.get('PYTHONPATH', '')}"}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, env=env)
    assert "raised after" in p.stdout and "compiled 1" in p.stdout, p.stdout + p.stderr
