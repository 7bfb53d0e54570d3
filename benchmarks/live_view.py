"""What the live view (`sgloc serve --view`) costs per update, on fleets of growing size: the
snapshot the server takes on its session thread (ingest waits for it), the messages the view
builds from it on its own thread, and the bytes sent per update to each viewer.

    python benchmarks/live_view.py              # the three fleets below
    python benchmarks/live_view.py --repeat 10

Fleets: R robots of K keyframes each (6 objects seen per keyframe, 8 classes, keyframe
back-end), every robot placed by an added link to the root (all their objects in the fleet
map). Times are medians over --repeat updates after one warm-up (the first snapshot also builds
the robots' cached object graphs, which the session builds anyway for its attempts). The view
updates at most twice a second (`ServeOptions.view_rate`), so the session thread spends at most
2 x the snapshot time per second on it; after each update the view rests twice as long as it
worked (`sgloc.live.view`), hence the updates per second at most of the last column (a full
update: every topic; an update after which the map did not change costs little). The table
goes to docs/live_view_benchmark.md.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sgloc import lie
from sgloc.live import view_messages as vm
from sgloc.online import OnlineConfig, OnlineSession

DOC = Path(__file__).resolve().parents[1] / "docs" / "live_view_benchmark.md"
FLEETS = ((4, 100), (8, 250), (16, 500))


def fleet(robots: int, keyframes: int, seed: int = 0) -> OnlineSession:
    """`robots` robots of `keyframes` keyframes, all placed by added links to r0."""
    s = OnlineSession(online=OnlineConfig(backend="keyframes", min_observations=1,
                                          max_attempts=0, solver="scipy"))
    rng = np.random.default_rng(seed)
    for k in range(keyframes):
        for r in range(robots):
            T = lie.se3_exp([0, 0, 0.01 * k, 2.0 * k, 10.0 * r, 0])
            s.add_keyframe(f"r{r}", float(k), T, rng.uniform(-15, 15, (6, 3)),
                           rng.integers(0, 8, 6))
    for r in range(1, robots):
        s.add_link("r0", f"r{r}", lie.se3_exp([0, 0, 0.1 * r, 0, 40.0 * r, 0]),
                   np.eye(6) * 1e-4)
    return s


def measure(s: OnlineSession, repeat: int) -> dict[str, float]:
    """Median snapshot and message times (ms), the bytes of one update, the objects of the
    placed robots' maps."""
    snap_ms, build_ms = [], []
    for i in range(repeat + 1):
        t0 = time.perf_counter()
        snap = vm.snapshot(s)
        t1 = time.perf_counter()
        msgs = vm.messages(snap)
        sizes = [len(m.encode()) for m in msgs.values()]
        t2 = time.perf_counter()
        if i:  # the first: warm-up
            snap_ms.append(1e3 * (t1 - t0))
            build_ms.append(1e3 * (t2 - t1))
    objects = sum(len(g) for g in snap.maps.values())
    return {"snapshot": float(np.median(snap_ms)), "build": float(np.median(build_ms)),
            "mb": sum(sizes) / 1e6, "objects": objects}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rows = ["| robots | keyframes (all) | objects (robots' maps) | snapshot, session thread (ms) "
            "| messages, view thread (ms) | one update (MB) | full updates/s at most |",
            "|---|---|---|---|---|---|---|"]
    for robots, keyframes in FLEETS:
        s = fleet(robots, keyframes)
        m = measure(s, args.repeat)
        per_s = min(2.0, 1e3 / (3 * m["build"]))
        rows.append(f"| {robots} | {robots * keyframes} | {m['objects']} | {m['snapshot']:.1f} "
                    f"| {m['build']:.1f} | {m['mb']:.2f} | {per_s:.1f} |")
        print(rows[-1], flush=True)
    text = ("# Live view: cost per update\n\nRegenerate with `python benchmarks/live_view.py` "
            "(what is measured: that script's docstring). Medians of "
            f"{args.repeat} updates, on one computer (x86_64, 2 cores).\n\n"
            + "\n".join(rows) + "\n")
    DOC.write_text(text)
    print("\n".join(rows[:2]))
    print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
