"""The first compile of an install is said once on stderr; `sgloc warmup` compiles every kernel."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import sgloc
from sgloc import kernels
from sgloc.cli import main

#: Compiles one small kernel (the pruning of neighbor rejection) and nothing else.
_ONE_KERNEL = """
import numpy as np
from sgloc.rejection.prune_kernels import prune_bits
print(prune_bits(np.zeros((3, 1), np.uint64), np.zeros(3, np.int64), 0.5).tolist())
"""


def _run(cache: Path) -> subprocess.CompletedProcess:
    src = str(Path(sgloc.__file__).resolve().parent.parent)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=src)
    return subprocess.run([sys.executable, "-c", _ONE_KERNEL], env=env, capture_output=True,
                          text=True, timeout=600, check=True)  # fmt: skip


def test_first_compile_is_said_once(tmp_path):
    first = _run(tmp_path)
    assert "sgloc: compiling numba kernels for first use" in first.stderr
    assert str(tmp_path) in first.stderr  # where they are cached
    assert "sgloc: compiled" in first.stderr and " s (" in first.stderr  # how long it took
    assert list(tmp_path.glob("sgloc-kernels-*.compiled"))  # the install's marker
    second = _run(tmp_path)
    assert second.stdout == first.stdout
    assert "sgloc:" not in second.stderr  # loaded from the cache, nothing said


def test_warmup_command(capsys):
    assert main(["warmup"]) == 0
    out = capsys.readouterr().out
    assert "kernels" in out and f"{len(kernels.MODULES)} kernel modules" in out
    assert main(["warmup", "--help"]) == 0
    assert "Example: sgloc warmup" in capsys.readouterr().out
