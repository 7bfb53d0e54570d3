"""Compiled (numba) kernels of the hot loops, each with a plain numpy reference in its caller.

Importing this package is cheap: numba is imported, and each kernel compiled, only when a
kernel module is first imported (callers import them inside functions). Compiled code is cached
on disk (`cache=True`): next to the sources when that directory is writable, otherwise in numba's
per-user cache directory; `NUMBA_CACHE_DIR` overrides both. When none of them is writable (a
read-only install and home), the kernels are cached in a folder of the temporary directory, or,
failing that, compiled in every process without a cache; either is said once on stderr.

Loading numba and the cached kernels costs a process about 0.7 s once. Problems up to
SMALL_PROBLEM matches therefore run the numpy references (`use_compiled`): a one-shot run on small
maps (the command line) never pays that. The choice depends on the problem's size only, never on
what the process did before, so the same inputs give the same bits in every process (the
references and the kernels agree to rounding, not bit for bit). The price: a process solving
many small problems runs the slower references (Guo's Airsim pair: about 4.4 ms of CPU a call
against 1.9 ms compiled); `FORCE = "compiled"` trades the start-up for that.

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

from sgloc.kernels.cache import ensure_cache_dir

ensure_cache_dir()

#: Problems up to this size (matches) run the numpy references, larger ones the kernels.
SMALL_PROBLEM = 1500
#: "compiled" or "reference" forces that path for every size (tests); None: the rule above.
FORCE: str | None = None


def use_compiled(size: int) -> bool:
    """Whether a problem of `size` matches runs the compiled kernel (else the numpy reference,
    equal to rounding): a pure function of the size, so a result never depends on what the
    process computed before."""
    if FORCE is not None:
        return FORCE == "compiled"
    return size > SMALL_PROBLEM


_BLAS_CONTROLLER = None


def one_blas_thread():
    """A context holding BLAS to one thread, for the small matrix products of the numpy paths:
    a second BLAS thread on a busy machine costs more than it gives (threadpoolctl, set up
    once per process)."""
    global _BLAS_CONTROLLER
    if _BLAS_CONTROLLER is None:
        from threadpoolctl import ThreadpoolController

        _BLAS_CONTROLLER = ThreadpoolController()
    return _BLAS_CONTROLLER.limit(limits=1, user_api="blas")
