"""Two robots driving opposite ways along the city's streets, sharing a controllable fraction
of their routes, and their camera poses.

Both routes are stretches of one self-avoiding path through the street grid. Robot A
("forwardCar") drives arc length [0, L] of the path; robot B ("backwardCar") drives
[s, s + L] backwards, with s = (1 - overlap) * (L + gap). Each keeps to the right-hand lane of
its own direction, so on shared streets they pass each other 2 * lane_offset apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.errors import SglocError
from sgloc.geometry import invert
from sgloc.sim.city import City
from sgloc.validation import MAX_COORDINATE, real, setting, validate_settings

ROBOT_NAMES = ("forwardCar", "backwardCar")


@dataclass
class TrajectoryConfig:
    """Routes and camera poses (lengths in metres).

    length: route length of each robot (L).
    step: distance between two frames along the street centre line (metres; in turns the
        outer lane is a little longer, the inner one shorter).
    overlap: fraction of the route the two robots share, 0 (disjoint) to 1 (same streets).
    gap: extra separation along the path at overlap 0 (s = (1 - overlap) * (length + gap)); with
        gap >= twice the camera range the robots see nothing in common at overlap 0.
    lane_offset: centre line to the robot's lane centre (to its right).
    camera_height: camera height above the ground.
    pitch_deg: camera pitch, positive looking down.
    corner_radius: half-width of the smoothing window that rounds the turns.
    straight_probability: chance to go straight on at an intersection (else turn).
    """

    length: float = setting(400.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    step: float = setting(1.5, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    overlap: float = setting(0.5, check=real(0.0, 1.0))
    gap: float = setting(0.0, check=real(0.0, MAX_COORDINATE, unit="m"))
    lane_offset: float = setting(1.75, check=real(-100.0, 100.0, unit="m"))
    camera_height: float = setting(1.6, check=real(-100.0, 1000.0, unit="m"))
    pitch_deg: float = setting(0.0, check=real(-90.0, 90.0, unit="degrees"))
    corner_radius: float = setting(8.0, check=real(0.0, MAX_COORDINATE, unit="m"))
    straight_probability: float = setting(0.6, check=real(0.0, 1.0))

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check every setting again (InvalidSettingError naming the first bad one)."""
        validate_settings(self, "TrajectoryConfig")


@dataclass
class TwoRobotRoutes:
    """Camera-body poses of the two robots in the world frame, and their shared path.

    T_world_body: per robot name, (N,4,4) world-from-body poses; body axes x forward, y right,
        z down (AirSim), so a level camera's body z points to -z of the world.
    centerline: (m,2) the smoothed street centre line both routes follow (world x, y).
    arc: per robot, (N,) arc length of each frame along `centerline`.
    overlap: the requested overlap; `shared_fraction` the resulting one (shared arc / L).
    """

    T_world_body: dict[str, np.ndarray]
    centerline: np.ndarray
    arc: dict[str, np.ndarray]
    overlap: float
    shared_fraction: float
    config: TrajectoryConfig

    @property
    def names(self) -> tuple[str, str]:
        return ROBOT_NAMES

    def start_pose(self, robot: str) -> np.ndarray:
        """T_world_start: the robot's map frame is its body frame at frame 0."""
        return self.T_world_body[robot][0]

    def poses_in_start_frame(self, robot: str) -> np.ndarray:
        """(N,4,4) T_start_body of each frame (frame 0 is the identity)."""
        return invert(self.start_pose(robot)) @ self.T_world_body[robot]

    def ground_truth(self, target: str = ROBOT_NAMES[0], query: str = ROBOT_NAMES[1]):
        """T_target_query between the two robots' start frames (4x4)."""
        return invert(self.start_pose(target)) @ self.start_pose(query)


def _neighbours(node: tuple[int, int], lo: int, hi: int) -> list[tuple[int, int]]:
    i, j = node
    out = [(i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)]
    return [(a, b) for a, b in out if lo <= a <= hi and lo <= b <= hi]


def grid_path(
    city: City,
    n_edges: int,
    rng: np.random.Generator,
    straight_probability: float = 0.6,
    max_tries: int = 200,
) -> np.ndarray:
    """A random self-avoiding walk of `n_edges` street segments over the inner intersections
    (1..blocks-1 each way), as (n_edges+1, 2) world (x, y) points. Prefers going straight."""
    cfg = city.config
    lo, hi = 1, cfg.blocks - 1
    if hi - lo < 1:
        raise SglocError(f"the city needs at least 3 blocks a side for routes, has {cfg.blocks}.")
    for _ in range(max_tries):
        node = (int(rng.integers(lo, hi + 1)), int(rng.integers(lo, hi + 1)))
        path, seen = [node], {node}
        heading = None
        while len(path) <= n_edges:
            options = [n for n in _neighbours(path[-1], lo, hi) if n not in seen]
            if not options:
                break
            nxt = None
            if heading is not None and rng.random() < straight_probability:
                ahead = (path[-1][0] + heading[0], path[-1][1] + heading[1])
                if ahead in options:
                    nxt = ahead
            if nxt is None:
                nxt = options[int(rng.integers(len(options)))]
            heading = (nxt[0] - path[-1][0], nxt[1] - path[-1][1])
            path.append(nxt)
            seen.add(nxt)
        if len(path) > n_edges:
            return np.array(path, dtype=np.float64) * cfg.pitch
    raise SglocError(
        f"could not find a route of {n_edges} street segments in a {cfg.blocks}x{cfg.blocks} "
        "city; use a larger city (CityConfig.blocks) or shorter routes."
    )


def _smooth_path(corners: np.ndarray, radius: float, ds: float = 0.25):
    """Resample the polyline every `ds` metres and round its corners with a moving average of
    half-width `radius`; returns (points (m,2), unit tangents (m,2), arc length (m,))."""
    seg = np.diff(corners, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    pad = 3 * radius + 4 * ds  # > the support of the two box filters below (zero padded)
    s = np.arange(-pad, cum[-1] + pad + ds / 2, ds)
    # extend the first/last segments straight on so the ends stay straight after smoothing
    idx = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    pts = corners[idx] + (s - cum[idx])[:, None] * (seg[idx] / seg_len[idx, None])
    k = max(1, int(round(radius / ds)))
    if radius > 0:
        w = np.ones(2 * k + 1) / (2 * k + 1)
        for _ in range(2):
            pts = np.stack([np.convolve(pts[:, d], w, mode="same") for d in range(2)], axis=1)
    inner = (s >= 0) & (s <= cum[-1])
    pts = pts[inner]
    d = np.gradient(pts, axis=0)
    tangent = d / np.linalg.norm(d, axis=1, keepdims=True)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return pts, tangent, arc


def body_poses(
    xy: np.ndarray, heading: np.ndarray, height: float, pitch_deg: float = 0.0
) -> np.ndarray:
    """(N,4,4) T_world_body for cameras at (x, y, height) looking along unit `heading` (N,2),
    pitched down by `pitch_deg`. Body axes: x forward, y right, z down."""
    n = len(xy)
    c, s = heading[:, 0], heading[:, 1]
    fwd = np.stack([c, s, np.zeros(n)], axis=1)
    right = np.stack([s, -c, np.zeros(n)], axis=1)
    down = np.tile([0.0, 0.0, -1.0], (n, 1))
    p = np.deg2rad(pitch_deg)
    x_b = np.cos(p) * fwd + np.sin(p) * down
    z_b = -np.sin(p) * fwd + np.cos(p) * down
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2] = x_b, right, z_b
    T[:, :2, 3] = xy
    T[:, 2, 3] = height
    return T


def make_routes(
    city: City,
    config: TrajectoryConfig | None = None,
    seed: int | np.random.Generator = 0,
) -> TwoRobotRoutes:
    """Plan the two robots' routes through `city` and their per-frame camera poses."""
    cfg = config or TrajectoryConfig()
    cfg.validate()
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    n = int(np.floor(cfg.length / cfg.step + 1e-9)) + 1
    L = (n - 1) * cfg.step  # the length actually driven
    offset = (1.0 - cfg.overlap) * (L + cfg.gap)
    # plan the path for overlap 0 whatever the overlap, so one seed gives the same streets at
    # every overlap and only robot B's stretch moves
    need = (L + cfg.gap) + L + 2 * cfg.corner_radius + cfg.step
    n_edges = int(np.ceil(need / city.config.pitch)) + 1
    corners = grid_path(city, n_edges, rng, cfg.straight_probability)
    pts, tangent, arc = _smooth_path(corners, cfg.corner_radius)
    start = cfg.corner_radius / 2

    def sample(s: np.ndarray, backwards: bool) -> np.ndarray:
        x = np.interp(s, arc, pts[:, 0])
        y = np.interp(s, arc, pts[:, 1])
        tx = np.interp(s, arc, tangent[:, 0])
        ty = np.interp(s, arc, tangent[:, 1])
        t = np.stack([tx, ty], axis=1)
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        if backwards:
            t = -t
        right = np.stack([t[:, 1], -t[:, 0]], axis=1)
        xy = np.stack([x, y], axis=1) + cfg.lane_offset * right
        return body_poses(xy, t, cfg.camera_height, cfg.pitch_deg)

    s_a = start + np.arange(n) * cfg.step
    s_b = start + offset + L - np.arange(n) * cfg.step
    T = {ROBOT_NAMES[0]: sample(s_a, False), ROBOT_NAMES[1]: sample(s_b, True)}
    shared = max(0.0, min(s_a[-1], s_b[0]) - max(s_a[0], s_b[-1])) / max(s_a[-1] - s_a[0], 1e-9)
    return TwoRobotRoutes(
        T_world_body=T,
        centerline=pts,
        arc={ROBOT_NAMES[0]: s_a, ROBOT_NAMES[1]: s_b},
        overlap=cfg.overlap,
        shared_fraction=float(shared),
        config=cfg,
    )
