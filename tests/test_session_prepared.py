"""The online session's prepared maps: each robot's map is prepared once for the attempts
against it and kept until its objects change; attempts on them give what attempts on graphs
sent to worker processes give."""

import numpy as np
import pytest

import sgloc.online.robot_map as robot_map
from sgloc import lie, localize_fleet
from sgloc.evaluation.fleet_scenes import world_fleet
from sgloc.online import OnlineConfig, OnlineSession
from sgloc.online.robot_map import RobotMap
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.prepared import PreparedMap
from sgloc.sim.object_world import make_object_world


def test_a_robot_map_keeps_its_prepared_map_until_its_objects_change():
    rng = np.random.default_rng(0)
    pts, lab = rng.uniform(-20, 20, (12, 3)), rng.integers(0, 3, 12)
    m, cfg = RobotMap("r", 1.0, 1, 20.0), LocalizerConfig()
    m.add(0.0, np.eye(4), pts[:2], lab[:2])
    assert m.prepared(cfg) is m.graph()  # too small to prepare: the graph itself
    m.add(1.0, np.eye(4), pts, lab)
    assert m.prepared(cfg, uses=1) is m.graph()  # one attempt: preparing would not pay
    p = m.prepared(cfg)
    assert m.prepared(cfg, uses=1) is p  # kept: it serves every attempt
    assert isinstance(p, PreparedMap) and m.prepared(cfg) is p
    np.testing.assert_array_equal(p.graph.positions, m.graph().positions)
    m.add(2.0, np.eye(4), pts[:0], lab[:0])  # a keyframe that sees nothing
    assert m.prepared(cfg) is p
    m.add(3.0, np.eye(4), pts[:3] + 0.1, lab[:3])  # moves three objects
    q = m.prepared(cfg)
    assert q is not p
    np.testing.assert_array_equal(q.graph.positions, m.graph().positions)
    m.reanchor(m.anchors() + 0.0)  # no keyframe moved
    assert m.prepared(cfg) is q
    moved = m.anchors()
    moved[1, 0, 3] += 0.5
    m.reanchor(moved)
    assert m.prepared(cfg) is not q
    assert m.prepared(LocalizerConfig()) is not m.prepared(cfg)  # another config


def test_a_fleet_prepares_each_map_that_several_attempts_target_once(monkeypatch):
    made = []
    real = robot_map.prepare

    def counting(graph, config):
        made.append(graph.name)
        return real(graph, config)

    monkeypatch.setattr(robot_map, "prepare", counting)
    fleet = localize_fleet(world_fleet(2).graphs[:4], workers=0)
    assert len(fleet.links) == 6  # every pair once
    targets = [lk.target for lk in fleet.links]
    assert sorted(made) == sorted({t for t in targets if targets.count(t) >= 2})  # once each
    assert len(made) == 2  # robots 0 and 1 (3 and 2 attempts); robot 2's one attempt: its graph


def _street_keyframes(pos, lab, xs, seed, view=30.0, step=4.0):
    """A robot on the object world's main street from xs[0] to xs[1] (exact odometry from
    its first pose): keyframes (stamp, T_odom_sensor, positions in the sensor frame, labels)."""
    rng = np.random.default_rng(seed)
    n = int(abs(xs[1] - xs[0]) / step) + 1
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = lie.so3_exp([0, 0, 0.0 if xs[1] > xs[0] else np.pi])
    T[:, 0, 3] = np.linspace(xs[0], xs[1], n)
    frames = []
    for k, Tk in enumerate(T):
        keep = (np.linalg.norm(pos - Tk[:3, 3], axis=1) < view) & (rng.random(len(pos)) < 0.9)
        inv = lie.between(Tk, np.eye(4))
        seen = pos[keep] @ inv[:3, :3].T + inv[:3, 3] + rng.normal(0, 0.1, (int(keep.sum()), 3))
        frames.append((float(k), lie.between(T[0], Tk), seen, lab[keep]))
    return frames


@pytest.mark.parametrize("backend", ["robots", "keyframes"])
def test_attempts_on_prepared_maps_equal_attempts_in_worker_processes(backend, monkeypatch):
    pos, lab = make_object_world(np.random.default_rng(5), length=400.0)
    robots = {"a": _street_keyframes(pos, lab, (0.0, 240.0), 1),
              "b": _street_keyframes(pos, lab, (360.0, 120.0), 2),
              "c": _street_keyframes(pos, lab, (60.0, 300.0), 3)}
    sessions, made, real = {}, [], robot_map.prepare

    def counting(graph, config):
        made.append(graph.name)
        return real(graph, config)

    monkeypatch.setattr(robot_map, "prepare", counting)
    for workers in (0, 2):
        s = OnlineSession(online=OnlineConfig(backend=backend, min_observations=1,
                                               max_attempts=0))
        for k in range(len(robots["a"])):
            for name, frames in robots.items():
                s.add_keyframe(name, *frames[k])
            if k % 10 == 9:
                s.run_pending(workers=workers)
        sessions[workers] = s
    here, there = sessions[0], sessions[2]
    assert len(here.attempts) >= 3 and any(a.accepted for a in here.attempts)
    assert made  # in this process, some map was the target of several attempts at once
    for a, b in zip(here.attempts, there.attempts, strict=True):
        assert (a.query, a.target, a.accepted, a.n_matches, a.reason) == \
               (b.query, b.target, b.accepted, b.n_matches, b.reason)
        if a.accepted:
            np.testing.assert_array_equal(a.transform, b.transform)
            np.testing.assert_array_equal(a.covariance, b.covariance)
