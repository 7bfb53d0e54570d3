"""A procedural city: a street grid lined with buildings and street furniture, built from two
primitives the renderer ray-casts (yawed boxes and vertical cylinders).

World frame: x east, y north, z up, metres; the ground is the plane z = 0. Streets run along x
at y = j * pitch and along y at x = i * pitch (i, j = 0..blocks). Objects of one class repeat
with the same few shapes all over the city, so local descriptors are ambiguous, as in real
cities.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.validation import (
    MAX_COORDINATE,
    integer,
    real,
    setting,
    span,
    validate_settings,
)

#: Class names of the synthetic city; class k is drawn with sgloc.maps.classes.AIRSIM_COLORS[k].
CITY_CLASSES: tuple[str, ...] = (
    "building",
    "tree",
    "pole",
    "car",
    "sign",
    "fence",
    "bush",
    "bench",
    "traffic_light",
    "bin",
    "bus_stop",
)
CLASS_ID = {name: k for k, name in enumerate(CITY_CLASSES)}

BOX, CYLINDER = 0, 1


#: The check of a (low, high) range of lengths in metres.
LENGTHS = span(0.0, MAX_COORDINATE, unit="m")


@dataclass
class CityConfig:
    """Layout of the procedural city (all lengths in metres).

    blocks: number of blocks along x and along y (the street grid has blocks + 1 streets each
        way; routes use the inner streets, so the outer ring of blocks frames every view).
    pitch: distance between parallel street centre lines.
    road_half_width: centre line to curb; lanes are 3.5 m wide either side of the centre.
    sidewalk: curb to property line (street furniture stands here).
    park_probability: chance a block is a park (trees, bushes, a fence) instead of buildings.
    building_*: frontage width, gap between neighbours and height ranges of buildings.
    *_probability / *_spacing: densities of the street furniture, per side of a street segment.
    """

    blocks: int = setting(7, check=integer(1, 1000))
    pitch: float = setting(80.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    road_half_width: float = setting(6.0, check=real(0.0, MAX_COORDINATE, unit="m"))
    sidewalk: float = setting(4.5, check=real(0.0, MAX_COORDINATE, unit="m"))
    park_probability: float = setting(0.15, check=real(0.0, 1.0))
    tree_row_probability: float = setting(0.7, check=real(0.0, 1.0))
    tree_spacing: tuple[float, float] = setting((9.0, 14.0), check=LENGTHS)
    pole_spacing: float = setting(20.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    car_slot: float = setting(6.5, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    car_occupancy: float = setting(0.3, check=real(0.0, 1.0))
    signs_per_side: tuple[int, int] = setting((0, 2), check=span(0, 1000, whole=True))
    fence_probability: float = setting(0.3, check=real(0.0, 1.0))
    bush_probability: float = setting(0.5, check=real(0.0, 1.0))
    bench_probability: float = setting(0.4, check=real(0.0, 1.0))
    bin_probability: float = setting(0.5, check=real(0.0, 1.0))
    bus_stop_probability: float = setting(0.15, check=real(0.0, 1.0))
    traffic_light_probability: float = setting(0.5, check=real(0.0, 1.0))
    building_height: tuple[float, float] = setting((8.0, 35.0), check=LENGTHS)
    building_width: tuple[float, float] = setting((10.0, 20.0), check=LENGTHS)
    building_gap: tuple[float, float] = setting((3.0, 8.0), check=LENGTHS)
    tree_crown_radius: tuple[float, float] = setting((1.0, 1.4), check=LENGTHS)

    def __post_init__(self) -> None:
        validate_settings(self, "CityConfig")

    @property
    def street_half_width(self) -> float:
        """Centre line to property line."""
        return self.road_half_width + self.sidewalk

    @property
    def size(self) -> float:
        """Extent of the city along x and y (metres)."""
        return self.blocks * self.pitch


@dataclass
class Primitives:
    """The city's geometry as flat arrays, one row per primitive.

    kind: (n,) BOX or CYLINDER.
    center: (n,3) box centre, or cylinder axis point at mid height (metres, world frame).
    half: (n,3) box half extents along its own (yawed) x, y and z; for a cylinder (r, r, h/2).
    yaw: (n,) box rotation about z (radians; 0 for cylinders).
    label: (n,) class id (CITY_CLASSES).
    instance: (n,) object id; the parts of one object (a tree's trunk and crown) share it.
    """

    kind: np.ndarray
    center: np.ndarray
    half: np.ndarray
    yaw: np.ndarray
    label: np.ndarray
    instance: np.ndarray

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    def corners(self) -> np.ndarray:
        """(n,8,3) corners of each primitive's bounding box (the box itself for boxes)."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        local = signs[None] * self.half[:, None, :]
        c, s = np.cos(self.yaw)[:, None], np.sin(self.yaw)[:, None]
        x = c * local[..., 0] - s * local[..., 1]
        y = s * local[..., 0] + c * local[..., 1]
        return np.stack([x, y, local[..., 2]], axis=-1) + self.center[:, None, :]

    def bounding_radius(self) -> np.ndarray:
        """(n,) radius of a sphere around `center` holding the whole primitive."""
        return np.linalg.norm(self.half, axis=1)


@dataclass
class City:
    """A generated city: its geometry, its objects (one row per object) and its street grid."""

    config: CityConfig
    primitives: Primitives
    object_positions: np.ndarray  # (k,3) centre of each object's bounding box, metres
    object_labels: np.ndarray  # (k,) class ids
    seed: int | None = None

    @property
    def n_objects(self) -> int:
        return int(self.object_labels.shape[0])

    def node_position(self, i: int, j: int) -> np.ndarray:
        """World (x, y) of the street intersection (i, j)."""
        return np.array([i * self.config.pitch, j * self.config.pitch])


class _Builder:
    """Collects primitives object by object."""

    def __init__(self) -> None:
        self.rows: list[tuple] = []
        self.n_objects = 0

    def new_object(self) -> int:
        self.n_objects += 1
        return self.n_objects - 1

    def box(self, obj: int, label: int, center, half, yaw: float = 0.0) -> None:
        self.rows.append((BOX, *center, *half, yaw, label, obj))

    def cylinder(
        self, obj: int, label: int, x: float, y: float, r: float, z0: float, z1: float
    ) -> None:
        self.rows.append((CYLINDER, x, y, (z0 + z1) / 2, r, r, (z1 - z0) / 2, 0.0, label, obj))

    def build(self) -> Primitives:
        a = np.array(self.rows, dtype=np.float64).reshape(-1, 10)
        return Primitives(
            kind=a[:, 0].astype(np.int8),
            center=a[:, 1:4].copy(),
            half=a[:, 4:7].copy(),
            yaw=a[:, 7].copy(),
            label=a[:, 8].astype(np.int64),
            instance=a[:, 9].astype(np.int64),
        )


def _frame(origin: np.ndarray, along: np.ndarray):
    """Map street-local (a, l) (a along the street, l to the left) to world (x, y)."""
    left = np.array([-along[1], along[0]])

    def to_world(a: float, lateral: float) -> tuple[float, float]:
        p = origin + a * along + lateral * left
        return float(p[0]), float(p[1])

    return to_world, float(np.arctan2(along[1], along[0]))


def _street_side(b: _Builder, rng: np.random.Generator, cfg: CityConfig, to_world, yaw, side):
    """Furniture on one side (side = +1 left, -1 right) of one street segment, whose usable
    length runs over a in [0, L] (L = pitch - 2 * street_half_width)."""
    L = cfg.pitch - 2 * cfg.street_half_width

    def at(a, lat):
        return to_world(a, side * lat)

    _curb_furniture(b, rng, cfg, at, yaw, L)
    _property_furniture(b, rng, cfg, at, yaw, L)


def _curb_furniture(
    b: _Builder, rng: np.random.Generator, cfg: CityConfig, at, yaw: float, L: float
) -> None:
    """Along the curb: parked cars, street lamps, a row of trees, signs and a bin. `at(a, lat)`
    maps street-side coordinates (metres along, metres out from the axis) to world (x, y)."""
    curb = cfg.road_half_width
    # Parked cars along the curb.
    for a in np.arange(cfg.car_slot / 2, L - cfg.car_slot / 2, cfg.car_slot):
        if rng.random() < cfg.car_occupancy:
            o = b.new_object()
            length, width = rng.uniform(4.2, 4.9), rng.uniform(1.75, 1.95)
            x, y = at(a + rng.uniform(-0.5, 0.5), curb - 1.2)
            cy = yaw + rng.normal(0, 0.03)
            b.box(o, CLASS_ID["car"], (x, y, 0.7), (length / 2, width / 2, 0.45), cy)
            b.box(o, CLASS_ID["car"], (x, y, 1.3), (length / 3.2, width / 2.2, 0.25), cy)
    # Street lamps (poles), regularly spaced.
    off = rng.uniform(2, cfg.pole_spacing / 2)
    for a in np.arange(off, L, cfg.pole_spacing):
        o = b.new_object()
        x, y = at(a, curb + 0.5)
        b.cylinder(o, CLASS_ID["pole"], x, y, 0.16, 0.0, rng.uniform(6.5, 8.0))
    # A row of street trees.
    if rng.random() < cfg.tree_row_probability:
        spacing = rng.uniform(*cfg.tree_spacing)
        for a in np.arange(rng.uniform(2, spacing), L - 2, spacing):
            _tree(b, rng, cfg, *at(a + rng.uniform(-0.6, 0.6), curb + 1.6))
    # Traffic signs facing the traffic.
    for _ in range(rng.integers(cfg.signs_per_side[0], cfg.signs_per_side[1] + 1)):
        o = b.new_object()
        x, y = at(rng.uniform(3, L - 3), curb + 0.4)
        b.cylinder(o, CLASS_ID["sign"], x, y, 0.06, 0.0, 2.3)
        b.box(o, CLASS_ID["sign"], (x, y, 2.75), (0.05, 0.45, 0.45), yaw)
    # Bins.
    if rng.random() < cfg.bin_probability:
        o = b.new_object()
        x, y = at(rng.uniform(3, L - 3), curb + 0.8)
        b.cylinder(o, CLASS_ID["bin"], x, y, 0.35, 0.0, 1.1)


def _property_furniture(
    b: _Builder, rng: np.random.Generator, cfg: CityConfig, at, yaw: float, L: float
) -> None:
    """Along the property side of the sidewalk: a bench, a bus stop, bushes and a fence
    (`at` as in `_curb_furniture`)."""
    prop = cfg.street_half_width
    # Benches along the property side of the sidewalk.
    if rng.random() < cfg.bench_probability:
        o = b.new_object()
        a = rng.uniform(4, L - 4)
        b.box(o, CLASS_ID["bench"], (*at(a, prop - 1.2), 0.25), (1.0, 0.35, 0.25), yaw)
        b.box(o, CLASS_ID["bench"], (*at(a, prop - 0.85), 0.75), (1.0, 0.06, 0.3), yaw)
    # A bus stop shelter.
    if rng.random() < cfg.bus_stop_probability:
        o = b.new_object()
        x, y = at(rng.uniform(6, L - 6), prop - 1.3)
        b.box(o, CLASS_ID["bus_stop"], (x, y, 1.35), (2.2, 0.8, 1.35), yaw)
    # Hedges / bushes in front of the lots.
    if rng.random() < cfg.bush_probability:
        for a in np.arange(rng.uniform(2, 8), L - 3, rng.uniform(7, 14)):
            o = b.new_object()
            x, y = at(a, prop - 0.6)
            if rng.random() < 0.5:
                b.cylinder(o, CLASS_ID["bush"], x, y, rng.uniform(0.7, 1.1), 0.0, 1.4)
            else:
                half = (rng.uniform(1.0, 2.0), 0.6, rng.uniform(0.55, 0.8))
                b.box(o, CLASS_ID["bush"], (x, y, half[2]), half, yaw)
    # A fence along the property line.
    if rng.random() < cfg.fence_probability:
        length = rng.uniform(12, L - 4)
        a0 = rng.uniform(2, L - length - 2) if L - length > 4 else 2.0
        o = b.new_object()
        x, y = at(a0 + length / 2, prop + 0.1)
        b.box(o, CLASS_ID["fence"], (x, y, 0.8), (length / 2, 0.05, 0.8), yaw)


def _tree(b: _Builder, rng: np.random.Generator, cfg: CityConfig, x: float, y: float) -> None:
    o = b.new_object()
    crown_z0 = rng.uniform(2.2, 3.0)
    b.cylinder(o, CLASS_ID["tree"], x, y, 0.22, 0.0, crown_z0 + 0.5)
    b.cylinder(
        o, CLASS_ID["tree"], x, y, rng.uniform(*cfg.tree_crown_radius), crown_z0, crown_z0 + 3.5
    )


def _block(b: _Builder, rng: np.random.Generator, cfg: CityConfig, x0, y0, x1, y1) -> None:
    """Fill the block [x0,x1] x [y0,y1] (inside its property lines)."""
    if rng.random() < cfg.park_probability:
        for x in np.arange(x0 + 6, x1 - 4, rng.uniform(10, 16)):
            for y in np.arange(y0 + 6, y1 - 4, rng.uniform(10, 16)):
                if rng.random() < 0.6:
                    _tree(b, rng, cfg, x + rng.uniform(-2, 2), y + rng.uniform(-2, 2))
                elif rng.random() < 0.5:
                    o = b.new_object()
                    b.cylinder(o, CLASS_ID["bush"], x, y, rng.uniform(0.8, 1.3), 0.0, 1.5)
        return
    # Perimeter buildings: the two x-facing sides span the block, the others fill in between.
    deepest = 18.0
    sides = [
        (np.array([x0, y0]), np.array([1.0, 0.0]), x1 - x0, 0.0),  # south edge, facing -y
        (np.array([x1, y1]), np.array([-1.0, 0.0]), x1 - x0, 0.0),  # north edge
        (np.array([x1, y0 + deepest]), np.array([0.0, 1.0]), y1 - y0 - 2 * deepest, 0.0),
        (np.array([x0, y1 - deepest]), np.array([0.0, -1.0]), y1 - y0 - 2 * deepest, 0.0),
    ]
    for origin, along, length, _ in sides:
        to_world, yaw = _frame(origin, along)
        a = rng.uniform(0, 4)
        while a < length - 6:
            width = min(rng.uniform(*cfg.building_width), length - a)
            depth = rng.uniform(10, deepest)
            setback = rng.uniform(0.0, 3.0)
            height = rng.uniform(*cfg.building_height)
            if rng.random() < 0.9:
                o = b.new_object()
                # the block interior lies to the left of `along` (counter-clockwise sides)
                x, y = to_world(a + width / 2, setback + depth / 2)
                b.box(
                    o,
                    CLASS_ID["building"],
                    (x, y, height / 2),
                    (width / 2, depth / 2, height / 2),
                    yaw,
                )
            a += width + rng.uniform(*cfg.building_gap)


def make_city(seed: int | np.random.Generator = 0, config: CityConfig | None = None) -> City:
    """Generate a city: `config.blocks` x `config.blocks` blocks of buildings or parks, and
    furniture along every street (cars, poles, trees, signs, bins, benches, bus stops, bushes,
    fences) plus traffic lights at the corners of intersections."""
    cfg = config or CityConfig()
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    b = _Builder()
    p, h = cfg.pitch, cfg.street_half_width
    for i in range(cfg.blocks):
        for j in range(cfg.blocks):
            _block(b, rng, cfg, i * p + h, j * p + h, (i + 1) * p - h, (j + 1) * p - h)
    # Street segments: along x between nodes (i, j) and (i+1, j); along y likewise.
    for j in range(cfg.blocks + 1):
        for i in range(cfg.blocks):
            origin, along = np.array([i * p + h, j * p]), np.array([1.0, 0.0])
            to_world, yaw = _frame(origin, along)
            for side in (1, -1):
                if (side == 1 and j == cfg.blocks) or (side == -1 and j == 0):
                    continue  # nothing outside the city
                _street_side(b, rng, cfg, to_world, yaw, side)
    for i in range(cfg.blocks + 1):
        for j in range(cfg.blocks):
            origin, along = np.array([i * p, j * p + h]), np.array([0.0, 1.0])
            to_world, yaw = _frame(origin, along)
            for side in (1, -1):
                if (side == 1 and i == 0) or (side == -1 and i == cfg.blocks):
                    continue
                _street_side(b, rng, cfg, to_world, yaw, side)
    # Traffic lights on the corners of the inner intersections.
    for i in range(1, cfg.blocks):
        for j in range(1, cfg.blocks):
            for sx in (-1, 1):
                for sy in (-1, 1):
                    if rng.random() < cfg.traffic_light_probability:
                        o = b.new_object()
                        x = i * p + sx * (cfg.road_half_width + 0.6)
                        y = j * p + sy * (cfg.road_half_width + 0.6)
                        b.cylinder(o, CLASS_ID["traffic_light"], x, y, 0.12, 0.0, 4.2)
                        b.box(o, CLASS_ID["traffic_light"], (x, y, 4.7), (0.25, 0.25, 0.6))
    prims = b.build()
    pos, lab = _object_table(prims, b.n_objects)
    return City(cfg, prims, pos, lab, seed=seed if isinstance(seed, int) else None)


def _object_table(prims: Primitives, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Centre of each object's axis-aligned bounding box and its class."""
    corners = prims.corners().reshape(-1, 3)
    inst = np.repeat(prims.instance, 8)
    lo = np.full((n, 3), np.inf)
    hi = np.full((n, 3), -np.inf)
    np.minimum.at(lo, inst, corners)
    np.maximum.at(hi, inst, corners)
    labels = np.zeros(n, np.int64)
    labels[prims.instance] = prims.label
    return (lo + hi) / 2, labels
