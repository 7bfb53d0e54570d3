"""A fresh process: what a localization loads (no module it does not need), with the same bits."""

import subprocess
import sys

import numpy as np


def test_poisson_tail_matches_scipy_stats_without_importing_it():
    """The acceptance's NFA far in the Poisson tail (where pdtrc underflows) equals
    scipy.stats.poisson.logsf's, bit for bit, and a process computing it never imports
    scipy.stats (~0.3 s of a fresh process)."""
    from scipy.special import pdtrc
    from scipy.stats import poisson

    from sgloc.acceptance.chance import log10_nfa

    ln10 = np.log(10.0)
    for k in (250, 600, 900, 2500, 12_000):
        for lam in (1e-12, 0.3, 4.0, 37.5)[: 3 + (k > 250)]:
            assert pdtrc(k - 3, lam) <= 1e-280  # the far tail, computed as logsf
            got = log10_nfa(k, 0, lam, n_tests=1e6, sample=2)
            tail = float(poisson.logsf(k - 3, max(lam, 1e-12)) / ln10)
            assert got == float(np.log(1e6) / ln10 + tail), (k, lam)
    code = (
        "import sys; from sgloc.acceptance.chance import log10_nfa; "
        "v = log10_nfa(400, 1000, 1.0); print(v < -280, 'scipy.stats' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "False"]


def test_a_kernel_compiles_once_whatever_the_array_flags():
    """A read-only array (a graph's positions) and a writable one, or a literal integer and an
    int64, are one compiled specialisation of a kernel: one compile on first use, one load in
    a fresh process, and no later compile for arguments met in another order."""
    from sgloc.matching.similarity_kernels import class_blocks, inverse_norms

    rng = np.random.default_rng(0)
    D = rng.random((40, 5))
    frozen = D.copy()
    frozen.flags.writeable = False
    order = np.argsort(rng.integers(0, 3, 40), kind="stable")
    labels = np.sort(rng.integers(0, 3, 40))
    got = [class_blocks(T, order, labels) for T in (D, frozen)]
    for a, b in zip(*got, strict=True):
        np.testing.assert_array_equal(a, b)
    assert inverse_norms(D).tobytes() == inverse_norms(frozen).tobytes()
    assert len(class_blocks.signatures) == 1
    assert len(inverse_norms.signatures) == 1  # also called by class_blocks


def test_kernels_hold_one_specialisation_and_return_writable_arrays():
    """After a localization and a registration, every loaded kernel holds one specialisation,
    and none returns a read-only array (a caller may write into what a kernel returns)."""
    from numba import types
    from numba.core.dispatcher import Dispatcher

    from sgloc import kernels, localize, register
    from sgloc.sim.object_world import make_two_robot_scene

    scene = make_two_robot_scene(seed=0, stretch=300.0)
    localize(scene.query, scene.target)
    localize(scene.query, scene.target, rejection="spectral")
    rng = np.random.default_rng(1)
    src = rng.uniform(-20, 20, (60, 3))
    register(src, src + [1.0, 2.0, 0.0], noise_bound=1.0)
    seen = 0
    for name in kernels.MODULES:
        module = sys.modules.get(name)
        for f in vars(module).values() if module else ():
            if not isinstance(f, Dispatcher) or not f.overloads:
                continue
            seen += 1
            assert len(f.overloads) == 1, (f.__qualname__, list(f.overloads))
            (result,) = f.overloads.values()
            ret = result.signature.return_type
            parts = ret.types if isinstance(ret, types.BaseTuple) else (ret,)
            assert not any(isinstance(p, types.Array) and not p.mutable for p in parts), (
                f.__qualname__,
                ret,
            )
    assert seen >= 15


def test_import_sgloc_leaves_the_fleet_layer_and_settings_files_alone():
    """`import sgloc` (a fresh process's first cost) loads neither the fleet layer (online
    session, pose graph: `sgloc.localize_fleet` imports it on first use), the YAML reader,
    scipy.stats or scipy.spatial (a localization needs neither);
    `sgloc.localize_fleet` is still the fleet's function."""
    code = (
        "import sys, sgloc; heavy = [m for m in ('sgloc.online.fleet', 'sgloc.online', 'yaml', "
        "'scipy.stats', 'scipy.spatial') if m in sys.modules]; "
        "from sgloc.online.fleet import localize_fleet; "
        "print(heavy, sgloc.localize_fleet is localize_fleet)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[] True"
