"""Compile every numba kernel into the cache ahead of use (`sgloc warmup`): for container images
and read-only installs, so no later process compiles.

The kernels compile for the argument types they meet, so this runs the public calls that reach
each of them (localize with every rejection, the 6-dof model, a prepared map, register) on small
generated problems (every non-empty problem runs the kernels).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class WarmupReport:
    """What `warm_up` did: seconds in all, wall and CPU seconds compiling (0: everything came
    from the cache), the cache folder and the kernel modules it loaded."""

    seconds: float
    compile_seconds: float
    compile_cpu_seconds: float
    cache_dir: Path
    modules: list[str]


def warm_up() -> WarmupReport:
    """Run every kernel once (compiling it into the cache when it is not there yet)."""
    import sys

    from sgloc import kernels

    t0 = time.perf_counter()
    _localizations()
    _registrations()
    loaded = [m for m in kernels.MODULES if m in sys.modules]
    wall, cpu = kernels.compile_seconds()
    return WarmupReport(time.perf_counter() - t0, wall, cpu, kernels.kernel_cache_dir(), loaded)


def _localizations() -> None:
    """localize with each rejection and motion model, and against a prepared map (grown once)."""
    from sgloc import SemanticGraph, localize, prepare
    from sgloc.datasets.downloads import airsim_guo
    from sgloc.rejection import REJECTORS
    from sgloc.sim.object_world import make_two_robot_scene

    localize(*airsim_guo())  # the shipped maps (reach the acceptance's runner-up search)
    scene = make_two_robot_scene(seed=0, stretch=300.0)
    q, t = scene.query, scene.target
    for rejection in REJECTORS:
        localize(q, t, rejection=rejection)
    localize(q, t, scope="local")  # the local neighbour constraint of large problems
    localize(q, t, dof=6, max_tilt=None)
    localize(q, t, search="index")  # the candidate-search index (large maps)
    localize(q, t, class_scale="height")
    localize(q, t, descriptor="random_walk")
    small = SemanticGraph(q.positions[:20], q.labels[:20])
    localize(small, t)  # a small query: the whole-map verification
    big = make_two_robot_scene(seed=1, stretch=1800.0, view_radius=130.0).target
    prepared = prepare(SemanticGraph(big.positions[:-10], big.labels[:-10]))
    prepared.add(big.positions[-10:], big.labels[-10:])
    localize(q, prepared)


def _registrations() -> None:
    """register on matched points with outliers (consistency, pruning, RANSAC, IRLS)."""
    from sgloc import register
    from sgloc.sim.correspondences import make_correspondences

    cs = make_correspondences(300, 0.8, np.random.default_rng(0), "structured")
    register(cs.src, cs.dst, noise_bound=2.5)
    register(cs.src, cs.dst, rejection="spectral", noise_bound=2.5)
