"""The cut data sets `sgloc replay` offers beside recorded runs, by name (`REPLAY_SCENARIOS`):
each a function of its options returning the robots' logs and the localizer preset that suits
them. The replay only keeps the registry; the scenarios come from the layer that makes runs
with ground truth, `sgloc.evaluation.replay_scenarios`, which adds `kitti00` (KITTI 00 cut into
consecutive segments) and `city` (the synthetic city's two routes cut into robots, objects only)
when it is imported."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from sgloc.io.keyframes import RobotLog
from sgloc.registry import Registry


@dataclass(frozen=True)
class ReplayInput:
    """The robots' logs to replay and the localizer preset they suit (None: the defaults)."""

    logs: list[RobotLog] = field(default_factory=list)
    preset: str | None = None


REPLAY_SCENARIOS: Registry[Callable[..., ReplayInput]] = Registry("replay scenario")
