"""OnlineConfig: how an online session associates observations, schedules attempts and keeps
the fleet frame consistent."""

from __future__ import annotations

import difflib
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from sgloc.errors import UnknownNameError
from sgloc.maps.graph import DEFAULT_EDGE_RADIUS
from sgloc.online.backend import BACKENDS
from sgloc.validation import (
    MAX_COORDINATE,
    MAX_ITERATIONS,
    MAX_VERTICES,
    check_choice,
    choice,
    flag,
    group,
    integer,
    real,
    setting,
    validate_settings,
)

#: The prefix naming an OdometryNoise field among flat online settings.
ODOMETRY_PREFIX = "odometry."


@dataclass(frozen=True)
class OdometryNoise:
    """How uncertain a robot's odometry is over a stretch of d metres, (6,6) covariance of the
    relative pose in gtsam Pose3's tangent order [rx ry rz tx ty tz] (rad, m), right
    perturbation (in the stretch's last keyframe's frame), diagonal (`sigmas`):

        sigma_t(d)^2 = translation_floor^2 + (translation_per_metre * d)^2        (each axis)
        sigma_r(d)^2 = rotation_floor^2 + (rotation_per_metre * d)^2
                       + rotation_per_sqrt_metre^2 * d                            (each axis)

    The per-metre terms are systematic (a scale error, a heading bias): they grow with the
    stretch, not with its square root. A pose graph joins consecutive keyframes by independent
    steps, which add up in quadrature; so one step T_k_k+1 of d metres (`covariance`) gets the
    per-metre variances (per_metre)^2 * d * max(d, correlation_length): the steps over
    `correlation_length` metres then add up to the per-metre error of that stretch, however
    densely the keyframes come (with (per_metre * d)^2 per step, n steps would add up to 1 /
    sqrt(n) of it, and the graph would hold denser odometry ever more rigid against its own
    drift).

    translation_per_metre: metres of error per metre travelled (0.01 = 1 %, scale error and
        the lateral error a heading error makes); rotation_per_metre: degrees per metre (a
        heading bias); rotation_per_sqrt_metre: degrees per sqrt(metre) (a heading random
        walk); translation_floor (m), rotation_floor (degrees): the least uncertainty of any
        step, also that of a robot standing still; correlation_length (m): the stretch over
        which the per-metre errors are taken as systematic (0: each step on its own; default
        the default `OnlineConfig.submap_length`, the stretch over which attempts link a
        robot). The rotation sigma applies to roll and pitch as well as heading. Defaults: a
        good LiDAR odometry (0.5 % scale error, a heading error of 0.002 deg per metre and
        0.002 deg per sqrt(metre)) with about twice that as margin.
    """

    translation_per_metre: float = setting(0.01, check=real(0.0, 1.0))
    rotation_per_metre: float = setting(0.005, check=real(0.0, 180.0, unit="degrees/m"))
    rotation_per_sqrt_metre: float = setting(
        0.005, check=real(0.0, 180.0, unit="degrees/sqrt(m)")
    )
    translation_floor: float = setting(
        0.005, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m")
    )
    rotation_floor: float = setting(0.005, check=real(0.0, 180.0, low_open=True, unit="degrees"))
    correlation_length: float = setting(100.0, check=real(0.0, MAX_COORDINATE, unit="m"))

    def __post_init__(self) -> None:
        validate_settings(self, "OdometryNoise")

    def sigmas(self, distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sigma_t in metres, sigma_r in radians), each shaped like `distance` (metres)."""
        d = np.abs(np.asarray(distance, np.float64))
        st = np.sqrt(self.translation_floor**2 + (self.translation_per_metre * d) ** 2)
        sr = np.sqrt(np.radians(self.rotation_floor) ** 2
                     + (np.radians(self.rotation_per_metre) * d) ** 2
                     + np.radians(self.rotation_per_sqrt_metre) ** 2 * d)
        return st, sr

    def scaled(self, scale: float) -> OdometryNoise:
        """The model with its drift variances (the per-metre and per-sqrt-metre terms) times
        `scale` > 0; the floors kept."""
        r = float(np.sqrt(scale))
        return replace(self, translation_per_metre=min(self.translation_per_metre * r, 1.0),
                       rotation_per_metre=self.rotation_per_metre * r,
                       rotation_per_sqrt_metre=self.rotation_per_sqrt_metre * r)

    def covariance(self, T_steps: np.ndarray) -> np.ndarray:
        """(..., 6, 6) covariances of the odometry steps T_steps (..., 4, 4) (T_k_k+1) as
        independent factors of a pose graph, their length d = the norm of each step's
        translation: the per-metre variances scaled to d * max(d, correlation_length) (see
        the class doc)."""
        d = np.linalg.norm(np.asarray(T_steps, np.float64)[..., :3, 3], axis=-1)
        dd = d * np.maximum(d, self.correlation_length)
        vt = self.translation_floor**2 + self.translation_per_metre**2 * dd
        vr = (np.radians(self.rotation_floor) ** 2 + np.radians(self.rotation_per_metre) ** 2 * dd
              + np.radians(self.rotation_per_sqrt_metre) ** 2 * d)
        var = np.stack([vr, vr, vr, vt, vt, vt], axis=-1)
        return var[..., :, None] * np.eye(6)


@dataclass(frozen=True)
class OnlineConfig:
    """Settings of `OnlineSession`.

    association_radius: metres; a new sighting joins the nearest confirmed-or-pending object of
        the same class within this radius (its position becomes the running mean).
    min_observations: sightings an object needs before it enters the robot's map (1 = at once).
    edge_radius: metres, the edge radius of the robots' SemanticGraphs.
    min_objects: a robot takes part in localization attempts from this many confirmed objects.
    growth_ratio, growth_objects: a pair is retried when one of its maps has grown by this
        fraction, or by this many confirmed objects, since the pair's last attempt.
    max_attempts: localization attempts at most per `add_keyframe` (None: no limit; 0: none,
        then `OnlineSession.run_pending` runs them).
    loop_translation, loop_rotation: metres (at the centroid of the robot's objects) / degrees
        by which one link may be off; a loop of k links may fail to compose to the identity by
        sqrt(k) times that and still count as consistent.
    confirmations: accepted attempts of a pair, in a row and agreeing with each other (as a
        loop of 2 links), before its link is used (1: at once).
    refine_links: refit each link on every object pair it co-locates in the two current maps
        (mutual nearest same-class neighbours within the localizer's RANSAC threshold) when it
        is accepted and whenever one of its maps has grown by growth_ratio / growth_objects
        since; the refit replaces the link when it rests on more pairs than the link's matches
        and agrees with it within the loop tolerance (a loop of 2). At most max_attempts
        refits per update (None: all; 0: in `run_pending` only). Backend "keyframes": an
        accepted attempt is refitted once, on the query submap and the target map.
    refine_fleet: after the pose graph, refine the placed robots' frames together on every
        object pair their maps co-locate in the fleet frame (mutual nearest same-class
        neighbours within refine_radius), linked robots or not: where a
        robot also passed objects of a robot it has no link to, those pairs fix its rotation
        far better than a link fitted at one meeting point (`sgloc.online.joint`). Robust
        (Huber) and in the localizer's dof (4: yaw and translation); skipped when it would move
        a robot by more than loop_translation / loop_rotation. With backend "keyframes" the
        same pairs, cut into windows of a quarter submap of travel, become co-location factors
        between the keyframes that saw them (`sgloc.online.keyframes.colocation`): the graph is
        held all along where two robots met, not only where an attempt aligned them.
    refine_fleet_growth: the joint refinement (or the co-location factors) reruns when the
        placed robots' confirmed objects have grown by this fraction since its last run, or a
        robot of that run is no longer placed; in between, each robot keeps the correction the
        last run made to its frame (0: after every change of the fleet frame). Bounds its cost
        as the fleet grows.
    refine_radius: metres, the pairing radius of refine_fleet (None: the localizer's RANSAC
        threshold).
    join_sigmas: None (off) or k, backend "robots": a robot not yet placed joins only once k
        standard deviations of its predicted error (its links' covariances composed along its
        path from the root, at the centroid of its objects, worst direction) are within
        loop_translation metres and loop_rotation degrees; until then it is held back (placed
        robots stay placed).
    solver: "auto" (gtsam when installed, else scipy), "gtsam" or "scipy".
    backend: "keyframes" (the default: a pose graph over every robot's keyframes, odometry
        factors between consecutive keyframes, links between keyframes; drift is corrected,
        see docs/online_session.md) or "robots" (one rigid frame per robot: the pose graph's
        nodes are the robots' odometry frames; for odometry that does not drift, and what
        `localize_fleet` uses on finished maps).
    odometry: the odometry's noise model (OdometryNoise), for backend "keyframes".
    submap_length: metres; backend "keyframes": an attempt matches the objects the query
        robot saw over its last submap_length metres of travel (its local submap).
    join_submaps: backend "keyframes": between two robots not yet joined, every other attempt
        of the pair (the second, fourth, ...) matches the objects the query robot saw last,
        within its local submap and fewer than the localizer's `small_query` (so that the
        whole geometry is verified against the other map), instead of its whole map. A
        sparse map (a one-class detector's few objects per keyframe) fits another map only
        where the two overlap, and its whole map is mostly elsewhere: its candidates there
        are too few for a fit, while the overlapping stretch alone fits. A map whose
        keyframes over the submap each saw more objects than that (the median keyframe) is
        matched whole. False: joins always match the whole map.
    loop_closures: backend "keyframes": also match each robot's local submap against its own
        older map (objects last seen before the submap's stretch), intra-robot loop closures.
    view_correction: backend "keyframes": the link refits and co-location factors use the
        objects corrected for the viewpoint offset measured on the maps (a sighting is the
        near side of an object, closer to the sensor than its centre;
        `sgloc.online.keyframes.views`), so that two robots that saw the same objects from
        opposite sides are not pulled apart along the way they looked.
    join_tests: backend "keyframes": a link that would join two groups of robots by itself
        must keep its acceptance evidence when counted against every attempt made between the
        two groups (its NFA, 1 / confidence - 1, times those attempts, within the NFA the
        localizer accepts at, 1 / min_confidence - 1); a weaker link waits until other links
        join the groups and is then taken as a loop closure (`keyframes.links`). Many robots
        make thousands of attempts between groups that do not overlap, and the rare chance
        alignment among them would otherwise place a whole group.
    link_checks: backend "keyframes": every link is checked against the robots' odometry
        under `odometry` before it enters the pose graph (pairwise consistency of each robot
        pair's links, loop closures against their robot's own odometry) and after each solve
        (a link whose solution bends a robot's odometry beyond its noise leaves);
        `sgloc.online.keyframes.consistency`. A link that fails is held (event "link_held")
        or revoked.
    link_agreement: backend "keyframes": a link whose maps disagree where it puts them side
        by side is held (event "link_held"): of the query objects around the link (each
        robot's objects seen within submap_length metres of travel of its end) that the link
        puts next to a target object, fewer than this fraction land on an object of their
        class (at least the localizer's `min_covered` of them; the localizer's radii). A link
        at another copy of a repeating layout (a street grid a block away) lands only what the
        layout repeats (`sgloc.online.keyframes.agreement`). None (the default): the
        localizer's `min_agreement`; 0: off.
    odometry_scale: backend "keyframes": the pose graph's odometry factors take the drift the
        links show: the variances of `odometry` times a scale in [0.01, 1] fitted to the
        heading errors of the loops the links close (`sgloc.online.keyframes.noise`), so that
        exact odometry is held nearly rigid and drifting odometry bends as much as it drifts;
        the consistency checks keep `odometry` as given. False: `odometry` as given.
    seed: attempt k of the pair (i, j) (robot indices, i < j) uses the seed [seed, i, j]
        (k = 0) or [seed, i, j, k].
    fuse_radius: metres; in the merged fleet map (`sgloc replay`'s merged.json), same-class
        objects of different robots closer than this are fused (as `FleetConfig.fuse_radius`).
    """

    association_radius: float = setting(1.5, check=real(0.0, MAX_COORDINATE, unit="m"))
    min_observations: int = setting(2, check=integer(1, MAX_ITERATIONS))
    edge_radius: float = setting(
        DEFAULT_EDGE_RADIUS, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m")
    )
    # A localization needs at least 3 objects.
    min_objects: int = setting(6, check=integer(3, MAX_VERTICES))
    growth_ratio: float = setting(0.10, check=real(0.0))
    growth_objects: int = setting(10, check=integer(0, MAX_VERTICES))
    max_attempts: int | None = setting(2, check=integer(0, MAX_ITERATIONS, none_ok=True))
    loop_translation: float = setting(3.0, check=real(0.0, MAX_COORDINATE, unit="m"))
    loop_rotation: float = setting(3.0, check=real(0.0, 180.0, unit="degrees"))
    confirmations: int = setting(1, check=integer(1, MAX_ITERATIONS))
    refine_links: bool = setting(True, check=flag())
    refine_fleet: bool = setting(True, check=flag())
    refine_fleet_growth: float = setting(0.10, check=real(0.0))
    refine_radius: float | None = setting(
        None, check=real(0.0, MAX_COORDINATE, low_open=True, none_ok=True, unit="m")
    )
    join_sigmas: float | None = setting(None, check=real(0.0, low_open=True, none_ok=True))
    solver: str = setting("auto", check=choice("auto", "gtsam", "scipy", what="the solver"))
    seed: int = setting(0, check=integer(0))
    backend: str = setting("keyframes", check=lambda name, value: check_choice(
        name, value, BACKENDS, "the back-end"))
    odometry: OdometryNoise = setting(default_factory=OdometryNoise, check=group(OdometryNoise))
    submap_length: float = setting(
        100.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m")
    )
    join_submaps: bool = setting(True, check=flag())
    loop_closures: bool = setting(True, check=flag())
    view_correction: bool = setting(True, check=flag())
    join_tests: bool = setting(True, check=flag())
    link_checks: bool = setting(True, check=flag())
    link_agreement: float | None = setting(None, check=real(0.0, 1.0, none_ok=True))
    odometry_scale: bool = setting(True, check=flag())
    fuse_radius: float = setting(2.0, check=real(0.0, MAX_COORDINATE, unit="m"))

    def __post_init__(self) -> None:
        validate_settings(self, "OnlineConfig")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def with_overrides(self, **settings: Any) -> OnlineConfig:
        """A copy with flat `settings` applied: OnlineConfig's field names, and
        `odometry.NAME` for the odometry noise model's (OdometryNoise) fields. Each value is
        checked; an unknown name raises UnknownNameError naming the nearest one."""
        own = [f.name for f in fields(self) if f.name != "odometry"]
        odometry = [f"{ODOMETRY_PREFIX}{f.name}" for f in fields(OdometryNoise)]
        top = {k: v for k, v in settings.items() if k in own}
        odo = {k[len(ODOMETRY_PREFIX):]: v for k, v in settings.items() if k in odometry}
        unknown = [k for k in settings if k not in own and k not in odometry]
        if unknown:
            close = difflib.get_close_matches(unknown[0], own + odometry, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise UnknownNameError(
                f"unknown online setting {unknown[0]!r}; {hint}the online settings are "
                f"OnlineConfig's fields ({', '.join(own)}) and the odometry noise model's as "
                f"{ODOMETRY_PREFIX}NAME ({', '.join(f.name for f in fields(OdometryNoise))}).")
        noise = replace(self.odometry, **odo) if odo else self.odometry
        return replace(self, **top, odometry=noise)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> OnlineConfig:
        """The settings `to_dict` gave. Settings saved before `backend`, `view_correction`,
        `join_tests`, `link_checks`, `link_agreement`, `odometry_scale`, `join_submaps` and
        `OdometryNoise.correlation_length` existed keep the behaviour they were saved with
        (robots, off, off, off, off, off, off, 0), so that a resumed session continues as
        it would."""
        data = dict(data)
        data.setdefault("backend", "robots")
        if isinstance(data.get("odometry"), dict):
            data["odometry"] = OdometryNoise(**{"correlation_length": 0.0, **data["odometry"]})
        data.setdefault("view_correction", False)
        data.setdefault("join_tests", False)
        data.setdefault("link_checks", False)
        data.setdefault("link_agreement", 0.0)
        data.setdefault("odometry_scale", False)
        data.setdefault("join_submaps", False)
        return cls(**data)
