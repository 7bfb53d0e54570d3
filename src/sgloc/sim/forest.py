"""Synthetic forests: tree trunks of one class on rolling ground, mapped by robots that start
together and drive apart, each map in its own frame with a few degrees of heading error that
grows slowly along its path (odometry drift), noisy, missing and spurious trunks.

World frame: x east, y north, z up, metres; the stand is the square [0, size]^2 and the robots
start near its centre. A map holds a trunk at breast height (1.3 m above the ground). Maps are
one class (label 0): only the geometry of the trunks tells places apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sgloc.geometry import invert
from sgloc.maps.graph import SemanticGraph
from sgloc.sim.scene_maps import MapPair, planar_transform, shared_count
from sgloc.validation import MAX_COORDINATE, real, setting, validate_settings

#: Height of a trunk's mapped centre above the ground (metres): breast height.
BREAST_HEIGHT = 1.3


@dataclass(frozen=True)
class ForestConfig:
    """A forest stand and how robots map it (lengths in metres).

    density: stems per m^2 (managed and natural stands: 0.02-0.1).
    clustering: share of the stems that grow in clumps (a Thomas process: clump centres
        Poisson, stems Gaussian around them with `clump_radius`); 0: a Poisson forest.
    size: side of the square stand.
    noise: standard deviation of a mapped trunk's horizontal position (0.2-0.5 m: trunk
        centres fitted to LiDAR returns); vertical: half of it.
    miss: chance that a robot's map lacks a trunk it passed.
    spurious: spurious trunks (bushes, stumps) per mapped trunk.
    view_radius: a robot maps the trunks within this distance of its path.
    drift_deg: each map's heading error at the start is uniform in +-drift_deg.
    drift_rate_deg: heading error added per 100 m driven (sign random per robot).
    start_offset: the robots start up to this far apart.
    terrain: amplitude of the rolling ground (its wavelength is 60 m).
    """

    density: float = setting(0.05, check=real(0.0, 10.0, low_open=True, unit="stems per m^2"))
    clustering: float = setting(0.0, check=real(0.0, 1.0))
    clump_radius: float = setting(4.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))

    def __post_init__(self) -> None:
        validate_settings(self, "ForestConfig")
    size: float = setting(400.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    noise: float = setting(0.3, check=real(0.0, MAX_COORDINATE, unit="m"))
    miss: float = setting(0.1, check=real(0.0, 1.0))
    spurious: float = setting(0.05, check=real(0.0, 100.0))
    view_radius: float = setting(15.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    drift_deg: float = setting(3.0, check=real(0.0, 180.0, unit="degrees"))
    drift_rate_deg: float = setting(0.5, check=real(0.0, 180.0, unit="degrees per 100 m"))
    start_offset: float = setting(1.0, check=real(0.0, MAX_COORDINATE, unit="m"))
    terrain: float = setting(2.0, check=real(0.0, MAX_COORDINATE, unit="m"))


def make_forest(rng: np.random.Generator, config: ForestConfig = ForestConfig()) -> np.ndarray:
    """(n,3) trunk positions (breast height, world frame) of a stand of config.density stems
    per m^2: Poisson, or partly clumped (config.clustering)."""
    area = config.size**2
    n = int(rng.poisson(config.density * area))
    n_clumped = int(round(config.clustering * n))
    xy = [rng.uniform(0.0, config.size, (n - n_clumped, 2))]
    if n_clumped:
        per_clump = 8.0
        centres = rng.uniform(0.0, config.size, (max(1, int(n_clumped / per_clump)), 2))
        pick = rng.integers(0, len(centres), n_clumped)
        xy.append(centres[pick] + rng.normal(0.0, config.clump_radius, (n_clumped, 2)))
    xy = np.concatenate(xy) % config.size
    return np.column_stack([xy, ground(xy, config) + BREAST_HEIGHT])


def ground(xy: np.ndarray, config: ForestConfig) -> np.ndarray:
    """Ground height (m) at the points xy (k,2): gentle hills of amplitude config.terrain."""
    w = 2.0 * np.pi / 60.0
    return 0.5 * config.terrain * (np.sin(w * xy[:, 0]) + np.cos(0.8 * w * xy[:, 1]))


def robot_path(
    rng: np.random.Generator, start: np.ndarray, heading: float, length: float, step: float = 1.0
) -> np.ndarray:
    """(k,2) points every `step` metres of a wandering path of `length` metres from `start`
    (xy) with initial `heading` (rad): the heading turns by a smooth random walk."""
    k = max(2, int(length / step) + 1)
    turn = np.convolve(rng.normal(0.0, 0.08, k), np.ones(8) / 8.0, mode="same")
    h = heading + np.cumsum(turn)
    steps = step * np.column_stack([np.cos(h), np.sin(h)])
    steps[0] = 0.0
    return start + np.cumsum(steps, axis=0)


@dataclass
class ForestMap:
    """A robot's map: object positions in its map frame, true trunk index per object (-1:
    spurious), and per point of its path the heading error (rad) and the position the robot
    believed it was at (xy, map frame)."""

    positions: np.ndarray
    truth: np.ndarray
    heading_error: np.ndarray
    believed: np.ndarray
    path: np.ndarray
    #: The map frame's x axis points along the robot's initial heading (rad, world frame).
    start_heading: float = 0.0

    def local_frame(self, k: int) -> np.ndarray:
        """T_map_world at path point k: how the world maps into this map there (at the start,
        k = 0, the map's frame; elsewhere drifted)."""
        T = planar_transform(float(self.heading_error[k]), np.zeros(3))
        T[:2, 3] = self.believed[k] - T[:2, :2] @ self.path[k]
        return planar_transform(-self.start_heading, np.zeros(3)) @ T

    @property
    def T_map_world(self) -> np.ndarray:
        """T_map_world at the start of the path."""
        return self.local_frame(0)


def map_along_path(
    rng: np.random.Generator,
    trunks: np.ndarray,
    path: np.ndarray,
    config: ForestConfig,
    view_radius: float | None = None,
) -> ForestMap:
    """The map a robot drives along `path` (k,2) makes of `trunks` (n,3): trunks within the view
    radius, each missed with config.miss, noisy, plus spurious ones; in the robot's map frame
    (origin at the path's start, x along its first step, heading error growing along the
    path)."""
    radius = config.view_radius if view_radius is None else view_radius
    d, at = cKDTree(path).query(trunks[:, :2])
    seen = np.flatnonzero((d < radius) & (rng.random(len(trunks)) >= config.miss))
    n_spur = int(rng.poisson(config.spurious * len(seen)))
    where = rng.integers(0, len(path), n_spur)
    r = radius * np.sqrt(rng.random(n_spur))
    a = rng.uniform(0.0, 2.0 * np.pi, n_spur)
    fake_xy = path[where] + np.column_stack([r * np.cos(a), r * np.sin(a)])
    fake = np.column_stack([fake_xy, ground(fake_xy, config) + BREAST_HEIGHT])
    world = np.concatenate([trunks[seen], fake])
    idx = np.concatenate([at[seen], where])
    truth = np.concatenate([seen, np.full(n_spur, -1)])
    # Heading error along the path and the drifted path the robot believes it drove.
    e0 = np.radians(rng.uniform(-config.drift_deg, config.drift_deg))
    rate = np.radians(config.drift_rate_deg) / 100.0 * rng.choice([-1.0, 1.0])
    e = e0 + rate * np.arange(len(path)) * _step(path)
    delta = np.diff(path, axis=0)
    c, s = np.cos(e[1:]), np.sin(e[1:])
    believed = np.vstack([[0.0, 0.0], np.cumsum(
        np.column_stack([c * delta[:, 0] - s * delta[:, 1], s * delta[:, 0] + c * delta[:, 1]]),
        axis=0)])  # fmt: skip
    v = world[:, :2] - path[idx]
    ce, se = np.cos(e[idx]), np.sin(e[idx])
    xy = believed[idx] + np.column_stack([ce * v[:, 0] - se * v[:, 1], se * v[:, 0] + ce * v[:, 1]])
    pos = np.column_stack([xy, world[:, 2]])
    pos += rng.normal(0.0, 1.0, pos.shape) * np.array([1.0, 1.0, 0.5]) * config.noise
    h = float(np.arctan2(*(path[1] - path[0])[::-1])) if len(path) > 1 else 0.0
    pos[:, :2] = pos[:, :2] @ planar_transform(-h, np.zeros(3))[:2, :2].T
    order = rng.permutation(len(pos))  # no hint of the truth in the vertex order
    return ForestMap(pos[order], truth[order], e, believed, path, h)


def _step(path: np.ndarray) -> float:
    return float(np.linalg.norm(path[1] - path[0])) if len(path) > 1 else 1.0


def forest_pair(
    rng: np.random.Generator,
    config: ForestConfig = ForestConfig(),
    lengths: tuple[float, float] = (150.0, 150.0),
    divergence_deg: tuple[float, float] = (20.0, 90.0),
) -> MapPair:
    """Two robots' trunk maps: they start together near the stand's centre (within
    config.start_offset), their headings `divergence_deg` apart (uniform in the range), and
    drive wandering paths of `lengths` metres; the maps overlap around the start.
    T_target_query relates the two maps' frames at the start (target: the first robot)."""
    trunks = make_forest(rng, config)
    centre = np.full(2, config.size / 2.0)
    h0 = rng.uniform(0.0, 2.0 * np.pi)
    h1 = h0 + np.radians(rng.uniform(*divergence_deg)) * rng.choice([-1.0, 1.0])
    offset = rng.normal(0.0, config.start_offset / 2.0, 2)
    paths = [robot_path(rng, centre, h0, lengths[0]),
             robot_path(rng, centre + offset, h1, lengths[1])]  # fmt: skip
    tgt, qry = (map_along_path(rng, trunks, p, config) for p in paths)
    T = tgt.T_map_world @ invert(qry.T_map_world)
    info = {"trunks": len(trunks), "density": config.density}
    return MapPair(
        SemanticGraph(qry.positions, np.zeros(len(qry.positions), np.int64), name="forest B"),
        SemanticGraph(tgt.positions, np.zeros(len(tgt.positions), np.int64), name="forest A"),
        T, shared_count(qry.truth, tgt.truth), qry.truth, tgt.truth, info,
    )  # fmt: skip


def forest_scan(
    rng: np.random.Generator,
    config: ForestConfig = ForestConfig(),
    length: float = 250.0,
    scan_radius: float = 20.0,
) -> MapPair:
    """One LiDAR scan of trunks (those within `scan_radius` of a sensor placed near a random
    point of the mapping robot's path, in the sensor's frame: any heading, 1 m above the
    ground) against the map that robot made of a `length` m path. The ground truth is the
    map's local frame there (its drift at that point of the path)."""
    trunks = make_forest(rng, config)
    centre = np.full(2, config.size / 2.0)
    path = robot_path(rng, centre, rng.uniform(0.0, 2.0 * np.pi), length)
    tgt = map_along_path(rng, trunks, path, config)
    # A point of the path inside the stand (a path may wander out of it).
    inside = np.flatnonzero(np.all((path > 0.0) & (path < config.size), axis=1))
    k = int(inside[rng.integers(0, len(inside))]) if inside.size else 0
    spot = path[k] + rng.normal(0.0, 3.0, 2)
    scan = map_along_path(rng, trunks, spot[None, :], config, view_radius=scan_radius)
    yaw = rng.uniform(0.0, 2.0 * np.pi)
    T_sensor_scan = planar_transform(yaw, np.array([0.0, 0.0, -1.0]))
    # The map's frame is shifted to put its origin where the robot believed it was at point k,
    # so that an error at the origin is the error where the scan was taken.
    at = tgt.local_frame(k) @ np.append(path[k], [0.0, 1.0])
    shift = planar_transform(0.0, -np.append(at[:2], 0.0))
    T = shift @ tgt.local_frame(k) @ invert(T_sensor_scan @ scan.T_map_world)
    q = scan.positions @ T_sensor_scan[:3, :3].T + T_sensor_scan[:3, 3]
    p = tgt.positions + shift[:3, 3]
    return MapPair(
        SemanticGraph(q, np.zeros(len(q), np.int64), name="scan"),
        SemanticGraph(p, np.zeros(len(p), np.int64), name="forest map"),
        T, shared_count(scan.truth, tgt.truth), scan.truth, tgt.truth,
        {"trunks": len(trunks), "path_index": k},
    )  # fmt: skip


def forest_negative(
    rng: np.random.Generator,
    config: ForestConfig = ForestConfig(),
    lengths: tuple[float, float] = (150.0, 150.0),
) -> MapPair:
    """A negative: two robots' trunk maps of two different stands of the same statistics (no
    trunk in common; any alignment a localizer accepts is wrong). T_target_query: identity."""
    maps = []
    for length in lengths:
        trunks = make_forest(rng, config)
        centre = np.full(2, config.size / 2.0)
        path = robot_path(rng, centre, rng.uniform(0.0, 2.0 * np.pi), length)
        maps.append(map_along_path(rng, trunks, path, config))
    tgt, qry = maps
    zeros = [np.zeros(len(m.positions), np.int64) for m in (qry, tgt)]
    return MapPair(
        SemanticGraph(qry.positions, zeros[0], name="forest B"),
        SemanticGraph(tgt.positions, zeros[1], name="forest A"),
        np.eye(4), 0, np.full(len(qry.positions), -1), np.full(len(tgt.positions), -1),
        {"negative": True},
    )  # fmt: skip
