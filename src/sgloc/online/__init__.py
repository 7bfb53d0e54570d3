"""Online fleet localization: robots' maps grow keyframe by keyframe; the session localizes
robot pairs as their maps grow and keeps one fleet frame over the mutually consistent links.

    from sgloc.online import OnlineSession
    s = OnlineSession(root="r1")
    events = s.add_keyframe("r1", stamp, T_odom_sensor, positions, labels)
    s.T_fleet_robot("r2")   # (4,4) r2's odometry frame -> fleet frame, or None
"""

from sgloc.online.config import OdometryNoise, OnlineConfig
from sgloc.online.records import Event, Link
from sgloc.online.session import OnlineSession

__all__ = ["Event", "Link", "OdometryNoise", "OnlineConfig", "OnlineSession"]
