"""OnlineConfig: how an online session associates observations, schedules attempts and keeps
the fleet frame consistent."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from sgloc.errors import SglocError
from sgloc.graph import DEFAULT_EDGE_RADIUS


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
        refits per update (None: all; 0: in `run_pending` only).
    join_sigmas: None (off) or k: a robot not yet placed joins only once k standard deviations
        of its predicted error (its links' covariances composed along its path from the root,
        at the centroid of its objects, worst direction) are within loop_translation metres
        and loop_rotation degrees; until then it is held back (placed robots stay placed).
    solver: "auto" (gtsam when installed, else scipy), "gtsam" or "scipy".
    seed: attempt k of the pair (i, j) (robot indices, i < j) uses the seed [seed, i, j]
        (k = 0) or [seed, i, j, k].
    """

    association_radius: float = 1.5
    min_observations: int = 2
    edge_radius: float = DEFAULT_EDGE_RADIUS
    min_objects: int = 6
    growth_ratio: float = 0.10
    growth_objects: int = 10
    max_attempts: int | None = 2
    loop_translation: float = 3.0
    loop_rotation: float = 3.0
    confirmations: int = 1
    refine_links: bool = True
    join_sigmas: float | None = None
    solver: str = "auto"
    seed: int = 0

    def __post_init__(self) -> None:
        if (self.association_radius < 0 or self.min_observations < 1 or self.min_objects < 3
                or self.confirmations < 1):
            raise SglocError(
                "OnlineConfig: association_radius must be >= 0 m, min_observations and "
                "confirmations >= 1, min_objects >= 3 (localization needs at least 3 objects)."
            )
        if self.join_sigmas is not None and not self.join_sigmas > 0:
            raise SglocError("OnlineConfig: join_sigmas must be > 0 or None (no hold).")
        if self.max_attempts is not None and self.max_attempts < 0:
            raise SglocError("OnlineConfig: max_attempts must be >= 0 or None (no limit).")
        if self.solver not in ("auto", "gtsam", "scipy"):
            raise SglocError(
                f"OnlineConfig: solver {self.solver!r} is unknown; use 'auto', 'gtsam' or 'scipy'."
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> OnlineConfig:
        return cls(**data)
