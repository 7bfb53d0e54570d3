"""Synthetic rooms and floors: furniture-like objects (desks with chairs and monitors along the
walls, meeting tables ringed by chairs, shelves, cabinets, lamps, plants, bins) in rooms of
20-60 objects, rooms side by side along a corridor, and robots whose maps each hold a part of
a room or of a floor, in their own frame, with ~5 cm noise and missed objects.

Room frame: origin at a corner, x along the room's width, y along its depth, z up, metres.
A floor is two rows of rooms facing each other across a corridor along x. Identical offices
(the same layout in several rooms) make a floor where one office alone cannot tell which it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.geometry import random_rigid_transform
from sgloc.maps.graph import SemanticGraph
from sgloc.sim.scene_maps import MapPair, shared_count
from sgloc.validation import MAX_COORDINATE, real, setting, span, validate_settings

#: Class names of the furniture; class k of a room map is FURNITURE_CLASSES[k].
FURNITURE_CLASSES: tuple[str, ...] = (
    "chair", "table", "desk", "shelf", "lamp", "plant", "sofa", "cabinet", "monitor", "bin",
)  # fmt: skip
_ID = {name: k for k, name in enumerate(FURNITURE_CLASSES)}
#: Height (m) of each class's mapped centre.
_HEIGHT = {"chair": 0.5, "table": 0.75, "desk": 0.75, "shelf": 1.0, "lamp": 1.5, "plant": 0.5,
           "sofa": 0.45, "cabinet": 0.6, "monitor": 1.0, "bin": 0.2}  # fmt: skip
#: Objects closer than this (m, horizontally) are not placed (furniture does not overlap).
MIN_GAP = 0.45


@dataclass(frozen=True)
class RoomConfig:
    """Rooms, floors and how robots map them (lengths in metres).

    objects: a room's object count is uniform in this range.
    width, depth: a room's size is uniform in these ranges (x, y).
    noise: standard deviation of a mapped object's position, each axis (~5 cm: object centres
        from RGB-D or LiDAR segments).
    miss: chance that a map lacks an object its robot saw.
    spurious: spurious objects (of a random class) per mapped object.
    corridor: width of a floor's corridor; wall: thickness of the walls between rooms.
    """

    objects: tuple[int, int] = setting((20, 60), check=span(1, 100000, whole=True))
    width: tuple[float, float] = setting((8.0, 14.0), check=span(0.5, MAX_COORDINATE, unit="m"))
    depth: tuple[float, float] = setting((6.0, 10.0), check=span(0.5, MAX_COORDINATE, unit="m"))
    noise: float = setting(0.05, check=real(0.0, MAX_COORDINATE, unit="m"))
    miss: float = setting(0.1, check=real(0.0, 1.0))
    spurious: float = setting(0.03, check=real(0.0, 100.0))
    corridor: float = setting(2.5, check=real(0.0, MAX_COORDINATE, unit="m"))
    wall: float = setting(0.2, check=real(0.0, MAX_COORDINATE, unit="m"))

    def __post_init__(self) -> None:
        validate_settings(self, "RoomConfig")


class _Placer:
    """Places objects in a width x depth room, refusing spots within MIN_GAP of another."""

    def __init__(self, rng: np.random.Generator, width: float, depth: float) -> None:
        self.rng, self.width, self.depth = rng, width, depth
        self.xy: list[np.ndarray] = []
        self.names: list[str] = []

    def free(self, pts: np.ndarray) -> bool:
        inside = np.all((pts > 0.2) & (pts < [self.width - 0.2, self.depth - 0.2]))
        if not inside:
            return False
        if not self.xy:
            return True
        d = np.linalg.norm(np.asarray(self.xy)[None, :, :] - pts[:, None, :], axis=2)
        return bool(d.min() >= MIN_GAP)

    def put(self, pts: np.ndarray, names: list[str]) -> bool:
        if not self.free(pts):
            return False
        self.xy += list(pts)
        self.names += names
        return True

    def wall_spot(self, inset: float) -> tuple[np.ndarray, np.ndarray]:
        """A point `inset` metres from a random wall and the unit normal into the room."""
        wall = int(self.rng.integers(0, 4))
        u = self.rng.uniform(0.6, 1.0 - 0.6 / max(self.width, self.depth))
        if wall < 2:  # walls y = 0 and y = depth
            p = np.array([u * self.width, inset if wall == 0 else self.depth - inset])
            return p, np.array([0.0, 1.0 if wall == 0 else -1.0])
        p = np.array([inset if wall == 2 else self.width - inset, u * self.depth])
        return p, np.array([1.0 if wall == 2 else -1.0, 0.0])


def _group(placer: _Placer) -> tuple[np.ndarray, list[str]]:
    """One furniture group at a random spot: a workstation, a meeting table with chairs, a
    shelf or cabinet or sofa by a wall, or a single lamp / plant / bin / chair."""
    rng = placer.rng
    kind = rng.choice(["desk", "table", "wall", "single"], p=[0.4, 0.15, 0.25, 0.2])
    if kind == "desk":
        p, n = placer.wall_spot(0.45)
        side = np.array([-n[1], n[0]])
        pts, names = [p, p + 0.75 * n, p + 0.5 * side], ["desk", "chair", "monitor"]
        if rng.random() < 0.3:
            pts.append(p - 0.55 * side)
            names.append("lamp")
        return np.array(pts), names
    if kind == "table":
        c = np.array([rng.uniform(2.0, placer.width - 2.0), rng.uniform(2.0, placer.depth - 2.0)])
        k = int(rng.integers(3, 7))
        a = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(k) / k
        ring = c + 1.0 * np.column_stack([np.cos(a), np.sin(a)])
        return np.vstack([c, ring]), ["table"] + ["chair"] * k
    if kind == "wall":
        p, _ = placer.wall_spot(0.3)
        return p[None, :], [str(rng.choice(["shelf", "shelf", "cabinet", "sofa"]))]
    p = np.array([rng.uniform(0.3, placer.width - 0.3), rng.uniform(0.3, placer.depth - 0.3)])
    return p[None, :], [str(rng.choice(["lamp", "plant", "bin", "chair"]))]


def make_room(
    rng: np.random.Generator, width: float, depth: float, n_objects: int
) -> tuple[np.ndarray, np.ndarray]:
    """A furnished room of `n_objects` objects (fewer if it is full): (positions (n,3) in the
    room frame, labels (n,) ids into FURNITURE_CLASSES)."""
    placer = _Placer(rng, width, depth)
    for _ in range(50 * n_objects):
        if len(placer.names) >= n_objects:
            break
        pts, names = _group(placer)
        placer.put(pts, names)
    xy, names = np.asarray(placer.xy)[:n_objects], placer.names[:n_objects]
    z = np.array([_HEIGHT[s] for s in names])
    return np.column_stack([xy, z]), np.array([_ID[s] for s in names], dtype=np.int64)


@dataclass
class Floor:
    """A floor of rooms: every object's position (n,3, floor frame), label and room id (-1:
    the corridor), and each room's origin (r,2) and size (r,2)."""

    positions: np.ndarray
    labels: np.ndarray
    room: np.ndarray
    origins: np.ndarray
    sizes: np.ndarray


def make_floor(
    rng: np.random.Generator,
    n_rooms: int = 6,
    config: RoomConfig = RoomConfig(),
    repeated: int = 0,
) -> Floor:
    """A floor of `n_rooms` rooms in two rows along a corridor (rooms 0, 2, 4, ... south of it,
    1, 3, 5, ... north), each furnished by `make_room`; the first `repeated` rooms are identical
    offices (the same layout, moved), the others each their own. A few plants and bins stand
    in the corridor."""
    w, d = rng.uniform(*config.width), rng.uniform(*config.depth)
    office = make_room(rng, w, d, int(rng.integers(config.objects[0], config.objects[1] + 1)))
    pos, lab, room, origins = [], [], [], []
    for r in range(n_rooms):
        x0 = (r // 2) * (w + config.wall)
        y0 = 0.0 if r % 2 == 0 else d + config.corridor
        n = int(rng.integers(config.objects[0], config.objects[1] + 1))
        p, lab_r = office if r < repeated else make_room(rng, w, d, n)
        pos.append(p + [x0, y0, 0.0])
        lab.append(lab_r)
        room.append(np.full(len(p), r))
        origins.append((x0, y0))
    length = ((n_rooms + 1) // 2) * (w + config.wall)
    k = max(1, int(length / 6.0))
    cx = np.sort(rng.uniform(0.5, length - 0.5, k))
    cy = d + rng.choice([0.3, config.corridor - 0.3], k)
    pos.append(np.column_stack([cx, cy, np.full(k, _HEIGHT["plant"])]))
    lab.append(rng.choice([_ID["plant"], _ID["bin"]], k))
    room.append(np.full(k, -1))
    return Floor(np.concatenate(pos), np.concatenate(lab), np.concatenate(room),
                 np.asarray(origins), np.tile([w, d], (n_rooms, 1)))  # fmt: skip


def observe(
    rng: np.random.Generator,
    positions: np.ndarray,
    labels: np.ndarray,
    visible: np.ndarray,
    config: RoomConfig,
    name: str,
) -> tuple[SemanticGraph, np.ndarray, np.ndarray]:
    """A robot's map of the `visible` objects (bool (n,)): each missed with config.miss, noisy,
    with spurious objects among them, moved into the robot's own frame (any yaw, up to 2 m:
    a robot's frame starts where it does, in the building; gravity shared). Returns (map,
    true object index per map object (-1: spurious), T_map_world)."""
    seen = np.flatnonzero(visible & (rng.random(len(positions)) >= config.miss))
    n_fake = int(rng.poisson(config.spurious * len(seen)))
    lo, hi = positions[seen].min(axis=0), positions[seen].max(axis=0)
    fake = rng.uniform(lo, hi, (n_fake, 3))
    pos = np.concatenate([positions[seen], fake])
    pos = pos + rng.normal(0.0, config.noise, pos.shape)
    lab = np.concatenate([labels[seen], rng.integers(0, len(FURNITURE_CLASSES), n_fake)])
    truth = np.concatenate([seen, np.full(n_fake, -1)])
    T = random_rigid_transform(rng, 2.0, 0.0)
    order = rng.permutation(len(pos))  # no hint of the truth in the vertex order
    moved = pos[order] @ T[:3, :3].T + T[:3, 3]
    return SemanticGraph(moved, lab[order], name=name), truth[order], T


def _pair(
    rng: np.random.Generator,
    positions: np.ndarray,
    labels: np.ndarray,
    sees: tuple[np.ndarray, np.ndarray],
    config: RoomConfig,
    names: tuple[str, str],
    info: dict,
) -> MapPair:
    """The maps of robots A (target) and B (query) that see the objects `sees` (bool masks)."""
    target, t_truth, T_a = observe(rng, positions, labels, sees[0], config, names[0])
    query, q_truth, T_b = observe(rng, positions, labels, sees[1], config, names[1])
    T = T_a @ np.linalg.inv(T_b)
    return MapPair(query, target, T, shared_count(q_truth, t_truth), q_truth, t_truth, info)


def room_pair(
    rng: np.random.Generator,
    config: RoomConfig = RoomConfig(),
    overlap: tuple[float, float] = (0.4, 0.9),
) -> MapPair:
    """Two robots' maps of one room, each of the part on its side of a line across the room:
    the two parts share a band of `overlap` (uniform in the range) of the room's length
    along that axis."""
    w, d = rng.uniform(*config.width), rng.uniform(*config.depth)
    n = int(rng.integers(config.objects[0], config.objects[1] + 1))
    pos, lab = make_room(rng, w, d, n)
    axis = int(rng.integers(0, 2))
    u = pos[:, axis] / (w, d)[axis]
    ov = rng.uniform(*overlap)
    hi = rng.uniform(ov, 1.0)
    sees = (u <= hi, u >= hi - ov)
    return _pair(rng, pos, lab, sees, config, ("room A", "room B"),
                 {"objects": len(pos), "overlap": round(ov, 3), "size": (w, d)})  # fmt: skip


def floor_pair(
    rng: np.random.Generator, config: RoomConfig = RoomConfig(), n_rooms: int = 8
) -> MapPair:
    """Two robots' maps of a floor of `n_rooms` different rooms: robot A maps the rooms (and
    the corridor) of the first columns along the corridor, robot B those of the last, and the
    two share one column (its two facing rooms) that is neither the first nor the last."""
    if n_rooms < 6:
        raise ValueError(f"floor_pair needs n_rooms >= 6 (3 columns), got {n_rooms}")
    floor = make_floor(rng, n_rooms, config)
    cols = (n_rooms + 1) // 2
    meet = int(rng.integers(1, cols - 1))
    col = np.where(floor.room >= 0, floor.room // 2, -1)
    width = floor.sizes[0, 0] + config.wall
    col = np.where(col >= 0, col, (floor.positions[:, 0] // width).astype(np.int64))
    sees = (col <= meet, col >= meet)
    return _pair(rng, floor.positions, floor.labels, sees, config, ("floor A", "floor B"),
                 {"objects": len(floor.positions), "shared_column": meet})  # fmt: skip


def repeated_room_pair(
    rng: np.random.Generator, config: RoomConfig = RoomConfig(), n_rooms: int = 6
) -> MapPair:
    """A negative: a floor of `n_rooms` identical offices mapped whole by robot A (target) and
    one of its offices mapped by robot B (query). The office's layout appears in every room,
    so which office B is in cannot be told: a localizer must refuse (info["ambiguous"])."""
    floor = make_floor(rng, n_rooms, config, repeated=n_rooms)
    r = int(rng.integers(0, n_rooms))
    sees = (np.ones(len(floor.positions), bool), floor.room == r)
    return _pair(rng, floor.positions, floor.labels, sees, config, ("floor", "office"),
                 {"objects": len(floor.positions), "room": r, "ambiguous": True})  # fmt: skip
