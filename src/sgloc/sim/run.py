"""A synthetic two-robot run in one object: city + routes + camera, rendered on demand, with
the ground truth between the robots' start frames; writes itself in the Airsim layout."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sgloc.datasets.base import Frame
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.presets import localizer_preset, localizer_settings
from sgloc.sim.airsim_writer import write_ground_truth, write_robot, write_run_metadata
from sgloc.sim.city import City, CityConfig, make_city
from sgloc.sim.render import Camera, render_frames
from sgloc.sim.trajectory import ROBOT_NAMES, TrajectoryConfig, TwoRobotRoutes, make_routes
from sgloc.validation import (
    MAX_COORDINATE,
    group,
    integer,
    real,
    setting,
    validate_settings,
)

#: Robot A (the target map) and robot B (the query), as in Guo's Airsim data.
TARGET, QUERY = ROBOT_NAMES

#: Localizer settings for graphs extracted from the city (the `city` preset of
# sgloc.pipeline.presets).
CITY_LOCALIZER_SETTINGS: dict = localizer_settings("city")


def city_localizer_config() -> LocalizerConfig:
    """LocalizerConfig for the synthetic city (the paper's defaults + the `city` preset)."""
    return localizer_preset("city")


@dataclass
class SyntheticRunConfig:
    """Everything that fixes a synthetic run. One `seed` gives the city and the streets; the
    overlap only moves robot B along the same path."""

    seed: int = setting(0, check=integer(0))
    overlap: float = setting(0.5, check=real(0.0, 1.0))
    width: int = setting(320, check=integer(2, 100_000))
    height: int = setting(180, check=integer(2, 100_000))
    length: float = setting(400.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    step: float = setting(1.5, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    city: CityConfig = setting(default_factory=CityConfig, check=group(CityConfig))
    trajectory: TrajectoryConfig = setting(
        default_factory=TrajectoryConfig, check=group(TrajectoryConfig)
    )

    def __post_init__(self) -> None:
        validate_settings(self, "SyntheticRunConfig")

    def resolved_trajectory(self) -> TrajectoryConfig:
        return dataclasses.replace(
            self.trajectory, overlap=self.overlap, length=self.length, step=self.step
        )

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["trajectory"] = dataclasses.asdict(self.resolved_trajectory())
        return d

    def key(self) -> str:
        """A short hash naming this run (for caches)."""
        blob = json.dumps(self.to_dict(), sort_keys=True, default=list)
        return hashlib.sha1(blob.encode()).hexdigest()[:12]


class SyntheticRun:
    """The city, both robots' routes and the camera of one synthetic run."""

    def __init__(self, config: SyntheticRunConfig | None = None) -> None:
        self.config = cfg = config or SyntheticRunConfig()
        city_seq, route_seq = np.random.SeedSequence(cfg.seed).spawn(2)
        self.city: City = make_city(np.random.default_rng(city_seq), cfg.city)
        self.routes: TwoRobotRoutes = make_routes(
            self.city, cfg.resolved_trajectory(), np.random.default_rng(route_seq)
        )
        self.camera = Camera(cfg.width, cfg.height)

    @property
    def robots(self) -> tuple[str, str]:
        return ROBOT_NAMES

    def n_frames(self, robot: str) -> int:
        return len(self.routes.T_world_body[robot])

    @property
    def ground_truth(self) -> np.ndarray:
        """T_target_query = T_forwardCar_backwardCar between the robots' start frames."""
        return self.routes.ground_truth(TARGET, QUERY)

    def frames(self, robot: str) -> Iterator[Frame]:
        """The robot's rendered frames, poses in its start frame (float depth, inf = sky)."""
        return render_frames(self.city.primitives, self.routes.T_world_body[robot], self.camera)

    def write(self, run_dir: str | Path, progress: Callable[[int], None] | None = None) -> Path:
        """Render both robots into `run_dir` in the Airsim layout, with ground_truth.txt and
        run.json; `progress(n)` is called with the number of frames just written."""
        run_dir = Path(run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        for robot in ROBOT_NAMES:
            write_robot(run_dir / robot, self.frames(robot), progress)
        write_ground_truth(run_dir, self.ground_truth, TARGET, QUERY)
        write_run_metadata(
            run_dir,
            {
                "config": self.config.to_dict(),
                "robots": {"target": TARGET, "query": QUERY},
                "frames": {r: self.n_frames(r) for r in ROBOT_NAMES},
                "shared_fraction": self.routes.shared_fraction,
                "T_world_start": {r: self.routes.start_pose(r) for r in ROBOT_NAMES},
                "n_objects": self.city.n_objects,
            },
        )
        return run_dir


def make_synthetic_run(seed: int = 0, overlap: float = 0.5, **settings) -> SyntheticRun:
    """A synthetic run; `settings` are SyntheticRunConfig fields (width, height, length, ...)."""
    return SyntheticRun(SyntheticRunConfig(seed=seed, overlap=overlap, **settings))
