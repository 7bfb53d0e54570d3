"""Synthetic worlds for demos, tests and benchmarks: a tiny object-level world, and a rendered
procedural city (buildings, trees, poles, cars, ...) driven by two robots with semantic + depth
cameras, written in the Airsim layout."""

from sgloc.sim.airsim_writer import read_ground_truth, write_ground_truth, write_robot
from sgloc.sim.city import CITY_CLASSES, City, CityConfig, Primitives, make_city
from sgloc.sim.object_world import TwoRobotScene, make_object_world, make_two_robot_scene
from sgloc.sim.render import T_BODY_OPTICAL, Camera, Renderer, Rendering, render_frames
from sgloc.sim.run import (
    CITY_LOCALIZER_SETTINGS,
    QUERY,
    TARGET,
    SyntheticRun,
    SyntheticRunConfig,
    city_localizer_config,
    make_synthetic_run,
)
from sgloc.sim.trajectory import ROBOT_NAMES, TrajectoryConfig, TwoRobotRoutes, make_routes

__all__ = [
    "CITY_CLASSES",
    "CITY_LOCALIZER_SETTINGS",
    "QUERY",
    "ROBOT_NAMES",
    "TARGET",
    "T_BODY_OPTICAL",
    "Camera",
    "City",
    "CityConfig",
    "Primitives",
    "Renderer",
    "Rendering",
    "SyntheticRun",
    "SyntheticRunConfig",
    "TrajectoryConfig",
    "TwoRobotRoutes",
    "TwoRobotScene",
    "city_localizer_config",
    "make_city",
    "make_object_world",
    "make_routes",
    "make_synthetic_run",
    "make_two_robot_scene",
    "read_ground_truth",
    "render_frames",
    "write_ground_truth",
    "write_robot",
]
