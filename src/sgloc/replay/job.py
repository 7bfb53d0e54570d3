"""A replay from inputs to outputs (`sgloc replay`): the input chosen (recorded sources, or a
scenario of `sgloc.replay.scenarios`, which the evaluation's runs fill) and checked with the
session's options, then streamed through one online session and written
(`sgloc.replay.outputs`, and a ROS 2 bag)."""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sgloc.errors import SglocError
from sgloc.io.keyframes import RobotLog
from sgloc.optional import require
from sgloc.pipeline.config import LocalizerConfig
from sgloc.replay.scenarios import REPLAY_SCENARIOS, ReplayInput


@dataclass(frozen=True)
class ReplayJob:
    """Checked robot logs with the session's options: the fleet back-end, the root robot (None:
    the first to send a keyframe), the seed; `preset` suits the logs (None: the defaults)."""

    logs: list[RobotLog]
    preset: str | None = None
    backend: str = "keyframes"
    root: str | None = None
    seed: int = 0
    online: dict[str, Any] = field(default_factory=dict)  # OnlineConfig.with_overrides's

    def online_config(self) -> Any:
        """The online session's settings: the job's seed and back-end, then `online`."""
        from sgloc.online import OnlineConfig

        return OnlineConfig(seed=self.seed, backend=self.backend).with_overrides(**self.online)

    def run(self, config: LocalizerConfig, out: str | Path, out_bag: str | Path | None = None,
            inputs: Sequence[str | Path | None] = (),
            progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:
        """Stream every keyframe through one online session localizing with `config`, write the
        results folder `out` (never over `inputs`) and, when given, the fleet frames as a ROS 2
        bag `out_bag`; returns the summary. `progress(done, total)` follows the keyframes."""
        from sgloc.online import OnlineSession
        from sgloc.replay.outputs import write_replay
        from sgloc.replay.stream import replay_logs

        session = OnlineSession(config, self.online_config(), root=self.root)
        total, done = sum(len(g) for g in self.logs), [0]

        def step(n: int) -> None:
            done[0] += n
            progress(done[0], total)

        if progress is not None:
            progress(0, total)
        record = replay_logs(self.logs, session, progress=step if progress else None)
        summary = write_replay(out, self.logs, session, record, inputs)
        if out_bag is not None:
            from sgloc.io.rosbag import write_fleet_bag

            write_fleet_bag(out_bag, record.transforms + final_poses(self.logs, session))
        return summary


def final_poses(logs: Sequence[RobotLog], session: Any) -> list[tuple[int, str, Any]]:
    """(stamp ns, robot, T_fleet_robot) of every placed robot at the logs' last stamp."""
    end = max(int(g.stamps_ns[-1]) for g in logs)
    out = []
    for g in logs:
        T = session.T_fleet_robot(g.name) if g.name in session.robots else None
        if T is not None:
            out.append((end, g.name, T))
    return out


def replay_job(
    sources: Sequence[str | Path] = (),
    named: Sequence[str] = (),
    scenarios: Sequence[str] = (),
    *,
    classes: str | Path | None = None,
    odom_topic: str | None = None,
    objects_topic: str | None = None,
    backend: str = "keyframes",
    root: str | None = None,
    seed: int = 0,
    online: dict[str, Any] | None = None,
    **options: Any,
) -> ReplayJob:
    """The checked replay of exactly one input: recorded `sources` and `named` robots (NAME=PATH
    items; `sgloc.replay.inputs`), or one of `scenarios` (REPLAY_SCENARIOS names, with the
    `options` and `seed` each takes; `poses` only for kitti00); `online`: the online
    session's settings (`OnlineConfig.with_overrides`). SglocError on a bad input, back-end,
    root robot or online setting, before any input is read."""
    online = dict(online or {})
    for name, option in (("seed", "--seed"), ("backend", "--backend")):
        if name in online:
            raise SglocError(f"--set online.{name}: give {option} instead.")
    check_backend(backend)
    ReplayJob([], backend=backend, seed=seed, online=online).online_config()  # checked now
    if bool(sources or named) + len(scenarios) != 1:
        raise SglocError("give exactly one input: a layout folder or bag (or one bag per robot), "
                         "--kitti00, or --city.")
    poses = options.get("poses", "raw")
    if poses not in ("raw", "refined"):
        raise SglocError(f"--poses {poses!r}: choose raw or refined.")
    if poses != "raw" and list(scenarios) != ["kitti00"]:
        raise SglocError(f"--poses {poses}: only for --kitti00 (other inputs bring their own "
                         "poses).")
    check_backend(backend)
    if scenarios:
        for option, value in (("--class-table", classes), ("--odom-topic", odom_topic),
                              ("--objects-topic", objects_topic)):
            if value is not None:
                raise SglocError(f"{option}: only for recorded inputs (a layout folder or "
                                 f"bags); --{scenarios[0]} brings its own classes and no "
                                 "topics.")
    if poses == "refined":
        require("gtsam", "gtsam", "--poses refined (the refined KITTI trajectory)")
    if scenarios:
        got = scenario_input(scenarios[0], seed=seed, **options)
    else:
        got = ReplayInput(_recorded(sources, named, classes, odom_topic, objects_topic))
    if root is not None and root not in {g.name for g in got.logs}:
        raise SglocError(f"--root {root!r} is not a robot of the input; robots: "
                         f"{', '.join(g.name for g in got.logs)}.")
    return ReplayJob(got.logs, got.preset, backend, root, seed, online)


def scenario_input(name: str, **options: Any) -> ReplayInput:
    """The scenario `name` of REPLAY_SCENARIOS with those of `options` it takes (the scenarios
    are added by `sgloc.evaluation.replay_scenarios`: import it first)."""
    if not REPLAY_SCENARIOS:
        raise SglocError(f"replay scenario {name!r}: no scenarios are loaded; import "
                         "sgloc.evaluation.replay_scenarios first (it adds kitti00 and city).")
    make = REPLAY_SCENARIOS.lookup(name)
    takes = inspect.signature(make).parameters
    return make(**{k: v for k, v in options.items() if k in takes})


def _recorded(sources, named, classes, odom_topic, objects_topic) -> list[RobotLog]:
    """The robots of one source, or of one source per robot (`named`: NAME=PATH items)."""
    from sgloc.replay.inputs import read_logs, read_robot_sources

    if len(sources) == 1 and not named:
        return read_logs(sources[0], classes, odom_topic, objects_topic)
    pairs = [(None, Path(p)) for p in sources]
    for item in named:
        name, sep, path = item.partition("=")
        if not sep or not name.strip() or not path.strip():
            raise SglocError(f"--robot {item!r}: give NAME=PATH, e.g. --robot "
                             "alpha=runs/alpha.mcap.")
        pairs.append((name.strip(), Path(path.strip())))
    return read_robot_sources(pairs, classes, odom_topic, objects_topic)


def check_backend(backend: str) -> None:
    """SglocError naming the back-ends when `backend` (`--backend`) is none of them."""
    from sgloc.online.backend import BACKENDS  # the session's machinery, on first use

    if backend not in BACKENDS:
        raise SglocError(f"--backend {backend!r}: choose {' or '.join(BACKENDS)}.")
