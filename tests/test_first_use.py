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
