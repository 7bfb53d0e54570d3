"""numba's on-disk cache never mixes up the kernel modules: compiled one module per process into
a fresh cache, then loaded together in one process in several orders, each kernel still equals
its numpy reference (`benchmarks/kernel_cache.py`; about 30-60 s, mostly compiling)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def kernel_cache(benchmark_module):
    """benchmarks/kernel_cache.py."""
    return benchmark_module("kernel_cache")


def test_cached_kernels_loaded_together_in_any_order_equal_references(tmp_path, kernel_cache):
    helpers = kernel_cache.populate(tmp_path, workers=2)
    assert set(helpers) == set(kernel_cache.MODULES) and any(helpers.values())
    # The names whose body numba's symbol does not fix stay out of every kernel ...
    assert kernel_cache.sort_search_helpers(tmp_path) == {}
    # ... and no other numba function is defined twice with two bodies: a clash waiting for the
    # per-process counters of two compiling processes to line up.
    assert kernel_cache.clashing_helpers(helpers) == {}
    for names in kernel_cache.orders(kernel_cache.MODULES, n_random=2):
        run = kernel_cache.run_probe(names, tmp_path)
        assert run.passed, f"{' '.join(names)}: {run.why}"


def test_every_cached_kernel_module_is_checked(kernel_cache):
    import sgloc

    package = Path(sgloc.__file__).parent
    compiled = re.compile(r"^@(kernel\b|njit\(cache=True)", re.MULTILINE)
    cached = {".".join(("sgloc", *p.relative_to(package).with_suffix("").parts))
              for p in package.rglob("*.py") if compiled.search(p.read_text())}  # fmt: skip
    assert cached == set(kernel_cache.MODULES) == set(kernel_cache.CHECKS)


def test_sort_and_argsort_helpers_are_one_name_with_two_bodies(kernel_cache):
    """The hazard itself (numba 0.68): np.sort and np.argsort of an int64 array compile helpers
    of one name (up to the counter) and different bodies; the check sees them."""
    import numpy as np
    from numba import njit

    sort, argsort = njit(lambda x: np.sort(x)), njit(lambda x: np.argsort(x))
    x = np.array([3, 1, 2])
    assert np.array_equal(sort(x), [1, 2, 3]) and np.array_equal(argsort(x), [1, 2, 0])
    helpers = {
        "sorts": kernel_cache.defined_numba_functions([sort]),
        "argsorts": kernel_cache.defined_numba_functions([argsort]),
    }
    clashes = kernel_cache.clashing_helpers(helpers)
    assert any("quicksort" in name for name in clashes), sorted(clashes)


def test_clashing_helpers_flags_one_name_with_two_bodies(kernel_cache):
    helpers = {"a": {"f": "1", "g": "2"}, "b": {"f": "1", "g": "3"}, "c": {"h": "4"}}
    assert kernel_cache.clashing_helpers(helpers) == {"g": ["a", "b"]}
