"""The cut data sets `sgloc replay` offers beside recorded runs, by name (`REPLAY_SCENARIOS`):
each a function of its options returning the robots' logs and the localizer preset that suits
them. `kitti00`: KITTI 00 cut into consecutive segments; `city`: the synthetic city's two routes
cut into robots (objects only, no rendering)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from sgloc.errors import SglocError
from sgloc.io.keyframes import RobotLog
from sgloc.registry import Registry


@dataclass(frozen=True)
class ReplayInput:
    """The robots' logs to replay and the localizer preset they suit (None: the defaults)."""

    logs: list[RobotLog] = field(default_factory=list)
    preset: str | None = None


REPLAY_SCENARIOS: Registry[Callable[..., ReplayInput]] = Registry("replay scenario")


@REPLAY_SCENARIOS.register("kitti00")
def kitti00(robots: int = 4, scans: str = "0-2999", every: int = 1,
            poses: str = "raw") -> ReplayInput:
    """KITTI 00 (data `kitti00`) scans `first-last` cut into `robots` consecutive segments,
    every `every`-th scan a keyframe; `poses` raw (poses_00.txt) or refined (needs gtsam)
    (`sgloc.evaluation.replay_scenarios.kitti_scenario`)."""
    from sgloc.evaluation.replay_scenarios import kitti_scenario

    try:
        first, last = (int(v) for v in scans.split("-"))
    except ValueError:
        raise SglocError(f"--scans {scans!r}: give first-last, e.g. 0-2999.") from None
    return ReplayInput(kitti_scenario(robots, first, last, every, poses).logs, "kitti-objects")


@REPLAY_SCENARIOS.register("city")
def city(robots: int = 4, seed: int = 0) -> ReplayInput:
    """The synthetic city `seed`'s two routes cut into `robots` robots, objects only
    (`sgloc.evaluation.replay_scenarios.city_scenario`)."""
    from sgloc.evaluation.replay_scenarios import city_scenario

    return ReplayInput(city_scenario(robots, seed).logs, "city-objects")
