"""Synthetic worlds for demos, tests and benchmarks."""

from sgloc.sim.object_world import TwoRobotScene, make_object_world, make_two_robot_scene

__all__ = ["TwoRobotScene", "make_object_world", "make_two_robot_scene"]
