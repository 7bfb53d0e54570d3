"""The live server under load: N robots streaming keyframes at R per second each for T minutes
to one `LiveServer` on this machine (server in its own process, robots in this one: one Zenoh
session each).

    python benchmarks/live.py                         # both configurations below, 10 minutes each
    python benchmarks/live.py --config 16x10 --minutes 2

Configurations: `16x10`: 16 robots at 10 keyframes/s, attempts on 1 worker process, the
12x12-block city (2,000 m routes); `64x2`: 64 robots at 2 keyframes/s, attempts on a Dask
LocalCluster (1 worker), the default city. Each robot drives its stretch of route forth and back
again until the time is up (routes driven again: the maps stop growing once a stretch is seen,
the keyframes do not).

Measured: latency from a keyframe published to its correction received (median, p99, max, ms);
keyframes lost (sent and never taken, or never answered); the server's resident memory (MB;
sampled every second, with its worker processes) at a tenth, half and the end of the run
against the keyframes and objects it holds; and, per robot, the time from its map first sharing
enough objects with a placed robot's (the oracle overlap: 15 same-class objects within 3 m in
the truth, through the root's group) to its first placed correction (median, max s). The table
goes to docs/live_benchmark.md (one row per configuration, replaced when rerun).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import re
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DOC = Path(__file__).resolve().parents[1] / "docs" / "live_benchmark.md"
GOALS = "median <= 20 ms, p99 <= 200 ms, none lost, memory bounded by the maps"


@dataclass(frozen=True)
class Setup:
    name: str
    robots: int
    rate: float  # keyframes per second per robot
    dask: bool
    length: float
    blocks: int | None


SETUPS = {"16x10": Setup("16x10", 16, 10.0, False, 2000.0, 12),
          "64x2": Setup("64x2", 64, 2.0, True, 400.0, None)}


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def driven_again(log, n: int, period_ns: int):
    """`log` driven forth, back, forth... to `n` keyframes, `period_ns` apart (the same
    sightings each time a keyframe pose comes again)."""
    from sgloc.io.keyframes import make_robot_log

    m = len(log)
    cycle = np.concatenate([np.arange(m), np.arange(m - 2, 0, -1)]) if m > 2 else np.arange(m)
    idx = cycle[np.arange(n) % len(cycle)]
    counts = np.bincount(log.keyframe, minlength=m)
    starts = np.concatenate([[0], np.cumsum(counts)])
    rows = np.concatenate([np.arange(starts[i], starts[i + 1]) for i in idx])
    kf = np.repeat(np.arange(n), counts[idx])
    return make_robot_log(log.name, np.arange(n, dtype=np.int64) * period_ns, log.xyz[idx],
                          log.quat[idx], kf, log.positions[rows], log.labels[rows])


def _server(endpoint: str, dask: bool, stop, out) -> None:
    """The server process: serve until `stop`, then put its counts and sizes on `out`."""
    from sgloc.live.server import LiveServer, ServeOptions
    from sgloc.online import OnlineConfig
    from sgloc.pipeline.presets import localizer_preset
    from sgloc.warmup import warm_up

    warm_up()  # the kernels loaded before the robots come, as a base station started early
    cluster = None
    if dask:
        from distributed import LocalCluster

        cluster = LocalCluster(n_workers=1, threads_per_worker=1, host="127.0.0.1",
                               dashboard_address=None)
    options = ServeOptions(listen=endpoint, workers=1,
                           scheduler=cluster.scheduler_address if cluster else None)
    with LiveServer(localizer_preset("city-objects"), OnlineConfig(), options,
                    root="city0") as srv:
        out.put(("ready", None))
        stop.wait()
        srv.wait_idle(60)
        s = srv.session
        out.put(("done", {"counts": dict(srv.counts), "links": len(s.links),
                          "placed": len(s.corrections()),
                          "keyframes": sum(len(s.keyframes(r)[0]) for r in s.robots)}))
    if cluster is not None:
        cluster.close()


def _rss_mb(pid: int) -> float:
    import psutil

    p = psutil.Process(pid)
    procs = [p, *p.children(recursive=True)]
    total = 0
    for q in procs:
        try:
            total += q.memory_info().rss
        except psutil.Error:
            pass
    return total / 2**20


class _Sampler(threading.Thread):
    """The server's memory every second."""

    def __init__(self, pid: int) -> None:
        super().__init__(daemon=True)
        self.pid, self.samples, self.halt = pid, [], threading.Event()

    def run(self) -> None:
        t0 = time.monotonic()
        while not self.halt.wait(1.0):
            self.samples.append((time.monotonic() - t0, _rss_mb(self.pid)))


def _join_delays(logs, truth, rec) -> np.ndarray:
    """Seconds from each robot's oracle join to its first placed correction (inf: never)."""
    from sgloc.evaluation.online_oracle import oracle_join_stamps

    join = oracle_join_stamps(logs, truth, "city0")
    return np.asarray([rec.first_placed.get(r, np.inf) - (rec.started + join[r])
                       for r in join if r != "city0" and np.isfinite(join[r])])


def run(setup: Setup, minutes: float) -> dict:
    """One configuration; the row of the table as a dict."""
    from sgloc.errors import SglocError
    from sgloc.evaluation.replay_scenarios import city_scenario
    from sgloc.live.stream import StreamRecord, stream_logs

    sc = city_scenario(setup.robots, 0, length=setup.length, blocks=setup.blocks)
    n = int(round(minutes * 60 * setup.rate))
    logs = [driven_again(g, n, int(round(1e9 / setup.rate))) for g in sc.logs]
    ctx = mp.get_context("spawn")
    stop, out = ctx.Event(), ctx.Queue()
    endpoint = f"tcp/127.0.0.1:{_port()}"
    proc = ctx.Process(target=_server, args=(endpoint, setup.dask, stop, out))
    proc.start()
    try:
        if out.get(timeout=600)[0] != "ready":
            raise SystemExit("error: the server did not start")
        sampler = _Sampler(proc.pid)
        sampler.start()
        rec = StreamRecord()
        try:
            stream_logs(logs, endpoint, rate=1.0, timeout=60, record=rec)
        except SglocError as e:  # the last corrections did not all come: counted below
            print(f"note: {e}", file=sys.stderr)
        sampler.halt.set()
        stop.set()
        _, result = out.get(timeout=900)
    finally:
        stop.set()
        proc.join(120)
        if proc.is_alive():
            proc.kill()
    return _row(setup, minutes, rec, result, sampler.samples,
                _join_delays(logs, sc.T_gt_odom, rec))


def _row(setup: Setup, minutes: float, rec, result: dict, samples: list,
         delays: np.ndarray) -> dict:
    lat = np.concatenate([np.asarray(v) for v in rec.latency_ms.values()])
    counts = result["counts"]
    taken = counts.get("keyframes", 0)
    rss = np.asarray([m for _, m in samples]) if samples else np.full(1, np.nan)
    at = [float(rss[min(int(f * len(rss)), len(rss) - 1)]) for f in (0.1, 0.5, 1.0)]
    return {
        "config": setup.name, "robots": setup.robots, "rate": setup.rate,
        "minutes": minutes, "attempts": "Dask LocalCluster" if setup.dask else "1 process",
        "sent": rec.sent, "taken": taken, "unanswered": rec.sent - len(lat),
        "dropped": {k: v for k, v in counts.items() if k not in ("keyframes", "received") and v},
        "median": float(np.median(lat)), "p99": float(np.percentile(lat, 99)),
        "max": float(lat.max()), "rss": at, "keyframes": result["keyframes"],
        "links": result["links"], "placed": result["placed"],
        "join_median": float(np.median(delays)) if len(delays) else float("nan"),
        "join_max": float(delays.max()) if len(delays) else float("nan"),
    }


HEAD = ("| config | robots x rate | minutes | attempts | keyframes sent / taken / unanswered "
        "| dropped | latency median / p99 / max (ms) | server memory at 10 % / 50 % / end (MB) "
        "| keyframes held | robots placed | oracle join -> placed median / max (s) |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|")


def _line(r: dict) -> str:
    dropped = ", ".join(f"{k} {v}" for k, v in r["dropped"].items()) or "0"
    return (f"| {r['config']} | {r['robots']} x {r['rate']:g}/s | {r['minutes']:g} | "
            f"{r['attempts']} | {r['sent']} / {r['taken']} / {r['unanswered']} | {dropped} | "
            f"{r['median']:.1f} / {r['p99']:.1f} / {r['max']:.0f} | "
            f"{' / '.join(f'{m:.0f}' for m in r['rss'])} | {r['keyframes']} | "
            f"{r['placed']} / {r['robots']} | {r['join_median']:.1f} / {r['join_max']:.1f} |")


def _verdict(r: dict) -> str:
    """The latency and loss goals judged; the memory's growth reported against the keyframes
    held (the pose graph keeps every keyframe, so it grows with them, not with the maps alone)."""
    lost = r["sent"] - r["taken"] + r["unanswered"]
    ok = r["median"] <= 20 and r["p99"] <= 200 and lost == 0
    first, last = r["rss"][0], r["rss"][-1]
    per_kf = (last - first) * 1024 / max(0.9 * r["keyframes"], 1)
    return (f"- {r['config']}: latency and loss {'met' if ok else 'NOT met'} (median "
            f"{r['median']:.1f} ms, p99 {r['p99']:.1f} ms, {lost} keyframes lost or unanswered);"
            f" memory {first:.0f} -> {last:.0f} MB with {r['keyframes']} keyframes held (about "
            f"{per_kf:.0f} kB per keyframe): it grows with the keyframes, not bounded by the maps")


def write(rows: list[dict], path: Path = DOC) -> None:
    """Keep the rows of other configurations, replace those measured now."""
    old = path.read_text() if path.exists() else ""
    keep = {m.group(1): line for line in old.splitlines()
            if (m := re.match(r"\| (\w+) \| \d+ x", line))}
    keep.update({r["config"]: _line(r) for r in rows})
    verdicts = {m.group(1): line for line in old.splitlines()
                if (m := re.match(r"- (\w+): (?:latency and loss )?(?:met|NOT met)", line))}
    verdicts.update({r["config"]: _verdict(r) for r in rows})
    text = ("# Live server under load\n\nRegenerate with `python benchmarks/live.py` "
            "(`--config 16x10` or `64x2`, `--minutes M`); what each column means is in the "
            "benchmark's docstring. Server and robots on one computer (x86_64, 2 cores). Goals: "
            f"{GOALS}.\n\n{HEAD}\n" + "\n".join(keep[k] for k in sorted(keep)) + "\n\n"
            + "\n".join(verdicts[k] for k in sorted(verdicts)) + "\n")
    path.write_text(text)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", choices=sorted(SETUPS), action="append",
                    help="a configuration (repeatable; default: all)")
    ap.add_argument("--minutes", type=float, default=10.0, help="streaming time per run")
    ap.add_argument("--out", type=Path, default=DOC, help="the table's markdown file")
    args = ap.parse_args(argv)
    rows = []
    for name in args.config or sorted(SETUPS):
        r = run(SETUPS[name], args.minutes)
        print(HEAD.splitlines()[0] if not rows else "", _line(r), _verdict(r), sep="\n",
              flush=True)
        rows.append(r)
    write(rows, args.out)


if __name__ == "__main__":
    sys.exit(main())
