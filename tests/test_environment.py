"""sgloc in a hostile environment: a read-only install with no writable cache folder, and the
same bits for the same inputs whatever the process did before."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parent.parent / "src"

PRUNE = """
import numpy as np
from sgloc.rejection.prune_kernels import prune_bits
from sgloc.consistency.pairwise import pack_rows
m = 5
M = np.ones((m, m), bool); np.fill_diagonal(M, False)
print(prune_bits(pack_rows(M), M.sum(1).astype(np.int64), 0.5).tolist())
"""


def _read_only_install(tmp_path: Path) -> tuple[Path, dict]:
    """A copy of the package whose kernels folder cannot hold a cache (its `__pycache__` is a
    file: unwritable even for root), with a home and cache folder that cannot be created."""
    root = tmp_path / "site"
    shutil.copytree(SRC / "sgloc", root / "sgloc",
                    ignore=shutil.ignore_patterns("__pycache__", "sample_data"))  # fmt: skip
    (root / "sgloc" / "kernels" / "__pycache__").write_text("not a folder")
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, so nothing can be created under it")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "SGLOC_KERNEL"))}
    env.update(PYTHONPATH=str(root), HOME=str(blocker / "home"),
               XDG_CACHE_HOME=str(blocker / "cache"), PYTHONDONTWRITEBYTECODE="1")  # fmt: skip
    return root, env


def _run(code: str, env: dict) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          timeout=300)  # fmt: skip


def test_read_only_install_caches_kernels_in_the_temporary_directory(tmp_path):
    _, env = _read_only_install(tmp_path)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env["TMPDIR"] = str(tmp)
    run = _run(PRUNE + "from sgloc.estimation import fit_kernels\n", env)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[0, 1, 2, 3, 4]"
    assert "no locator" not in run.stderr and "Traceback" not in run.stderr
    assert run.stderr.count("sgloc: no writable cache folder") == 1
    cached = list(tmp.glob("sgloc-numba-cache-*/**/*.nbi"))
    assert cached, "the kernels were not cached in the temporary directory"


def test_nothing_writable_runs_the_kernels_uncached(tmp_path):
    _, env = _read_only_install(tmp_path)
    blocked = str(tmp_path / "blocker" / "tmp")  # Python would fall back to /tmp from TMPDIR
    run = _run(f"import tempfile; tempfile.tempdir = {blocked!r}\n" + PRUNE, env)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[0, 1, 2, 3, 4]"
    assert "no locator" not in run.stderr and "Traceback" not in run.stderr
    assert run.stderr.count("compiling them in every process") == 1


REPRO = """
import hashlib, sys
import numpy as np
from sgloc import localize
from sgloc.datasets.downloads import airsim_guo
q, t = airsim_guo()
if sys.argv[1] == "warm":  # a process that worked before: numba loaded, many problems solved
    import sgloc.estimation.fit_kernels  # noqa: F401
    for seed in range(30):
        localize(q.subgraph(np.arange(40)), t, seed=seed)
r = localize(q, t, seed=7)
print(hashlib.sha256(r.transform.tobytes() + np.float64(r.confidence).tobytes()
                     + np.asarray(r.matches).tobytes()).hexdigest())
"""


def _fingerprint(seed: int) -> str:
    """A hash of the bits of one localize result (a process-pool task)."""
    import hashlib

    import numpy as np

    from sgloc import localize
    from sgloc.datasets.downloads import airsim_guo

    q, t = airsim_guo()
    r = localize(q, t, seed=seed)
    data = r.transform.tobytes() + np.float64(r.confidence).tobytes()
    return hashlib.sha256(data + np.asarray(r.matches).tobytes()).hexdigest()


def test_same_bits_in_a_fresh_and_a_busy_process():
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    runs = [subprocess.run([sys.executable, "-c", REPRO, how], env=env, capture_output=True,
                           text=True, timeout=600) for how in ("cold", "warm")]  # fmt: skip
    for run in runs:
        assert run.returncode == 0, run.stderr
    assert runs[0].stdout == runs[1].stdout


@pytest.mark.parametrize("method", ["spawn", "fork"])
def test_same_bits_in_a_process_pool_and_serially(method):
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    import sgloc.estimation.fit_kernels  # noqa: F401  (this process has the kernels loaded)

    seeds = [1, 2, 3]
    serial = [_fingerprint(s) for s in seeds]
    with ProcessPoolExecutor(2, mp_context=mp.get_context(method)) as pool:
        assert list(pool.map(_fingerprint, seeds)) == serial


def test_same_bits_in_threads_and_on_dask():
    """The same seeds give the same bits run serially, from several threads at once, and as
    tasks on a Dask cluster (an in-process cluster here)."""
    from concurrent.futures import ThreadPoolExecutor

    distributed = pytest.importorskip("distributed")
    from sgloc.runtime.tasks import run_all

    seeds = [1, 2, 3, 4]
    serial = [_fingerprint(s) for s in seeds]
    with ThreadPoolExecutor(4) as pool:
        assert list(pool.map(_fingerprint, seeds)) == serial
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=2,
                            dashboard_address=None) as client:  # fmt: skip
        assert run_all(seeds, _fingerprint, scheduler=client) == serial
