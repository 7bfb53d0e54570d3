"""Join attempts between robots not yet joined: the whole map, and with `join_submaps` the
recent submap cut below the localizer's small-query size on every other try."""

import numpy as np

from sgloc.online import OnlineConfig, OnlineSession
from sgloc.online.keyframes.state import recent_start
from sgloc.online.robot_map import RobotMap


def test_recent_start_cuts_the_stretch_to_the_objects_seen_last():
    m = RobotMap("r", 1.0, 1, 20.0)
    for k in range(20):  # one new object per keyframe, 1 m apart
        T = np.eye(4)
        T[0, 3] = float(k)
        m.add(float(k), T, np.array([[0.0, 5.0 + 10.0 * k, 0.0]]), np.array([0]))
    assert recent_start(m, 100.0) == 0
    assert recent_start(m, 5.0) == 14
    first = recent_start(m, 100.0, 6)
    assert first == 14 and m.seen_since(first).sum() == 6
    assert recent_start(m, 3.0, 6) == 16  # the metres cut first


def _sizes(join_submaps, per_keyframe=3, n=80):
    s = OnlineSession(online=OnlineConfig(backend="keyframes", min_observations=1,
                                          loop_closures=False, join_submaps=join_submaps))
    ra, rb = np.random.default_rng(1), np.random.default_rng(2)
    for k in range(n):  # two robots in unrelated places, each object seen once
        for name, rng in (("a", ra), ("b", rb)):
            T = np.eye(4)
            T[0, 3] = 2.0 * k
            m = per_keyframe
            pts = np.column_stack([rng.uniform(-20, 20, m), rng.uniform(-20, 20, m),
                                   np.zeros(m)])
            s.add_keyframe(name, float(k), T, pts, np.zeros(m, np.int64))
    return [x.sizes[0] for x in s.attempts], s


def test_join_attempts_alternate_the_whole_map_and_a_small_recent_submap():
    sizes, s = _sizes(True)
    assert not any(x.accepted for x in s.attempts)
    small = s.config.acceptance.evidence.small_query
    whole, sub = np.array(sizes[0::2]), np.array(sizes[1::2])
    assert len(sub) >= 10
    assert (sub < small).all()  # verified against the whole map (a small query)
    assert (np.diff(whole) >= 0).all() and whole[-1] > 3 * small  # the whole maps as they grow
    off = np.array(_sizes(False)[0])
    grown = np.flatnonzero(off >= small)[0]
    assert (off[grown:] >= small).all()  # without: every attempt on the whole map


def test_a_dense_map_joins_on_its_whole_map():
    # each keyframe sees more objects than a small query holds: no submap of them is small
    on, _ = _sizes(True, per_keyframe=40, n=12)
    off, _ = _sizes(False, per_keyframe=40, n=12)
    assert len(on) >= 4 and on == off


def test_seen_per_keyframe_counts_each_confirmed_object_once_per_keyframe():
    from sgloc.online.keyframes.state import seen_per_keyframe

    m = RobotMap("r", 1.0, 2, 20.0)
    pts = np.array([[0.0, 5.0, 0.0], [0.0, 15.0, 0.0], [0.0, 25.0, 0.0]])
    for k, rows in enumerate([[0, 1], [0, 1, 2], [0], [2]]):
        m.add(float(k), np.eye(4), pts[rows], np.zeros(len(rows), np.int64))
    # objects 0, 1 and 2 are confirmed (two sightings each): per keyframe what it saw of them
    assert seen_per_keyframe(m, 0).tolist() == [2, 3, 1, 1]
    assert seen_per_keyframe(m, 2).tolist() == [1, 1]


def test_a_dense_map_with_a_gap_in_its_view_still_joins_on_its_whole_map():
    # 40 objects per keyframe, but every fourth keyframe sees 15 (a gap in the view): the
    # submap's typical keyframe sees more than a small query holds, so every join attempt
    # matches the whole map, as without submaps
    def sizes(join_submaps):
        s = OnlineSession(online=OnlineConfig(backend="keyframes", min_observations=1,
                                              loop_closures=False, join_submaps=join_submaps))
        ra, rb = np.random.default_rng(1), np.random.default_rng(2)
        for k in range(16):
            for name, rng in (("a", ra), ("b", rb)):
                T = np.eye(4)
                T[0, 3] = 2.0 * k
                m = 15 if k % 4 == 3 else 40
                pts = np.column_stack([rng.uniform(-20, 20, m), rng.uniform(-20, 20, m),
                                       np.zeros(m)])
                s.add_keyframe(name, float(k), T, pts, np.zeros(m, np.int64))
        return [x.sizes[0] for x in s.attempts]

    on, off = sizes(True), sizes(False)
    assert len(on) >= 4 and on == off
