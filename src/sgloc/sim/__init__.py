"""Synthetic worlds for demos, tests and benchmarks: a tiny object-level world, a rendered
procedural city (buildings, trees, poles, cars, ...) driven by two robots with semantic + depth
cameras, written in the Airsim layout, and object maps of forests (one class) and of rooms and
floors (furniture), each robot's in its own frame (`MapPair`)."""

from sgloc.sim.airsim_writer import read_ground_truth, write_ground_truth, write_robot
from sgloc.sim.city import CITY_CLASSES, City, CityConfig, Primitives, make_city
from sgloc.sim.forest import (
    ForestConfig,
    forest_negative,
    forest_pair,
    forest_scan,
    make_forest,
)
from sgloc.sim.object_world import TwoRobotScene, make_object_world, make_two_robot_scene
from sgloc.sim.render import T_BODY_OPTICAL, Camera, Renderer, Rendering, render_frames
from sgloc.sim.rooms import (
    FURNITURE_CLASSES,
    RoomConfig,
    floor_pair,
    make_floor,
    make_room,
    repeated_room_pair,
    room_pair,
)
from sgloc.sim.run import (
    CITY_LOCALIZER_SETTINGS,
    QUERY,
    TARGET,
    SyntheticRun,
    SyntheticRunConfig,
    city_localizer_config,
    make_synthetic_run,
)
from sgloc.sim.scene_maps import MapPair
from sgloc.sim.trajectory import ROBOT_NAMES, TrajectoryConfig, TwoRobotRoutes, make_routes

__all__ = [
    "CITY_CLASSES",
    "CITY_LOCALIZER_SETTINGS",
    "FURNITURE_CLASSES",
    "ForestConfig",
    "MapPair",
    "RoomConfig",
    "floor_pair",
    "forest_negative",
    "forest_pair",
    "forest_scan",
    "make_floor",
    "make_forest",
    "make_room",
    "repeated_room_pair",
    "room_pair",
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
