"""The records an online session exposes: links between robots, events, attempts."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: Event kinds.
ROBOT_JOINED, LINK_ACCEPTED, LINK_REVOKED = "robot_joined", "link_accepted", "link_revoked"
#: A link the checks against the odometry keep out of the pose graph before it ever entered
#: (keyframe back-end; `keyframes.consistency`).
LINK_HELD = "link_held"


@dataclass
class Link:
    """An accepted localization between two robots: an edge of the fleet's pose graph.

    A separate record from the `Attempt` that produced it: an attempt is a finished, immutable
    fact (one try, kept in `OnlineSession.attempts` whatever its outcome), while a link lives on
    in the fleet's state (active or not, agreed by later attempts, refitted on the grown maps,
    revoked) and holds what the pose graph needs (T_a_b in robot or keyframe frames, its
    covariance); a link may outlive or replace several attempts of its pair.

    T_a_b: (4,4) maps robot_b's odometry frame into robot_a's (p_a = R @ p_b + t).
    covariance: (6,6) of T_a_b, GTSAM Pose3 tangent order [rx ry rz tx ty tz] (rad, m), right
        perturbation (T_true = T_a_b @ Exp(xi), in b's frame).
    confidence: the acceptance test's, in [0, 1]. stamp: when the link was (last) accepted.
    active: True while the link is part of the consistent set the fleet frame is built from;
        reason: why not (or how the covariance was obtained).
    n_matches: the localization's inliers; agreed: how many accepted attempts of this pair in
        a row agree with each other (`OnlineConfig.confirmations`); refined_pairs: the object
        pairs of the link's last refit on the grown maps (0: as the localization gave it).
    keyframe_a, keyframe_b: None for a link between two robots' odometry frames (back-end
        "robots"); with back-end "keyframes", the indices of the two keyframes it relates, and
        then T_a_b is the pose of keyframe_b of robot_b in keyframe_a of robot_a's sensor frame
        and covariance is in keyframe_b's frame; robot_a == robot_b for a loop closure.
    revoked: the link was in the consistent set and left it; it does not come back (a newer
        attempt of the pair, new evidence, makes a new link).
    tests: the localization attempts made between the two robots' groups (robots joined by
        active links) up to and including the one that gave the link: how many chances a
        false alignment had (back-end "keyframes", `keyframes.links.select_links`; 1 for a
        link added from elsewhere or saved before this was counted).
    landed, covered: back-end "keyframes", the link's overlap as measured when it was made
        (`keyframes.agreement.overlap`): of the query objects around the link that it puts next
        to a target object (covered), those that land on one of their class (0, 0: not
        measured).
    """

    robot_a: str
    robot_b: str
    T_a_b: np.ndarray
    covariance: np.ndarray
    confidence: float
    stamp: float
    active: bool = True
    reason: str = ""
    n_matches: int = 0
    agreed: int = 1
    refined_pairs: int = 0
    keyframe_a: int | None = None
    keyframe_b: int | None = None
    revoked: bool = False
    tests: int = 1
    landed: int = 0
    covered: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "robot_a": self.robot_a, "robot_b": self.robot_b, "T_a_b": self.T_a_b.tolist(),
            "covariance": self.covariance.tolist(), "confidence": self.confidence,
            "stamp": self.stamp, "active": self.active, "reason": self.reason,
            "n_matches": self.n_matches, "agreed": self.agreed,
            "refined_pairs": self.refined_pairs, "keyframe_a": self.keyframe_a,
            "keyframe_b": self.keyframe_b, "revoked": self.revoked, "tests": self.tests,
            "landed": self.landed, "covered": self.covered,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Link:
        d = dict(d)
        d["T_a_b"] = np.array(d["T_a_b"], dtype=np.float64)
        d["covariance"] = np.array(d["covariance"], dtype=np.float64)
        return cls(**d)


@dataclass(frozen=True)
class Event:
    """Something that changed the fleet: kind in {"robot_joined", "link_accepted",
    "link_revoked", "link_held"}, the robots concerned, a sentence of detail; stamp = the
    keyframe's."""

    stamp: float
    kind: str
    robots: tuple[str, ...]
    detail: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"stamp": self.stamp, "kind": self.kind, "robots": list(self.robots),
                "detail": self.detail}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Event:
        return cls(float(d["stamp"]), d["kind"], tuple(d["robots"]), d.get("detail", ""))


@dataclass
class Attempt:
    """One localization attempt of robot `query` in robot `target`'s map (both names), the one
    record of a pairwise localization from the worker that ran it to `FleetResult.links`:
    `transform` = T_target_query when accepted, `covariance` its (6,6) covariance ([rx ry rz tx
    ty tz], rad and m, query frame; None when not accepted), `confidence` the acceptance
    test's, `n_matches` the inliers, `reason` why not accepted, `seconds` its wall time,
    `sizes` the objects of (query, target) it ran on. `used`: how `localize_fleet` used it
    ("tree" or "loop": kept, "dropped" by the loop check, "": not accepted; "" in a session).

    An accepted attempt becomes a `Link` of the session; `to_dict` leaves out `covariance`
    (the link keeps it) and `used` (a fleet result writes it), as earlier session files did."""

    query: str
    target: str
    stamp: float
    accepted: bool
    transform: np.ndarray | None
    confidence: float
    n_matches: int
    reason: str
    seconds: float
    sizes: tuple[int, int]  # confirmed objects of (query, target) at the attempt
    covariance: np.ndarray | None = None
    used: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "query": self.query, "target": self.target, "stamp": self.stamp,
            "accepted": self.accepted,
            "transform": None if self.transform is None else self.transform.tolist(),
            "confidence": self.confidence, "n_matches": self.n_matches, "reason": self.reason,
            "seconds": self.seconds, "sizes": list(self.sizes),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Attempt:
        d = dict(d)
        d["transform"] = None if d["transform"] is None else np.array(d["transform"], float)
        d["sizes"] = tuple(d["sizes"])
        if d.get("covariance") is not None:
            d["covariance"] = np.array(d["covariance"], float)
        return cls(**d)
