"""The session's batch surface (plan_attempts -> run_batch -> apply_attempts, corrections,
revision): the same fleet as add_keyframe's own attempts, bit for bit, and planning leaves no
trace until applied."""

from __future__ import annotations

import json
import pickle
from dataclasses import replace

import numpy as np
import pytest

from sgloc.evaluation.replay_scenarios import city_scenario
from sgloc.online import OnlineConfig, OnlineSession
from sgloc.online.batch import AttemptBatch, run_batch
from sgloc.pipeline.presets import localizer_preset
from sgloc.replay.stream import keyframe_order, replay_logs


@pytest.fixture(scope="module")
def city():
    return city_scenario(4, 0).logs, localizer_preset("city-objects")


def _keyframes(logs):
    """(robot, stamp, T, positions, labels, last keyframe of the robot) in replay order."""
    obs = [list(g.observations()) for g in logs]
    for r, k in keyframe_order(logs):
        g = logs[r]
        _, pos, lab = obs[r][k]
        yield g.name, float(g.stamps[k]), g.poses[k], pos, lab, k == len(g) - 1


def _batched(logs, config, backend, pickled=True):
    """The replay's fleet driven through plan/run/apply: ingest only, then the same budget."""
    budget = OnlineConfig().max_attempts
    s = OnlineSession(config, OnlineConfig(backend=backend, max_attempts=0))
    revisions = [s.revision]
    for robot, stamp, T, pos, lab, last in _keyframes(logs):
        s.add_keyframe(robot, stamp, T, pos, lab)
        for kw in ({"max_attempts": budget}, {"finishing": robot} if last else None):
            if kw is None:
                continue
            batch = s.plan_attempts(stamp, **kw)
            if batch is None:
                continue
            sent = pickle.loads(pickle.dumps(batch)) if pickled else batch
            s.apply_attempts(batch, run_batch(sent, config))
        revisions.append(s.revision)
    return s, revisions


def _state(s):
    meta, arrays = s.to_state()
    meta = dict(meta)
    meta.pop("online")
    for a in meta["attempts"]:
        a.pop("seconds")
    return json.dumps(meta, sort_keys=True), arrays


@pytest.mark.parametrize("backend", ["keyframes", "robots"])
def test_plan_run_apply_gives_the_add_keyframe_fleet_to_the_bit(city, backend):
    logs, config = city
    ref = OnlineSession(config, OnlineConfig(backend=backend))
    replay_logs(logs, ref)
    got, revisions = _batched(logs, config, backend)
    (m1, a1), (m2, a2) = _state(ref), _state(got)
    assert m1 == m2
    assert a1.keys() == a2.keys() and all(np.array_equal(a1[k], a2[k]) for k in a1)
    c1, c2 = ref.corrections(), got.corrections()
    assert len(c1) == len(logs) and c1.keys() == c2.keys()
    assert all(np.array_equal(c1[r], c2[r]) for r in c1)
    assert all(np.array_equal(c1[r], ref.T_fleet_robot(r)) for r in c1)
    # the revision moved with the frame, and only then
    assert revisions == sorted(revisions) and revisions[-1] >= 2


def test_a_batch_pickles_without_the_session(city):
    logs, config = city
    s = OnlineSession(config, OnlineConfig(max_attempts=0))
    for robot, stamp, T, pos, lab, _ in _keyframes(logs):
        s.add_keyframe(robot, stamp, T, pos, lab)
    batch = s.plan_attempts()
    assert isinstance(batch, AttemptBatch) and len(batch) > 0
    data = pickle.dumps(batch)
    assert b"OnlineSession" not in data and b"RobotMap" not in data
    back = pickle.loads(data)
    r1, r2 = run_batch(batch, config), run_batch(back, config)
    assert [(a.accepted, a.n_matches) for a in r1] == [(a.accepted, a.n_matches) for a in r2]


def test_pairs_in_flight_are_not_planned_again_until_applied(city):
    logs, config = city
    s = OnlineSession(config, OnlineConfig(max_attempts=0))
    for robot, stamp, T, pos, lab, _ in _keyframes(logs):
        s.add_keyframe(robot, stamp, T, pos, lab)
    first = s.plan_attempts(max_attempts=2)
    assert first is not None and first.pairs
    second = s.plan_attempts()
    planned = set() if second is None else set(second.pairs)
    assert not planned & set(first.pairs)
    with pytest.raises(Exception, match="results"):
        s.apply_attempts(first, [])
    s.apply_attempts(first, run_batch(first, config))
    if second is not None:
        s.apply_attempts(second, run_batch(second, config))
    assert len(s.attempts) == len(first) + (0 if second is None else len(second))


def test_to_state_with_a_batch_in_flight_is_as_if_never_planned(city):
    logs, config = city
    s = OnlineSession(config, OnlineConfig(max_attempts=0))
    for robot, stamp, T, pos, lab, _ in _keyframes(logs):
        s.add_keyframe(robot, stamp, T, pos, lab)
    before = _state(s)
    batch = s.plan_attempts()
    assert batch is not None and len(batch) > 0
    after = _state(s)
    assert before[0] == after[0]
    assert all(np.array_equal(before[1][k], after[1][k]) for k in before[1])
    # a session resumed from it plans the same attempts again
    again = OnlineSession.from_state(*s.to_state()).plan_attempts()
    assert again.pairs == batch.pairs and [t[2] for t in again.tasks] == \
        [t[2] for t in batch.tasks]


def test_a_batch_applied_after_more_keyframes_still_links(city):
    """Async use: keyframes keep coming while a batch runs; its links come from the maps as
    they were planned."""
    logs, config = city
    s = OnlineSession(config, replace(OnlineConfig(), max_attempts=0))
    pending = None
    for robot, stamp, T, pos, lab, _ in _keyframes(logs):
        s.add_keyframe(robot, stamp, T, pos, lab)
        if pending is not None:
            s.apply_attempts(pending, run_batch(pending, config))
        pending = s.plan_attempts(stamp, max_attempts=2)
    if pending is not None:
        s.apply_attempts(pending, run_batch(pending, config))
    assert any(lk.active for lk in s.links)
    assert len(s.corrections()) >= 2
