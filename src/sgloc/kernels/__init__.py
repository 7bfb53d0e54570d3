"""The compiled (numba) kernels' runtime: where the kernels are cached, the first-compile
notice. The kernels themselves live beside the stage code they serve (`MODULES`), which calls
them directly; the plain numpy references they are checked against live with the tests
(`tests/references/`).

Importing this package is cheap: numba is imported, and each kernel compiled, only when a
kernel module is first imported (callers import them inside functions). Compiled code is cached
on disk (`cache=True`): next to their sources when that directory is writable, otherwise in numba's
per-user cache directory; `NUMBA_CACHE_DIR` overrides both. When none of them is writable (a
read-only install and home), the kernels are cached in a folder of the temporary directory, or,
failing that, compiled in every process without a cache; either is said once on stderr.

Every problem runs the compiled kernels (a stage handles an empty problem itself), so the same
inputs give the same bits in every process whatever it ran before (the references and the
kernels agree to rounding, not always bit for bit). Loading numba and the cached kernels costs
a process about 0.3 s once. Every kernel is declared with
`sgloc.kernels.dispatch.kernel`: one compiled specialisation, whatever flags (read-only or
writable) its array arguments carry.

Rule for every kernel here: no numba sort or search (np.sort, np.argsort, ndarray.sort,
np.searchsorted, ...) inside a cached kernel: sort in numpy before the call, or write the loop
(a binary search, marking). numba names the helpers it generates for them by their element
types and a per-process counter, not by what they do (sort or argsort, left or right side), and
the names are shared between modules: two kernel modules cached by different processes can
each define one name with its own body, and a process loading both runs the first body for
both (wrong results, or a crash). `benchmarks/kernel_cache.py` (run by the test suite) checks
that no cached kernel holds such a helper, that no numba function is defined by two modules
with two bodies, and that the modules loaded together from one cache, in any order, equal
their references.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

from sgloc.kernels.cache import ensure_cache_dir

ensure_cache_dir()

_BLAS_CONTROLLER = None

#: The kernel modules (each compiled on first use, `cache=True`).
#: Each lives beside the stage code it serves.
MODULES = (
    "sgloc.maps.canonical_kernels", "sgloc.rejection.clique_kernels",
    "sgloc.consistency.pairwise_kernels", "sgloc.acceptance.evidence_kernels",
    "sgloc.estimation.fit_kernels", "sgloc.matching.similarity_kernels",
    "sgloc.maps.neighbor_kernels",
    "sgloc.consistency.local_kernels", "sgloc.rejection.prune_kernels",
    "sgloc.estimation.ransac_kernels", "sgloc.acceptance.runner_up_kernels",
    "sgloc.rejection.spectral_kernels", "sgloc.consistency.triangle_kernels",
    "sgloc.descriptors.walk_kernels",
)  # fmt: skip


def kernel_cache_dir() -> Path:
    """The folder numba caches these kernels in: NUMBA_CACHE_DIR when set, else this
    package's `__pycache__` when the package folder is writable, else numba's per-user cache
    folder (as numba chooses)."""
    from numba.core import config

    if config.CACHE_DIR:
        return Path(config.CACHE_DIR)
    here = Path(__file__).resolve().parent
    if os.access(here, os.W_OK):
        return here / "__pycache__"
    from numba.misc.appdirs import AppDirs

    return Path(AppDirs(appname="numba", appauthor=False).user_cache_dir)


def compiled_marker() -> Path:
    """The file whose presence says this install's kernels have compiled into `kernel_cache_dir()`
    (named after the kernel sources' paths, sizes and times, numba's and Python's versions: a
    new install or an upgrade compiles, and is said, anew)."""
    import hashlib

    import numba

    here = Path(__file__).resolve().parent
    parts = [numba.__version__, sys.version, str(here)]
    for name in MODULES:  # the source files, found without importing their packages
        st = here.parent.joinpath(*name.split(".")[1:]).with_suffix(".py").stat()
        parts.append(f"{name}:{st.st_size}:{st.st_mtime_ns}")
    digest = hashlib.sha1("|".join(parts).encode()).hexdigest()[:16]
    return kernel_cache_dir() / f"sgloc-kernels-{digest}.compiled"


class _CompileNotice:
    """numba compile listener (`watch_compiles`): on an install's first compile, one line on
    stderr saying what compiles and where it is cached, and at exit how long it took."""

    def __init__(self) -> None:
        self.depth, self.start, self.total = 0, 0.0, 0.0
        self.cpu_start, self.cpu = 0.0, 0.0
        self.by_thread: dict[int, float] = {}  # wall seconds compiling, by thread
        self.kernels: set[str] = set()
        self.said = False

    def on_start(self, ev) -> None:
        if self.depth == 0 and not _ours(ev):
            return  # another library's (or the user's) numba function: not ours to say
        if self.depth == 0:
            self.start, self.cpu_start = time.perf_counter(), time.process_time()
            if not self.said and not compiled_marker().exists():
                self.said = True
                name = getattr(ev.data.get("dispatcher"), "__qualname__", "kernels")
                print(f"sgloc: compiling numba kernels for first use ({name}, ...), once per "
                      f"install; cached in {kernel_cache_dir()}. `sgloc warmup` compiles them all "
                      "ahead.", file=sys.stderr, flush=True)  # fmt: skip
                import atexit

                atexit.register(self.summary)
        self.depth += 1

    def on_end(self, ev) -> None:
        if self.depth == 0:
            return  # the end of a compile `on_start` left alone
        self.depth -= 1
        if _ours(ev):  # not numba's own helpers compiled on the way
            self.kernels.add(ev.data["dispatcher"].py_func.__qualname__)
        if self.depth == 0:
            took = time.perf_counter() - self.start
            self.total += took
            self.cpu += time.process_time() - self.cpu_start
            tid = threading.get_ident()
            self.by_thread[tid] = self.by_thread.get(tid, 0.0) + took
            if self.said:
                _touch(compiled_marker())

    def summary(self) -> None:
        n = len(self.kernels)
        print(f"sgloc: compiled {n} numba kernel{'s' * (n != 1)} in {self.total:.1f} s "
              f"({self.cpu:.1f} s CPU; first use: later runs load them from the cache).",
              file=sys.stderr, flush=True)  # fmt: skip


def _ours(ev) -> bool:
    """Whether a numba compile event is of one of sgloc's kernels."""
    func = getattr(ev.data.get("dispatcher"), "py_func", None)
    return getattr(func, "__module__", "").startswith("sgloc.")


def _touch(path: Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch()
    except OSError:
        pass  # a read-only cache: the notice is said again next time, nothing else changes


_NOTICE: list[_CompileNotice] = []


def watch_compiles() -> None:
    """Listen to numba's compiles (once per process; each kernel module calls this when
    imported): an install's first compile is said on stderr, with its duration at exit."""
    if _NOTICE:
        return
    from numba.core import event

    class Notice(_CompileNotice, event.Listener):
        pass

    _NOTICE.append(Notice())
    event.register("numba:compile", _NOTICE[0])


def compile_seconds() -> tuple[float, float]:
    """(wall, CPU) seconds this process has spent compiling kernels ((0, 0): none compiled)."""
    return (_NOTICE[0].total, _NOTICE[0].cpu) if _NOTICE else (0.0, 0.0)


def thread_compile_seconds() -> float:
    """Wall seconds the calling thread has spent compiling kernels (0: none compiled)."""
    return _NOTICE[0].by_thread.get(threading.get_ident(), 0.0) if _NOTICE else 0.0


def one_blas_thread():
    """A context holding BLAS to one thread, for the small matrix products of the numpy paths:
    a second BLAS thread on a busy machine costs more than it gives (threadpoolctl, set up
    once per process)."""
    global _BLAS_CONTROLLER
    if _BLAS_CONTROLLER is None:
        from threadpoolctl import ThreadpoolController

        _BLAS_CONTROLLER = ThreadpoolController()
    return _BLAS_CONTROLLER.limit(limits=1, user_api="blas")
