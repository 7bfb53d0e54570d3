"""Speed benchmark of the compiled core, all goals in one run.

    python -m benchmarks.speed [--seeds 4] [--reps 3] [--no-maps] [--update-docs]
    python -m benchmarks.speed --only threads --reps 2   # just the localize / BLAS-thread part
    python -m benchmarks.speed --only prepared --prepared-parts cold   # fresh process, first use
    python -m benchmarks.speed --only prepared --scans-only --scan-sizes 15000  # scans only

1. register (neighbor + RANSAC + IRLS) vs KISS-Matcher (`prune_and_solve`) vs sgloc's plain
   numpy pipeline (the reference of the compiled kernels), on synthetic correspondence sets
   (m = 300 / 80 %, 2,000 / 90 %, 10,000 / 95 % outliers; random and structured outliers),
   calls interleaved set by set; wall-clock medians with min / max over all calls.
2. Threads: register and `localize` on Guo's Airsim maps with the default BLAS threads vs
   one thread, interleaved (`localize` also with new graph objects per call; no call keeps
   anything for the next).
3. Start-up: `import sgloc`; the first call in a fresh process with an empty numba cache vs a
   later process; `sgloc localize` on the two Airsim maps as a whole process (after one run).
5. Prepared maps and the cold call (benchmarks/prepared_speed.py): Airsim maps with new graph
   objects per call, one scan against prepared maps of 15,000 and up to 1,000,000 objects, a
   fresh process on two 20,000-object maps, a fresh install's first-use compile.
4. Maps end to end: `localize` on two generated maps of n vertices each (50 % overlap), in a
   fresh process under a memory cap: wall time of the first call (loads the kernels) and of a
   second one (new graph objects), peak resident memory of that process (VmHWM).
5. Map-to-map scale: two maps of N objects (50 % overlap), new graph objects every call, N =
   10k / 20k / 50k / 90k, each N in a fresh process (median, min, max; peak memory); the time
   ratio 90k / 10k; two maps of 500,000 objects (`--only scale`, `--scale-sizes`,
   `--scale-large`).

Writes the tables to results/speed_benchmark.md, or docs/speed_benchmark.md with --update-docs.
KISS-Matcher is used when `kiss_matcher` is importable (`pip install kiss-matcher`).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from threadpoolctl import ThreadpoolController, threadpool_limits

from benchmarks import prepared_speed
from benchmarks.peers.methods import kiss_matcher_method
from sgloc.estimation import RansacConfig, irls_refine, ransac_reference, weighted_kabsch
from sgloc.geometry import transform_error
from sgloc.pipeline.registration import register
from sgloc.sim.correspondences import make_correspondences

#: The numpy references of the kernels live with the tests (tests/references).
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from references.consistency import consistency_bool  # noqa: E402
from references.paths import on_references  # noqa: E402
from references.rejection import prune_by_support as prune_by_support_reference  # noqa: E402

#: (m, outlier ratio, goal ms for register).
GOALS = [(300, 0.8, 0.5), (2000, 0.9, 5.0), (10000, 0.95, 200.0)]
TAU = THRESHOLD = 5.0
SUCCESS_M, SUCCESS_DEG = 2.0, 2.0
#: Methods take turns in bursts of BURST timed calls, each burst after an untimed pause, so
#: that worker threads a method leaves spinning (OpenMP waits actively for a while) do not slow
#: down the next method's calls.
COOL_DOWN_S = 0.005
BURST = 3
#: The plain numpy pipeline: one burst per set (it takes seconds at m = 10,000).
REFERENCE = "sgloc numpy reference"
#: The parts of the benchmark (`--only`).
PARTS = ("register", "threads", "startup", "maps", "scale", "prepared")


def numpy_reference(src, dst, rng):
    """The same pipeline in plain numpy (the kernels' references): T_dst_src or None."""
    kept = prune_by_support_reference(consistency_bool(src, dst, TAU, "distance"), 0.5)
    cfg = RansacConfig(threshold=THRESHOLD, dof=6, max_tilt=None)  # register's motion model
    rs = ransac_reference(src[kept], dst[kept], cfg, rng)
    if rs.transform is None:
        return None
    s, d = src[kept][rs.inliers], dst[kept][rs.inliers]
    return irls_refine(s, d, weighted_kabsch(s, d))


def methods() -> dict:
    """name -> (solve(src, dst, rng), OpenMP thread limit to apply around the call or None)."""

    def ours(src, dst, rng):
        return register(src, dst, "neighbor", noise_bound=TAU / 2, rng=rng).transform

    out = {
        "sgloc.register": (ours, None),
        REFERENCE: (numpy_reference, None),
    }
    km = kiss_matcher_method()
    if km.solve is not None:

        def kiss(s, d, rng):
            return km.solve(s, d, TAU, THRESHOLD, rng)

        out["KISS-Matcher"] = (kiss, None)
        out["KISS-Matcher, 1 OpenMP thread"] = (kiss, 1)
    return out


def _ok(T, T_gt) -> bool:
    if T is None:
        return False
    te, re = transform_error(T, T_gt)
    return bool(te < SUCCESS_M and re < SUCCESS_DEG)


def run_register(seeds: int, reps: int) -> list[dict]:
    """Every method on every set, calls interleaved (the method order rotates per repeat)."""
    meths = methods()
    names = list(meths)
    rows = []
    for m, ratio, goal in GOALS:
        calls = {n: [] for n in names}
        ok = {n: [] for n in names}
        for kind in ("random", "structured"):
            for seed in range(seeds):
                cs = make_correspondences(m, ratio, np.random.default_rng([m, seed]), kind)
                for n in names:  # warm-up (compilation, caches)
                    if n != REFERENCE:
                        meths[n][0](cs.src, cs.dst, np.random.default_rng(seed))
                for rep in range(reps):
                    for n in names[rep % len(names) :] + names[: rep % len(names)]:
                        if n == REFERENCE and rep:
                            continue  # slow: one burst per set
                        solve, omp = meths[n]
                        lim = threadpool_limits(omp, user_api="openmp") if omp else None
                        time.sleep(COOL_DOWN_S)
                        for _ in range(BURST):
                            t0 = time.perf_counter()
                            T = solve(cs.src, cs.dst, np.random.default_rng(seed))
                            calls[n].append((time.perf_counter() - t0) * 1e3)
                            ok[n].append(_ok(T, cs.T_dst_src))
                        if lim is not None:
                            lim.restore_original_limits()
        for n in names:
            rows.append({"m": m, "ratio": ratio, "goal": goal, "method": n,
                         "ms": calls[n], "success": 100.0 * np.mean(ok[n])})  # fmt: skip
    return rows


_LOAD = "import time\nt = time.time()\nwhile time.time() - t < 600: pass\n"


def airsim_maps():
    from sgloc import SemanticGraph
    from sgloc.datasets.downloads import data_path

    d = data_path("airsim_guo")
    return SemanticGraph.load(d / "cloud1.pcd"), SemanticGraph.load(d / "cloud2.pcd")


#: Rounds of the threads part per --reps: every case and thread setting takes a turn of 5
#: calls per round, so a burst of load from other jobs falls on all of them alike.
THREAD_ROUNDS = 10
#: The localize case also run on the numpy references (tests/references: `on_references`).
REFERENCE_CASE = "localize, Airsim maps, numpy references"


def _on_references(call):
    """`call` with every kernel replaced by its numpy reference."""

    def run():
        with on_references():
            return call()

    return run


def run_threads(reps: int, load: bool) -> list[dict]:
    """register and localize (Airsim maps) with the default BLAS threads vs one, and localize
    on the numpy references: in rounds where every case and setting takes a turn of 5 calls;
    with `load`, a busy process competes for the cores."""
    from sgloc import localize

    q, t = airsim_maps()
    cases = {}
    for m, ratio, _ in GOALS[:2]:
        cs = make_correspondences(m, ratio, np.random.default_rng(m), "random")
        cases[f"register m={m}, {ratio:.0%}"] = lambda cs=cs: register(
            cs.src, cs.dst, noise_bound=TAU / 2
        )
    cases["localize, Airsim maps"] = lambda: localize(q, t, seed=0)
    # New graph objects per call: nothing the first call computed (descriptors) is reused.
    cases["localize, Airsim maps, new graph objects"] = lambda: localize(
        q.subgraph(np.arange(len(q))), t.subgraph(np.arange(len(t))), seed=0
    )
    cases[REFERENCE_CASE] = _on_references(cases["localize, Airsim maps"])
    ctl = ThreadpoolController()
    times = {(name, label): [] for name in cases for label in ("default", "1")}
    stages = {name: {} for name in cases}
    for call in cases.values():
        call()  # warm-up
    busy = subprocess.Popen([sys.executable, "-c", _LOAD]) if load else None
    try:
        for _ in range(reps * THREAD_ROUNDS):
            for (name, label), out in times.items():
                lim = ctl.limit(limits=1, user_api="blas") if label == "1" else None
                time.sleep(COOL_DOWN_S)  # threads the previous block left spinning settle
                for _ in range(5):
                    t0 = time.perf_counter()
                    res = cases[name]()
                    out.append((time.perf_counter() - t0) * 1e3)
                    if label == "default" and hasattr(res, "confidence"):
                        for k, v in res.timings.items():
                            stages[name].setdefault(k, []).append(v * 1e3)
                if lim is not None:
                    lim.restore_original_limits()
    finally:
        if busy is not None:
            busy.kill()
            busy.wait()
    return [{"case": name, "threads": label, "ms": v,
             "stages": stages[name] if label == "default" else {}}
            for (name, label), v in times.items()]  # fmt: skip


_FIRST_CALL = """
import time; t0 = time.perf_counter()
import numpy as np, sgloc
t1 = time.perf_counter()
from sgloc.sim.correspondences import make_correspondences
cs = make_correspondences(300, 0.8, np.random.default_rng(0))
t2 = time.perf_counter(); sgloc.register(cs.src, cs.dst); t3 = time.perf_counter()
sgloc.register(cs.src, cs.dst); t4 = time.perf_counter()
print(t1 - t0, t3 - t2, t4 - t3)
"""


def bytecode_env(folder: str) -> dict[str, str]:
    """The environment of the start-up's fresh processes: Python's bytecode cached in `folder`
    (PYTHONPYCACHEPREFIX; PYTHONDONTWRITEBYTECODE dropped), as an installed package has its
    bytecode, filled by an untimed first process, so that no timed process compiles Python
    sources. Nothing is written next to the sources."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = folder
    subprocess.run([sys.executable, "-c", "import sgloc.cli, sgloc.sim.correspondences"],
                   env=env, check=True)  # fmt: skip
    return env


def run_startup(runs: int, base: dict[str, str]) -> dict:
    """Seconds: import sgloc; the first register call (m = 300) with a fresh numba cache
    (compiles) and in later processes (cache loaded); a call after that. `base`: the
    processes' environment (`bytecode_env`)."""
    out = {"import sgloc": [], "first compiled call, empty cache (compiles)": [],
           "first compiled call, cached (loads)": [], "compiled call after that": []}  # fmt: skip
    for _ in range(runs):
        with tempfile.TemporaryDirectory() as cache:
            env = dict(base, NUMBA_CACHE_DIR=cache)
            for k in range(2):
                res = subprocess.run([sys.executable, "-c", _FIRST_CALL], env=env,
                                     capture_output=True, text=True, check=True)  # fmt: skip
                imp, first, after = map(float, res.stdout.split())
                out["import sgloc"].append(imp)
                key = "empty cache (compiles)" if k == 0 else "cached (loads)"
                out[f"first compiled call, {key}"].append(first)
                out["compiled call after that"].append(after)
    return out


def run_cli(runs: int, env: dict[str, str]) -> list[float]:
    """Wall seconds of `sgloc localize cloud1.pcd cloud2.pcd` (Airsim maps) as a whole process
    in the environment `env` (`bytecode_env`), after one untimed run."""
    from sgloc.datasets.downloads import data_path

    d = data_path("airsim_guo")
    cmd = [sys.executable, "-m", "sgloc", "localize", str(d / "cloud1.pcd"), str(d / "cloud2.pcd")]
    out = []
    for k in range(runs + 1):
        t0 = time.perf_counter()
        subprocess.run(cmd, capture_output=True, check=True, env=env)
        if k:
            out.append(time.perf_counter() - t0)
    return out


def run_startup_part(runs: int) -> tuple[dict, list[float]]:
    """`run_startup` and `run_cli` (runs + 2 processes) with one bytecode cache folder."""
    with tempfile.TemporaryDirectory() as pyc:
        env = bytecode_env(pyc)
        return run_startup(runs, env), run_cli(runs + 2, env)


_MAPS = """
import json, resource, sys, time
import numpy as np
n, cap = int(sys.argv[1]), int(sys.argv[2])
resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
from sgloc import localize
from sgloc.geometry import transform_error
from sgloc.sim.object_world import make_two_robot_scene
# Robots see whole cross streets (view radius 130 m): about 0.47 objects per metre of street.
scene = make_two_robot_scene(seed=0, overlap=0.5, stretch=n / 0.47, view_radius=130.0)
q, t = scene.query, scene.target


def peak_mb():
    # VmHWM: this process's own peak (ru_maxrss would include the parent's before exec).
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM"):
            return int(line.split()[1]) / 1e3


out = {"n_query": len(q), "n_target": len(t), "base_mb": peak_mb()}
try:
    t0 = time.perf_counter()
    res = localize(q, t, seed=0)
    out["wall_s"] = time.perf_counter() - t0
    out["accepted"] = bool(res.accepted)
    if res.transform is not None:
        out["t_err"] = transform_error(res.transform, scene.T_target_query)[0]
    out["timings"] = res.timings
    out["peak_mb"] = peak_mb()
    if len(sys.argv) > 3:  # a second call on new graph objects: kernels loaded, no caches
        q2, t2 = q.subgraph(np.arange(len(q))), t.subgraph(np.arange(len(t)))
        t0 = time.perf_counter()
        res = localize(q2, t2, seed=0)
        out["second_wall_s"] = time.perf_counter() - t0
        out["second_timings"] = res.timings
except MemoryError as e:
    out["error"] = "MemoryError " + str(e)[:80]
out["peak_mb"] = peak_mb()
print(json.dumps(out))
"""


def run_maps(sizes: list[int], cap_gb: float, second_below: int = 50_000) -> list[dict]:
    """Each size in a fresh process; maps below `second_below` vertices also get a second call."""
    rows = []
    for n in sizes:
        args = [str(n), str(int(cap_gb * 2**30))] + (["second"] if n < second_below else [])
        res = subprocess.run([sys.executable, "-c", _MAPS, *args],
                             capture_output=True, text=True)  # fmt: skip
        if res.returncode == 0:
            rows.append({"n": n, **json.loads(res.stdout.strip().splitlines()[-1])})
        else:
            rows.append({"n": n, "error": res.stderr.strip().splitlines()[-1][:120]})
    return rows


_SCALE = """
import json, sys, time
import numpy as np
from sgloc import localize
from sgloc.geometry import transform_error
from sgloc.sim.object_world import make_two_robot_scene


def scene(n):
    # Robots see whole cross streets (view radius 130 m): about 0.47 objects per metre of street.
    return make_two_robot_scene(seed=0, overlap=0.5, stretch=n / 0.47, view_radius=130.0)


def peak_mb():
    for line in open("/proc/self/status"):  # VmHWM: this process's peak resident set
        if line.startswith("VmHWM"):
            return int(line.split()[1]) / 1e3


n, reps = int(sys.argv[1]), int(sys.argv[2])
small = scene(2000)
localize(small.query, small.target, seed=0, scope="local")  # loads the kernels (not timed)
s = scene(n) out = {"n_query": len(s.query), "n_target": len(s.target), "base_mb": peak_mb(), "s":
[]} for _ in range(reps):
    # New graph objects every call: nothing computed for the last call is reused.
    q, t = s.query.subgraph(np.arange(len(s.query))), s.target.subgraph(np.arange(len(s.target)))
    t0 = time.perf_counter() res = localize(q, t, seed=0)
    out["s"].append(time.perf_counter() - t0)
    out["timings"] = res.timings
out["accepted"] = bool(res.accepted)
if res.transform is not None:
    out["t_err"] = float(transform_error(res.transform, s.T_target_query)[0])
out["n_candidates"], out["n_survivors"] = len(res.candidates), len(res.survivors)
out["peak_mb"] = peak_mb()
print(json.dumps(out))
"""

#: Map-to-map goals: 90k objects per map in at most this many seconds and MB, time ratio
#: 90k / 10k at most SCALE_RATIO.
SCALE_GOAL_S, SCALE_GOAL_MB, SCALE_RATIO = 3.0, 1000.0, 15.0


def run_scale(sizes: list[int], reps: int, large: int) -> list[dict]:
    """Each map size in a fresh process: `reps` calls on new graph objects (`large`: one)."""
    rows = []
    for n, r in [(n, reps) for n in sizes] + ([(large, 1)] if large else []):
        res = subprocess.run([sys.executable, "-c", _SCALE, str(n), str(r)],
                             capture_output=True, text=True)  # fmt: skip
        if res.returncode == 0:
            rows.append({"n": n, **json.loads(res.stdout.strip().splitlines()[-1])})
        else:
            rows.append({"n": n, "error": (res.stderr.strip().splitlines() or ["?"])[-1][:120]})
    return rows


def report_scale(rows: list[dict], args) -> list[str]:
    """The map-to-map table and its goals."""
    reps = args.scale_reps
    sizes = " ".join(str(n) for n in args.scale_sizes)
    lines = ["## Map to map at scale", "",
             f"Command: `python -m benchmarks.speed --only scale --scale-sizes {sizes} "
             f"--scale-reps {reps} --scale-large {args.scale_large}` "
             f"({time.strftime('%Y-%m-%d')}). "
             "`localize(query, target)` with default settings on two generated object maps of "
             "N objects each (`sgloc.sim.object_world`, 50 % overlap, view radius 130 m), new "
             f"graph objects every call (nothing cached), {reps} calls per size in a fresh "
             "process after one untimed call on small maps (kernels loaded); the largest size "
             "once. Wall seconds median (min – max); peak memory: the process's peak resident "
             "set (VmHWM, including about 200 MB of Python, numpy, scipy and numba); bytes per "
             "object: (peak - resident set before the calls) / objects of both maps.", "",
             "| N per map | objects (query, target) | candidates, survivors | s median (min – max) "
             "| peak MB | bytes / object | outcome (stages of the last call, s) |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    med = {}
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['n']:,} | - | - | - | - | - | {r['error']} |")
            continue
        med[r["n"]] = float(np.median(r["s"]))
        per = (r["peak_mb"] - r["base_mb"]) * 1e6 / (r["n_query"] + r["n_target"])
        res = ("localized" if r["accepted"] else "not localized") + (
            f", t_err {r['t_err']:.2f} m" if "t_err" in r else ""
        )
        stages = ", ".join(f"{k} {v:.2f}" for k, v in r["timings"].items())
        lines.append(f"| {r['n']:,} | {r['n_query']:,}, {r['n_target']:,} | "
                     f"{r['n_candidates']:,}, {r['n_survivors']:,} | {_mmm(r['s'])} | "
                     f"{r['peak_mb']:.0f} | {per:.0f} | {res} ({stages}) |")  # fmt: skip
    out = []
    big = next((r for r in rows if r["n"] == 90_000 and "error" not in r), None)
    if big is not None:
        out.append(
            f"- 90,000 objects per map: {med[90_000]:.2f} s median (<= {SCALE_GOAL_S:g} s: "
            f"{_verdict(med[90_000] <= SCALE_GOAL_S)}), peak {big['peak_mb']:.0f} MB "
            f"(<= {SCALE_GOAL_MB:g} MB: {_verdict(big['peak_mb'] <= SCALE_GOAL_MB)})."
        )
    if 90_000 in med and 10_000 in med:
        ratio = med[90_000] / med[10_000]
        out.append(f"- time ratio 90k / 10k: {ratio:.1f} (<= {SCALE_RATIO:g}: "
                   f"{_verdict(ratio <= SCALE_RATIO)}).")  # fmt: skip
    for r in rows:
        if r["n"] > 90_000:
            done = "error" not in r
            out.append(f"- {r['n']:,} objects per map: "
                       + (f"completes in {med[r['n']]:.0f} s, peak {r['peak_mb']:.0f} MB."
                          if done else f"did not complete ({r['error']})."))  # fmt: skip
    return lines + ["", *out, ""]


def _mmm(v) -> str:
    v = np.asarray(v, float)
    return f"{np.median(v):.3g} ({v.min():.3g} – {v.max():.3g})"


def _verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def report_register(reg, args) -> list[str]:
    lines = [
        f"Command: `python -m benchmarks.speed --seeds {args.seeds} --reps {args.reps} "
        f"--startup-runs {args.startup_runs}{' --load' if args.load else ''}` "
        f"({time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores, other processes running, "
        "default BLAS threads unless said). Wall-clock milliseconds: median (min – max) over "
        f"all calls ({args.seeds} seeds x 2 outlier kinds x {args.reps} turns x {BURST} calls "
        "per size); "
        f"success: translation error < {SUCCESS_M} m and rotation error < {SUCCESS_DEG} deg. "
        f"Methods take turns (the order rotates) in bursts of {BURST} calls on the same set, "
        f"each burst after an untimed {COOL_DOWN_S * 1e3:g} ms pause (threads left spinning by "
        "one method must not slow down the next); every call counts. In-process timings run "
        "the compiled kernels (as every non-empty problem does; see Start-up). "
        "register runs neighbor rejection (tau = 5 m), RANSAC (threshold 5 m) and the IRLS fit; "
        "KISS-Matcher runs `prune_and_solve` with noise bounds tau / 2 (the same consistency "
        "graph), with its default OpenMP threads and with one; the numpy reference is the same "
        f"pipeline as register without compiled kernels (one burst of {BURST} calls per set).",
        "",
        "| m | outliers | method | success % | ms median (min – max) | goal |",
        "|---|---|---|---|---|---|",
    ]
    by = {(r["m"], r["method"]): r for r in reg}
    verdicts = []
    for m, ratio, goal in GOALS:
        for r in (x for x in reg if x["m"] == m):
            g = f"<= {goal:g} ms" if r["method"] == "sgloc.register" else ""
            lines.append(f"| {m} | {ratio:.0%} | {r['method']} | {r['success']:.0f} | "
                         f"{_mmm(r['ms'])} | {g} |")  # fmt: skip
        ref = float(np.median(by[(m, "sgloc numpy reference")]["ms"]))
        kiss = [by[k] for k in by if k[0] == m and k[1].startswith("KISS-Matcher")]
        best_k = min(kiss, key=lambda r: np.median(r["ms"])) if kiss else None
        ours = by[(m, "sgloc.register")]
        med = float(np.median(ours["ms"]))
        v = f"- register, m = {m}, {ratio:.0%}: {med:.3g} ms (<= {goal:g} ms: "
        v += f"{_verdict(med <= goal)})"
        if best_k is not None:
            kmed = float(np.median(best_k["ms"]))
            faster = med < kmed and ours["success"] >= best_k["success"]
            v += (f"; fastest KISS-Matcher setting {kmed:.3g} ms ({kmed / med:.2g}x ours), "
                  f"success {ours['success']:.0f} % vs {best_k['success']:.0f} % (faster at "
                  f"equal or better success: {_verdict(faster)})")  # fmt: skip
        else:
            v += "; KISS-Matcher not importable: compared with the numpy reference only"
        verdicts.append(v + f"; numpy reference {ref:.3g} ms ({ref / med:.2g}x ours).")
    return lines + ["", *verdicts, ""]


def report_threads(threads, args) -> list[str]:
    load = " plus one busy process competing for the cores" if args.load else ""
    lines = ["## Threads and the whole localize", "",
             "The default BLAS threads vs one (threadpoolctl), in rounds where every call and "
             f"setting takes a turn of 5 calls on the same input ({args.reps * THREAD_ROUNDS} "
             f"rounds; each turn after an untimed {COOL_DOWN_S * 1e3:g} ms pause), so that "
             "bursts of load fall on all alike; other processes ran at the "
             f"same time{load}. `localize` runs "
             "Guo's Airsim maps (cloud1 against cloud2, 318 and 328 objects) with default "
             "settings; with the same graph objects every call and with new graph objects per "
             "call (a call keeps nothing for the next: both describe the maps every time; a "
             "map used again is prepared once, `sgloc.prepare`); and with every "
             "compiled kernel replaced by its numpy reference (same results).", "",
             "| call | BLAS threads | ms median (min – max) | stages, ms (medians) |",
             "|---|---|---|---|"]  # fmt: skip
    for r in threads:
        st = ", ".join(f"{k} {np.median(v):.2f}" for k, v in r["stages"].items())
        lines.append(f"| {r['case']} | {r['threads']} | {_mmm(r['ms'])} | {st} |")
    by = {(r["case"], r["threads"]): float(np.median(r["ms"])) for r in threads}
    out = []
    for case in ("localize, Airsim maps", "localize, Airsim maps, new graph objects"):
        med, one = by[(case, "default")], by[(case, "1")]
        out.append(f"- {case}: {med:.3g} ms median with the default threads (<= 2 ms: "
                   f"{_verdict(med <= 2.0)}); one thread {one:.3g} ms (default / one "
                   f"{med / one:.2f}).")  # fmt: skip
    ref, ours = by[(REFERENCE_CASE, "default")], by[("localize, Airsim maps", "default")]
    out.append(f"- localize on the numpy references: {ref:.3g} ms median with the default "
               f"threads; the compiled kernels take {ours / ref:.2f} of that, measured in the "
               "same rounds.")  # fmt: skip
    return lines + ["", *out, ""]


def report_startup(startup, cli) -> list[str]:
    lines = ["## Start-up", "",
             "Fresh processes; seconds, median (min – max). `import sgloc` loads neither numba "
             "nor the kernels (nor scipy.stats, matplotlib, dask). Loading numba and the cached "
             "kernels costs a process a few tenths of a second once; every problem runs the "
             "kernels (the numpy references, equal to rounding, serve the tests), so the same "
             "inputs give the same bits in every process. The first "
             "compiled call compiles the kernels it uses (numba, `cache=True`) "
             "when the cache is empty "
             "and loads them afterwards. The compiled code is cached next to the installed "
             "sources (`sgloc/kernels/__pycache__`) when that folder is writable, otherwise in "
             "numba's per-user cache folder (`~/.cache/numba` on Linux); `NUMBA_CACHE_DIR` "
             "overrides both (here an empty folder per pair of processes). Python's bytecode "
             "is cached, as in an installed package (here in a temporary folder, "
             "`PYTHONPYCACHEPREFIX`, filled by an untimed first process). Each `sgloc` command "
             "loads its own machinery only when it runs, and the program sets Python's garbage "
             "collector for a short-lived process (full collections less often, none of the "
             "start-up's objects walked at exit); `main(argv)` called from Python leaves the "
             "collector as it is.", "",
             "| what | s |", "|---|---|"]  # fmt: skip
    lines += [f"| {k} | {_mmm(v)} |" for k, v in startup.items()]
    lines.append(f"| `sgloc localize cloud1.pcd cloud2.pcd`, whole process | {_mmm(cli)} |")
    imp, med = float(np.median(startup["import sgloc"])), float(np.median(cli))
    return lines + ["", f"- import sgloc: {imp:.2f} s (<= 0.5 s: {_verdict(imp <= 0.5)}); "
                    f"`sgloc localize` on the Airsim maps: {med:.2f} s wall (< 1 s: "
                    f"{_verdict(med < 1.0)}).", ""]  # fmt: skip


def report_maps(maps, cap_gb) -> list[str]:
    lines = ["## Two maps end to end", "",
             "`localize(query, target)` with default settings on generated object maps "
             "(`sgloc.sim.object_world`, 50 % overlap), each size in a fresh process capped at "
             f"{cap_gb:g} GB of address space. First call: includes loading numba and the "
             "cached kernels; second call: new graph objects (nothing cached). Peak memory: "
             "the process's peak resident set (VmHWM), of which about 200 MB is Python, numpy, "
             "scipy and numba.", "",
             "| n per map | vertices (query, target) | first call s | second call s | peak MB "
             "| outcome (stages of the last call, s) |", "|---|---|---|---|---|---|"]  # fmt: skip
    out = []
    for r in maps:
        if "wall_s" in r and "error" not in r:
            res = ("localized" if r["accepted"] else "not localized") + (
                f", t_err {r['t_err']:.2f} m" if "t_err" in r else ""
            )
            tim = r.get("second_timings", r["timings"])
            stages = ", ".join(f"{k} {v:.2f}" for k, v in tim.items())
            second = f"{r['second_wall_s']:.2f}" if "second_wall_s" in r else "-"
            lines.append(f"| {r['n']} | {r['n_query']}, {r['n_target']} | {r['wall_s']:.2f} | "
                         f"{second} | {r['peak_mb']:.0f} | {res} ({stages}) |")  # fmt: skip
            best = min(r["wall_s"], r.get("second_wall_s", np.inf))
            if r["n"] == 20000:
                out.append(f"- 20,000 vertices: {r['wall_s']:.2f} s first call, {second} s "
                           f"second (<= 1 s: {_verdict(best <= 1.0)}), peak {r['peak_mb']:.0f} "
                           f"MB (<= 500 MB: {_verdict(r['peak_mb'] <= 500)}).")  # fmt: skip
            else:
                out.append(f"- {r['n']:,} vertices: completes in {r['wall_s']:.1f} s, peak "
                           f"{r['peak_mb']:.0f} MB.")  # fmt: skip
        else:
            lines.append(
                f"| {r['n']} | {r.get('n_query', '-')}, {r.get('n_target', '-')} | - "
                f"| - | {r.get('peak_mb', float('nan')):.0f} | {r['error']} |"
            )
            out.append(f"- {r['n']:,} vertices: did not complete ({r['error']}).")
    return lines + ["", *out, ""]


def report(reg, threads, startup, cli, maps, args) -> list[str]:
    lines = ["# Speed of the compiled core", ""]
    if args.loads:
        first, last = args.loads[0], args.loads[-1]
        lines += [f"Machine load while this ran: 1-minute load average {first:.2f} at the start, "
                  f"{last:.2f} at the end, {max(args.loads):.2f} at most between the parts, on "
                  f"{os.cpu_count()} cores (other jobs share them: single calls can be several "
                  "times slower than on an idle machine; the ratios within a table are measured "
                  "in the same process and rounds).", ""]  # fmt: skip
    if reg:
        lines += report_register(reg, args)
    if threads:
        lines += report_threads(threads, args)
    if startup:
        lines += report_startup(startup, cli)
    if maps:
        lines += report_maps(maps, args.cap_gb)
    if args.scale_rows:
        lines += report_scale(args.scale_rows, args)
    if getattr(args, "prepared", None):
        lines += prepared_speed.report(args.prepared)
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--startup-runs", type=int, default=3)
    ap.add_argument("--no-maps", action="store_true")
    ap.add_argument("--maps", type=int, nargs="*", default=[20000, 100000])
    ap.add_argument("--cap-gb", type=float, default=6.0)
    ap.add_argument("--scale-sizes", type=int, nargs="*", default=[10_000, 20_000, 50_000, 90_000])
    ap.add_argument("--scale-reps", type=int, default=3)
    ap.add_argument("--scale-large", type=int, default=500_000, help="0: skip")
    ap.add_argument("--load", action="store_true", help="a busy process during the BLAS test")
    ap.add_argument("--update-docs", action="store_true", help="write docs/speed_benchmark.md")
    ap.add_argument("--scan-sizes", type=int, nargs="+", default=[15_000, 1_000_000],
                    help="map sizes of the prepared-map scans (part prepared)")  # fmt: skip
    ap.add_argument("--scans-only", action="store_true",
                    help="part prepared: only the scans against prepared maps")  # fmt: skip
    ap.add_argument("--only", nargs="+", choices=PARTS, default=list(PARTS),
                    help="run only these parts (never written to docs/)")  # fmt: skip
    ap.add_argument("--prepared-parts", nargs="+", choices=prepared_speed.PARTS,
                    default=list(prepared_speed.PARTS),
                    help="of part `prepared`, only these (e.g. `cold`: the fresh process and "
                         "first use; never written to docs/)")  # fmt: skip
    args = ap.parse_args()
    parts = set(args.only)
    args.loads = [os.getloadavg()[0]]
    reg = run_register(args.seeds, args.reps) if "register" in parts else []
    args.loads.append(os.getloadavg()[0])
    threads = run_threads(args.reps, args.load) if "threads" in parts else []
    args.loads.append(os.getloadavg()[0])
    startup, cli = run_startup_part(args.startup_runs) if "startup" in parts else ({}, [])
    args.loads.append(os.getloadavg()[0])
    maps = run_maps(args.maps, args.cap_gb) if "maps" in parts and not args.no_maps else []
    args.loads.append(os.getloadavg()[0])
    args.scale_rows = []
    if "scale" in parts:
        args.scale_rows = run_scale(args.scale_sizes, args.scale_reps, args.scale_large)
        args.loads.append(os.getloadavg()[0])
    args.prepared = prepared_speed.run(args) if "prepared" in parts else None
    args.loads.append(os.getloadavg()[0])
    text = "\n".join(report(reg, threads, startup, cli, maps, args))
    print(text)
    partial = (
        parts != set(PARTS)
        or args.scans_only
        or set(args.prepared_parts) != set(prepared_speed.PARTS)
    )
    out = Path("docs" if args.update_docs and not partial else "results") / "speed_benchmark.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
