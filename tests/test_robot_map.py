"""RobotMap keeps who saw what: sightings with their keyframe and sensor-frame position, and
objects that follow a corrected trajectory."""

import numpy as np
import pytest

from sgloc import lie
from sgloc.errors import SglocError
from sgloc.online.robot_map import RobotMap


def _map_of_two_keyframes():
    m = RobotMap("r", radius=1.0, min_observations=1, edge_radius=20.0)
    T0, T1 = np.eye(4), lie.se3_exp([0, 0, 0.1, 5.0, 0.0, 0.0])
    objects = np.array([[10.0, 2.0, 0.0], [12.0, -3.0, 1.0], [30.0, 0.0, 0.0]])
    m.add(0.0, T0, objects[:2], np.array([1, 2]))
    seen1 = np.linalg.inv(T1)[:3, :3] @ objects[1:].T + np.linalg.inv(T1)[:3, 3:]
    m.add(1.0, T1, seen1.T, np.array([2, 3]))
    return m, T0, T1, objects


def test_sightings_keep_their_keyframe_sensor_position_and_object():
    m, T0, T1, objects = _map_of_two_keyframes()
    k, p, o = m.sightings()
    assert k.tolist() == [0, 0, 1, 1] and o.tolist() == [0, 1, 1, 2]
    np.testing.assert_allclose(p[:2], objects[:2])
    np.testing.assert_allclose(p[2:] @ T1[:3, :3].T + T1[:3, 3], objects[1:], atol=1e-12)
    np.testing.assert_allclose(m.graph().positions, objects, atol=1e-12)


def test_a_corrected_trajectory_moves_the_objects_exactly():
    m, T0, T1, objects = _map_of_two_keyframes()
    C1 = lie.se3_exp([0, 0, -0.2, 4.0, 1.0, 0.0])  # keyframe 1 corrected
    assert m.reanchor(np.stack([T0, C1])) == 1
    k, p, _ = m.sightings()
    from_1 = p[2:] @ C1[:3, :3].T + C1[:3, 3]
    expected = np.array([objects[0], (objects[1] + from_1[0]) / 2, from_1[1]])
    np.testing.assert_allclose(m.graph().positions, expected, atol=1e-12)
    # Moving both keyframes by one rigid transform moves the whole map by it.
    G = lie.se3_exp([0.0, 0.0, 0.5, -3.0, 7.0, 1.0])
    assert m.reanchor(G @ np.stack([T0, C1])) == 2
    np.testing.assert_allclose(m.graph().positions, expected @ G[:3, :3].T + G[:3, 3],
                               atol=1e-9)
    assert m.reanchor(m.anchors()) == 0
    assert m.seen_since(1).tolist() == [False, True, True]
    assert len(m.subgraph(~m.seen_since(1)).positions) == 1
    np.testing.assert_allclose(m.travelled(), [0.0, np.linalg.norm(T1[:3, 3])])
    with pytest.raises(SglocError, match="reanchor"):
        m.reanchor(np.eye(4)[None])


def test_state_restores_sightings_and_anchors():
    m, T0, T1, _ = _map_of_two_keyframes()
    m.reanchor(np.stack([T0, lie.se3_exp([0, 0, 0.05, 5.0, 0.5, 0.0])]))
    r = RobotMap("r", radius=1.0, min_observations=1, edge_radius=20.0)
    r.set_state(m.state())
    for a, b in zip(m.sightings(), r.sightings(), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(r.anchors(), m.anchors())
    np.testing.assert_array_equal(r.graph().positions, m.graph().positions)
    C = np.stack([T0, T1])
    m.reanchor(C)
    r.reanchor(C)
    np.testing.assert_array_equal(r.graph().positions, m.graph().positions)
