"""Guard of numba's on-disk cache: kernel modules loaded from one cache, in any order in one
process, each still equal its numpy reference (no wrong result, no crash).

Each kernel module is first compiled in a fresh process of its own, with a fresh
NUMBA_CACHE_DIR (as happens when a user's runs touch the kernels one by one). Then fresh
processes load the modules from that cache in the given orders, calling each module's kernels
right after its import and comparing them with the numpy references (tests/references, which
load no kernel module); a process that loaded anything by compiling instead of from the cache
fails too (the check would prove nothing).

Whether two cached modules clash depends on numba's per-process function counter lining up in
the processes that compiled them, so two order-free checks come first: no cached kernel holds a
numba sort/search helper, and no numba function is defined by two modules with two bodies.
`--shift MODULE=N` lines counters up on purpose (a module whose helpers clash with another's
then gives wrong results or crashes in the load orders).

    python benchmarks/kernel_cache.py                   # forward, reverse, 4 random orders
    python benchmarks/kernel_cache.py --pairs           # also every ordered pair, one process each
    python benchmarks/kernel_cache.py --probe sgloc.rejection.clique_kernels \
        sgloc.consistency.triangle_kernels                  # one process, this order
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import sgloc
from sgloc import kernels

#: The kernel modules with compiled (cached) code, each beside the stage it serves.
MODULES = kernels.MODULES
#: The numpy references of the kernels live with the tests.
TESTS = Path(__file__).resolve().parents[1] / "tests"


def _references():
    """The `references` package of the tests (tests/references)."""
    if str(TESTS) not in sys.path:
        sys.path.insert(0, str(TESTS))
    import references
    import references.acceptance
    import references.consistency
    import references.descriptors
    import references.estimation
    import references.maps
    import references.matching
    import references.rejection

    return references


def _graph(m: int, p: float, seed: int) -> np.ndarray:
    """A random symmetric bool adjacency (m,m), empty diagonal."""
    R = np.triu(np.random.default_rng(seed).random((m, m)) < p, 1)
    return R | R.T


def _matches(m: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    from sgloc.sim.correspondences import make_correspondences

    cs = make_correspondences(m, 0.7, np.random.default_rng(seed), "structured")
    return np.ascontiguousarray(cs.src), np.ascontiguousarray(cs.dst)


def check_canonical() -> None:
    import types

    from sgloc.maps.canonical import CanonicalPair, canonical_order, without_duplicates
    from sgloc.maps.graph import SemanticGraph
    from sgloc.pipeline.config import LocalizerConfig

    ref = _references().maps
    rng = np.random.default_rng(2)
    pos = rng.uniform(-3, 3, (300, 3)).round(1)  # ties
    pos[::5] = pos[1::5] + 1e-4  # duplicates
    g = SemanticGraph(pos, np.repeat(np.arange(2), 150))
    pair = CanonicalPair(g, g, LocalizerConfig())
    cand = rng.integers(0, len(pair.query), (200, 2))
    r = types.SimpleNamespace(candidates=cand, scores=rng.integers(0, 3, 200) / 3.0,
                              survivors=cand[:50], matches=cand[:20])  # fmt: skip
    plain = types.SimpleNamespace(**{k: np.copy(v) for k, v in vars(r).items()})
    pair.restore(r)
    ref.restore(pair, plain)
    order = canonical_order(g)
    got = (order, without_duplicates(g, order), pair.query_order, *vars(r).values())
    want = (ref.canonical_order(g), ref.without_duplicates(g, order),
            ref.canonical_form(g, pair.classes)[0], *vars(plain).values())  # fmt: skip
    assert len(got[1]) < 300, "duplicates"
    for a, b in zip(got, want, strict=True):
        assert np.array_equal(a, b), "canonical form"


def check_clique() -> None:
    from sgloc.consistency.pairwise import pack_rows
    from sgloc.rejection import clique_kernels as clique

    core_numbers, greedy_clique = (getattr(_references().rejection, name)
                                   for name in ("core_numbers", "greedy_clique"))  # fmt: skip

    for m, p in [(70, 0.3), (200, 0.8)]:
        R = _graph(m, p, m)
        bits, degree = pack_rows(R), R.sum(axis=1)
        core = clique.core_numbers(bits, degree)
        assert np.array_equal(core, core_numbers(R)), "core numbers"
        rank = core * (m + 1) + degree
        seeds = np.argsort(-rank, kind="stable")[:16]
        got = clique.greedy_clique(bits, rank, seeds)
        assert np.array_equal(got, greedy_clique(R, rank, seeds)), "greedy clique"


def check_pairwise() -> None:
    from sgloc.consistency import pairwise_kernels as consistency
    from sgloc.consistency.pairwise import unpack_rows

    consistency_bool = _references().consistency.consistency_bool

    src, dst = _matches(150, 1)
    for neighbor in (False, True):
        bits, degree = consistency.consistency_bits(src, dst, 4.0, neighbor)
        form = "neighbor" if neighbor else "distance"
        ref = consistency_bool(src, dst, 4.0, form)
        assert np.array_equal(unpack_rows(bits, len(src)), ref), form
        assert np.array_equal(degree, ref.sum(axis=1)), form


def check_fit() -> None:
    import sgloc.estimation.fit_kernels  # noqa: F401 (loaded first, then called through the estimation)
    from sgloc.estimation import irls_refine, weighted_kabsch
    from sgloc.geometry import apply, random_rigid_transform

    rng = np.random.default_rng(2)
    src = rng.uniform(-80, 80, (60, 3)) * [1, 1, 0.1]
    dst = apply(random_rigid_transform(rng, 50.0, 5.0), src) + rng.normal(0, 0.5, (60, 3))
    dst[:10] += rng.normal(0, 10, (10, 3))
    T0, w, classes = weighted_kabsch(src, dst), rng.uniform(0.5, 2, 60), rng.integers(0, 4, 60)
    reference = _references().estimation.irls_refine
    for kw in ({"dof": 6}, {"dof": 4, "max_tilt": 15.0}, {"dof": 6, "classes": classes}):
        got, want = irls_refine(src, dst, T0, w, **kw), reference(src, dst, T0, w, **kw)
        assert np.abs(got - want).max() < 1e-9, f"irls {kw}"


def check_local() -> None:
    from sgloc.consistency.local import RadiusGrid
    from sgloc.consistency.local_kernels import local_counts, local_prune

    ref = _references().consistency
    local_counts_reference, prune_local_reference = ref.local_counts, ref.prune_local

    src, dst = _matches(400, 11)
    for radius in (20.0, 1e4):
        g = RadiusGrid.build(src, radius)
        grid = (g.order, g.cell_start, g.point_cell, g.near_cells, radius)
        got = local_counts(src, dst, *grid, 5.0, False)
        ref = local_counts_reference(src, dst, 5.0, radius)
        assert all(np.array_equal(a, b) for a, b in zip(got, ref, strict=True)), "local counts"
        kept = local_prune(src, dst, *grid, 5.0, False, 0.5, 0)
        assert np.array_equal(kept, prune_local_reference(src, dst, 5.0, 0.5, radius)), "local"


def check_similarity() -> None:
    import sgloc.matching.similarity_kernels  # noqa: F401 (loaded first, then called through matching)
    from sgloc.matching.candidates import MatchingConfig, match_flagged

    rng = np.random.default_rng(3)
    dq = rng.random((60, 16)) * (rng.random((60, 16)) < 0.5)
    dt = rng.random((80, 16)) * (rng.random((80, 16)) < 0.5)
    lq, lt = rng.integers(0, 3, 60) * 7, rng.integers(0, 3, 80) * 7
    cfg = MatchingConfig(min_similarity=0.1, top_k=3)
    ma, sa, fa = match_flagged(dq, dt, lq, lt, cfg, 0.8)
    mb, sb, fb = _references().matching.match_flagged(dq, dt, lq, lt, cfg, 0.8)
    assert len(ma) > 20 and np.array_equal(ma, mb) and np.array_equal(fa, fb), "candidates"
    assert np.abs(sa - sb).max() < 1e-12, "similarities"


def check_evidence() -> None:
    from sgloc.acceptance import (
        ChanceModel,
        evidence_kernels,  # noqa: F401 (loaded first, then as acceptance)
        inlier_spread,
    )
    from sgloc.acceptance.assessment import squared_residuals_of
    from sgloc.acceptance.chance import chance_terms, object_nfa_over_radii
    from sgloc.acceptance.mirror import reflect_across_line
    from sgloc.maps.graph import SemanticGraph

    reference = _references().acceptance

    rng = np.random.default_rng(9)
    tpos = rng.uniform(-60, 60, (200, 3)) * [1, 1, 0.1]
    qpos = tpos[:120] + rng.normal(0, 1.0, (120, 3))
    qlab = rng.integers(0, 4, 120)
    qi = np.sort(rng.integers(0, 120, 150))  # some objects with two candidates, half true
    cand = np.stack([qi, np.where(rng.random(150) < 0.5, qi, rng.integers(0, 200, 150))], 1)
    res2 = np.sum((qpos[cand[:, 0]] - tpos[cand[:, 1]]) ** 2, axis=1)
    rows = rng.random(150) < 0.7
    model = ChanceModel(SemanticGraph(tpos, rng.integers(0, 4, 200)), 5.0, 4)
    counts, used = model.near_counts_and_targets(qpos, cand[:, 1])
    tlab = model.labels[cand[:, 1]].astype(np.int64)
    out = {}
    for path, stage in (("reference", reference), ("compiled", None)):
        out[path] = (
            (stage.object_nfa_over_radii if stage else object_nfa_over_radii)(
                res2, qi, rows, 120, 5.0, (2.0, 0.5), 150, 1e4, 2),
            (stage.chance_terms if stage else chance_terms)(
                qlab, counts, used, qi, tlab, res2 < 25.0, model),
            (stage.inlier_spread if stage else inlier_spread)(qpos[:40], 4),
            (stage.reflect_across_line if stage else reflect_across_line)(qpos, qpos[:30]),
            (stage.squared_residuals_of if stage else squared_residuals_of)(
                np.eye(4), qpos, tpos[:120]),
        )  # fmt: skip
    ref, got = out["reference"], out["compiled"]
    assert got[0] == ref[0], "per-object fits"
    assert got[1][0] == ref[1][0] > 0 and got[1][3] == ref[1][3], "chance counts"
    assert np.allclose(got[1], ref[1], rtol=1e-12), "chance sums"
    assert abs(got[2] - ref[2]) < 1e-9 * ref[2], "spread"
    assert np.abs(got[3] - ref[3]).max() < 1e-9, "reflection"
    assert np.allclose(got[4], ref[4], rtol=1e-12), "residuals"


def check_neighbor() -> None:
    from sgloc.acceptance import ChanceModel
    from sgloc.maps.graph import SemanticGraph
    from sgloc.maps.neighbor_kernels import near_class_counts

    rng = np.random.default_rng(4)
    pts = rng.uniform(-60, 60, (300, 3)) * [1, 1, 0.1]
    labels = rng.integers(0, 5, 300)
    moved = np.concatenate([pts[:100] + [3.0, 4.0, 0.0], rng.uniform(-90, 90, (100, 3))])
    usage = rng.integers(0, 4, 300).astype(np.float64)
    references = _references()
    model = ChanceModel(SemanticGraph(pts, labels), 5.0, 5)
    got = near_class_counts(moved, model.positions, labels.astype(np.int64), 5, 5.0, usage)
    ref = references.acceptance.near_counts(model, moved, (None, usage))
    assert got[0].sum() > 100
    for a, b in zip(got, ref, strict=True):
        assert np.array_equal(a, b), "near counts"
    from sgloc.descriptors import DistanceHistogramDescriptor
    from sgloc.maps.neighbor_kernels import distance_histograms

    desc = DistanceHistogramDescriptor()
    rows = np.arange(300)
    got = distance_histograms(pts, rows, pts, labels.astype(np.int64), 5, 40.0, 16, 0.8)
    assert got.sum() > 300
    want = references.descriptors.distance_histograms(desc, pts, labels, 5)
    assert np.array_equal(got, want), "distance histograms"


def check_prune() -> None:
    from sgloc.consistency.pairwise import pack_rows
    from sgloc.rejection.prune_kernels import prune_bits

    prune_by_support_reference = _references().rejection.prune_by_support

    for m, p in [(65, 0.3), (300, 0.6)]:
        R = _graph(m, p, m + 1)
        for eta in (0.2, 0.5, 0.8):
            got = prune_bits(pack_rows(R), R.sum(axis=1), eta)
            assert np.array_equal(got, prune_by_support_reference(R, eta)), f"prune {eta}"


def check_ransac() -> None:
    from sgloc.estimation import RansacConfig, ransac_compiled, ransac_reference
    from sgloc.geometry import apply, make_transform

    rng = np.random.default_rng(5)
    src = rng.uniform([-80, -80, 0], [80, 80, 10], (120, 3))
    c, s = np.cos(0.7), np.sin(0.7)
    T = make_transform(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), np.array([5.0, 3, 1]))
    dst = apply(T, src) + rng.normal(0, 0.3, src.shape)
    dst[:50] = rng.uniform([-100, -100, 0], [100, 100, 10], (50, 3))
    for scoring in ("msac", "count"):
        cfg = RansacConfig(threshold=3.0, scoring=scoring, dof=4, max_tilt=15.0)
        a = ransac_compiled(src, dst, cfg, np.random.default_rng(1))
        b = ransac_reference(src, dst, cfg, np.random.default_rng(1))
        assert np.array_equal(a.inliers, b.inliers), f"ransac inliers ({scoring})"
        assert np.abs(a.transform - b.transform).max() < 1e-9, f"ransac transform ({scoring})"


def check_runner_up() -> None:
    from sgloc.acceptance import (
        AcceptanceConfig,
        pair_consistency,
        rivals,
        runner_up_kernels,  # noqa: F401 (loaded first, then called as acceptance does)
    )
    from sgloc.acceptance import runner_up as search_runner_up
    from sgloc.consistency.pairwise import ConsistentPairs
    from sgloc.estimation import rot_z
    from sgloc.geometry import apply, make_transform

    rng = np.random.default_rng(6)
    src = rng.uniform(-80, 80, (120, 3)) * [1, 1, 0.05]
    T = make_transform(rot_z(np.array([0.3]))[0], np.array([5.0, -2.0, 0.5]))
    T_alt = make_transform(rot_z(np.array([1.9]))[0], np.array([-30.0, 12.0, 0.0]))
    dst = np.concatenate([apply(T, src[:50]), apply(T_alt, src[50:90]), src[90:] + 40.0])
    dst += rng.normal(0, 0.5, dst.shape)
    exclude = np.sum((apply(T, src) - dst) ** 2, axis=1) < 100.0
    cfg = AcceptanceConfig()
    bits, _ = pair_consistency(src, dst, 5.0)
    out = {}
    compiled = rivals._compiled_yaw_runner_up
    for path in ("reference", "compiled"):  # the same draws, searched in numpy or compiled
        if path == "reference":
            rivals._compiled_yaw_runner_up = _references().acceptance.yaw_runner_up
        try:
            edges = ConsistentPairs(bits)
            rng = np.random.default_rng(7)
            out[path] = search_runner_up(src, dst, T, exclude, bits, edges, 5.0, cfg, rng, 4)
        finally:
            rivals._compiled_yaw_runner_up = compiled
    ref, got = out["reference"], out["compiled"]
    assert got[0] == ref[0] >= 30, "runner-up inliers"
    assert np.abs(got[1] - ref[1]).max() < 1e-9, "runner-up transform"


def check_spectral() -> None:
    from sgloc.consistency.pairwise import pack_rows
    from sgloc.rejection import SpectralRejector
    from sgloc.rejection import spectral_kernels as spectral

    rej = SpectralRejector()
    src, dst = _matches(300, 8)
    M = _references().consistency.consistency_bool(src, dst, rej.tau, "distance")
    bits, degree = pack_rows(M), M.sum(axis=1)
    csr = spectral.affinity_csr(src, dst, bits, degree, float(rej.sigma))
    x = spectral.leading_eigenvector(*csr, 200, 1e-6)
    order = np.argsort(-x, kind="stable")
    got = spectral.greedy_select(x, order, bits, rej.min_ratio, rej.min_agreement)
    want = _references().rejection.spectral(rej, src, dst)
    assert len(got) > 50 and np.array_equal(got, want), "spectral"


def check_triangle() -> None:
    from sgloc.consistency import triangle_kernels as triangles
    from sgloc.consistency.pairwise import pack_rows

    for m, p in [(5, 0.5), (130, 0.1), (300, 0.6)]:
        R = _graph(m, p, m + 2)
        bits, degree = pack_rows(R), R.sum(axis=1)
        ii, jj = triangles.upper_edges(bits, degree)
        ref_i, ref_j = np.nonzero(np.triu(R))
        assert np.array_equal(ii, ref_i) and np.array_equal(jj, ref_j), "upper edges"
        assert triangles.common_counts(bits, ii, jj) == (R[ref_i] & R[ref_j]).sum(), "common"
        keep = np.random.default_rng(m).random(m) < 0.7
        keep_words = pack_rows(keep[None, :])[0]
        counts = triangles.upper_counts(bits, keep_words, keep)
        K = np.triu(R & keep[:, None] & keep[None, :], 1)
        assert np.array_equal(counts, K.sum(axis=1)), "upper counts"
        row_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        ks = np.arange(0, row_start[-1], 3, dtype=np.int64)
        ki, kj = triangles.edges_at(bits, keep_words, row_start, ks)
        ref_i, ref_j = np.nonzero(K)
        assert np.array_equal(ki, ref_i[ks]) and np.array_equal(kj, ref_j[ks]), "edges at"


def check_walk() -> None:
    from sgloc.descriptors import (
        RandomWalkDescriptor,
        walk_kernels,  # noqa: F401 (loaded first, then by the descriptor)
    )
    from sgloc.maps.graph import SemanticGraph

    random_walks = _references().descriptors.random_walks

    rng = np.random.default_rng(10)
    g = SemanticGraph(rng.uniform(0, 60, (40, 3)), rng.integers(0, 5, 40))
    for length, n_classes in [(3, 5), (4, 50)]:  # dense and sorted counting
        rw = RandomWalkDescriptor(n_walks=200, walk_length=length)
        got = rw(g, n_classes, np.random.default_rng(11))
        ref = random_walks(rw, g, n_classes, np.random.default_rng(11))
        for field in ("indptr", "indices", "data"):
            assert np.array_equal(getattr(got, field), getattr(ref, field)), f"walks {field}"


def short_name(module: str) -> str:
    """`sgloc.maps.neighbor_kernels` -> `neighbor`: the name of a kernel module's check."""
    return module.rsplit(".", 1)[1].removesuffix("_kernels")


#: Each kernel module's check (`check_<short name>`).
CHECKS: dict[str, Callable[[], None]] = {
    name: globals()[f"check_{short_name(name)}"] for name in MODULES
}

#: numba's generated sort and search helpers: their symbol names hold the element types and a
#: per-process counter, not what the code does (sort or argsort, left or right side), so two
#: cached modules compiled in different processes can define one name with two bodies.
SORT_SEARCH_HELPER = re.compile(rb"_ZN5numba(?:(?!_ZN)\w)*?(?:sort|search)(?:(?!_ZN)\w)*?B\d+v\d+B")
#: The per-process counter in a numba symbol name (an Itanium ABI tag "v<n>").
_UID_TAG = re.compile(r"B\d+v\d+")
#: The ".<n>" LLVM appends to a global's name already taken in the module (constants).
_GLOBAL_SUFFIX = re.compile(r"(@[\w.$]+?)(?:\.\d+)+(?=[\s,()]|$)")
#: A function definition of numba's own (not sgloc's) in LLVM IR: its name and its body.
_NUMBA_DEFINE = re.compile(r'^define [^@]*@"?(_ZN5numba[^"(]+)"?\((.*?)^}', re.M | re.S)


def sort_search_helpers(cache_dir: Path) -> dict[str, set[str]]:
    """Per cache file under cache_dir, the numba sort/search helper symbols its object code
    holds (`sgloc.kernels` keeps none)."""
    found = {}
    for path in sorted(Path(cache_dir).rglob("*.nbc")):
        names = {m.decode() for m in SORT_SEARCH_HELPER.findall(path.read_bytes())}
        if names:
            found[path.name] = names
    return found


def defined_numba_functions(functions: Iterable[Any]) -> dict[str, str]:
    """The numba functions the compiled code of `functions` (numba dispatchers compiled in
    this process) defines: the name without the counter tag -> a hash of the body (counter
    tags, global suffixes, attribute and metadata numbers dropped)."""
    defined = {}
    for function in functions:
        for ir in function.inspect_llvm().values():
            for symbol, body in _NUMBA_DEFINE.findall(ir):
                body = _GLOBAL_SUFFIX.sub(r"\1", _UID_TAG.sub("", body))
                body = re.sub(r"[#!]\d+", "", body)
                defined[_UID_TAG.sub("", symbol)] = hashlib.sha1(body.encode()).hexdigest()[:16]
    return defined


def numba_helpers(names: list[str]) -> dict[str, dict[str, str]]:
    """Per kernel module (compiled in this process), `defined_numba_functions` of its kernels."""
    from numba.core.dispatcher import Dispatcher

    out = {}
    for name in names:
        found = vars(sys.modules[name]).values()
        out[name] = defined_numba_functions(v for v in found if isinstance(v, Dispatcher))
    return out


def clashing_helpers(helpers: dict[str, dict[str, str]]) -> dict[str, list[str]]:
    """The numba functions (name without the counter tag) that two kernel modules define with
    different bodies -> those modules: one counter value away from a clash in a process that
    loads both from the cache."""
    bodies: dict[str, dict[str, str]] = {}
    for module, defined in helpers.items():
        for symbol, digest in defined.items():
            bodies.setdefault(symbol, {})[module] = digest
    return {s: sorted(b) for s, b in bodies.items() if len(set(b.values())) > 1}


def cache_misses() -> dict[str, int]:
    """Per loaded kernel module, the specialisations its dispatchers compiled (not loaded)."""
    from numba.core.dispatcher import Dispatcher

    out = {}
    for name in MODULES:
        module = sys.modules.get(name)
        if module is None:
            continue
        found = [v for v in vars(module).values() if isinstance(v, Dispatcher)]
        out[name] = sum(sum(d.stats.cache_misses.values()) for d in found)
    return out


def probe(names: list[str], expect_cached: bool) -> None:
    """In this process: import each kernel module in turn and check it at once. Compiling
    (not expect_cached): then print the numba functions each module defines (`numba_helpers`)."""
    _references()  # the references load no kernel module: none loads unasked
    for name in names:
        CHECKS[name]()
        print(f"ok {name}", flush=True)
    if expect_cached:
        compiled = {k: v for k, v in cache_misses().items() if v}
        assert not compiled, f"compiled instead of loaded from the cache: {compiled}"
    else:
        print("helpers " + json.dumps(numba_helpers(names)), flush=True)


@dataclass
class ProbeRun:
    """One `probe` process: passed, why not, and (compiling) the numba functions defined."""

    passed: bool
    why: str
    helpers: dict[str, dict[str, str]]


def run_probe(
    names: list[str], cache_dir: Path, compile: bool = False, uid_start: int | None = None
) -> ProbeRun:
    """`probe(names)` in a fresh process on NUMBA_CACHE_DIR=cache_dir. uid_start: the first
    value of numba's per-process function counter (to line counters up on purpose)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    src_dir = str(Path(sgloc.__file__).resolve().parent.parent)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src_dir, env.get("PYTHONPATH")) if p)
    cmd = [sys.executable, __file__, "--probe", *names] + ["--compile"] * compile
    if uid_start is not None:
        cmd += ["--uid-start", str(uid_start)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
    lines = proc.stdout.splitlines()
    helpers = {}
    for line in lines:
        if line.startswith("helpers "):
            helpers = json.loads(line.removeprefix("helpers "))
    if proc.returncode == 0:
        return ProbeRun(True, "", helpers)
    passed = [line.split()[1] for line in lines if line.startswith("ok ")]
    failed = names[len(passed)] if len(passed) < len(names) else "(after the checks)"
    tail = (proc.stderr.strip().splitlines() or [""])[-1]
    how = f"signal {-proc.returncode}" if proc.returncode < 0 else f"exit {proc.returncode}"
    return ProbeRun(False, f"{failed} failed after {passed}: {how}: {tail}", helpers)


def populate(
    cache_dir: Path,
    names: tuple[str, ...] = MODULES,
    uid_start: dict[str, int] | None = None,
    workers: int = 1,
) -> dict[str, dict[str, str]]:
    """Compile each kernel module in a fresh process of its own into cache_dir (`workers` at a
    time); the numba functions each defines (`numba_helpers`)."""

    def one(name: str) -> ProbeRun:
        return run_probe([name], cache_dir, compile=True, uid_start=(uid_start or {}).get(name))

    with ThreadPoolExecutor(workers) as pool:
        runs = dict(zip(names, pool.map(one, names), strict=True))
    helpers = {}
    for name, run in runs.items():
        if not run.passed:
            raise RuntimeError(f"compiling {name}: {run.why}")
        helpers.update(run.helpers)
    return helpers


def orders(names: tuple[str, ...], n_random: int, seed: int = 0) -> list[list[str]]:
    """Forward, reverse and `n_random` shuffled orders of all `names`."""
    rng = np.random.default_rng(seed)
    out = [list(names), list(reversed(names))]
    out += [[names[k] for k in rng.permutation(len(names))] for _ in range(n_random)]
    return out


def _uid_starts(items: list[str]) -> dict[str, int]:
    """{"clique": 23} from ["clique=23"]."""
    out = {}
    for item in items:
        name, _, value = item.partition("=")
        out[name] = int(value)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--probe", nargs="+", choices=MODULES, help="run these checks, in order")
    ap.add_argument("--compile", action="store_true", help="(with --probe) compiling is fine")
    ap.add_argument("--uid-start", default="", help=argparse.SUPPRESS)
    ap.add_argument("--pairs", action="store_true", help="also every ordered pair of modules")
    ap.add_argument("--random", type=int, default=4, help="shuffled orders of all modules")
    ap.add_argument("--workers", type=int, default=1, help="modules compiled at a time")
    ap.add_argument(
        "--shift", nargs="*", default=[], metavar="MODULE=N",
        help="compile MODULE with numba's function counter starting at N (line up names)",
    )  # fmt: skip
    args = ap.parse_args()
    if args.probe:
        if args.uid_start:
            from numba.core.bytecode import FunctionIdentity

            FunctionIdentity._unique_ids = itertools.count(int(args.uid_start))
        probe(args.probe, expect_cached=not args.compile)
        return 0
    runs = orders(MODULES, args.random)
    if args.pairs:
        runs += [list(p) for p in itertools.permutations(MODULES, 2)]
    failures = 0
    with tempfile.TemporaryDirectory(prefix="sgloc-numba-cache-") as tmp:
        t0 = time.perf_counter()
        helpers = populate(Path(tmp), uid_start=_uid_starts(args.shift), workers=args.workers)
        print(f"cache populated, a process per module: {time.perf_counter() - t0:.1f} s")
        for file, names in sort_search_helpers(Path(tmp)).items():
            failures += 1
            print(f"FAIL {file} holds numba sort/search helpers: {sorted(names)}")
        for symbol, modules in clashing_helpers(helpers).items():
            failures += 1
            print(f"FAIL {symbol} defined with different bodies by {modules}")
        t0 = time.perf_counter()
        for names in runs:
            run = run_probe(names, Path(tmp))
            failures += not run.passed
            status = "ok  " if run.passed else "FAIL"
            print(f"{status} {' '.join(names)}" + ("" if run.passed else f"\n     {run.why}"))
        print(f"{len(runs)} load orders, {failures} failures, {time.perf_counter() - t0:.1f} s")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
