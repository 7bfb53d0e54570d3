"""The keyframe back-end's attempt planning (`KeyframeState.due_by_travel`, `directions`,
`ordered`, vectorised) against plain-Python references of the same rules, on random states."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.online import OnlineConfig
from sgloc.online.keyframes.state import KeyframeState


def _moved(f, t, q, trav, never=np.inf):
    if (t, q) in f.query_last:
        return trav[q] - f.query_last[(t, q)]
    i, j = min(t, q), max(t, q)
    if (i, j) not in f.travel_last:
        return trav[q] - never if np.isfinite(never) else never
    return trav[q] - f.travel_last[(i, j)][0 if q == i else 1]


def _due_ref(f, trav, sizes, min_objects, robot):
    step, scored = f.online.submap_length / 2, []
    for j in range(len(sizes)):
        for i in range(j + 1):
            if sizes[i] < min_objects or sizes[j] < min_objects or robot not in (None, i, j):
                continue
            if i == j and not f.online.loop_closures:
                continue
            m = max(_moved(f, t, q, trav, 0.0) for t, q in ((i, j), (j, i)))
            if m >= step:
                scored.append(((i, j) not in f.travel_last, m, i, j))
    scored.sort(key=lambda x: (not x[0], -x[1], x[2], x[3]))
    return [(i, j) for _, _, i, j in scored]


def _directions_ref(f, pairs, trav, finishing):
    step, out = f.online.submap_length / 2, []
    for i, j in pairs:
        if i == j:
            out.append((i, i))
            continue
        both = [(t, q) for t, q in ((i, j), (j, i))
                if (m := _moved(f, t, q, trav)) >= step or (q == finishing and m > 0)]
        if not both:
            prev = f.travel_last.get((i, j), (0.0, 0.0))
            both = [(i, j) if trav[j] - prev[1] >= trav[i] - prev[0] else (j, i)]
        out += both
    return out


def _ordered_ref(f, attempts, trav, group):
    def since(t, q):
        prev = f.travel_last.get((min(t, q), max(t, q)))
        return np.inf if prev is None else trav[q] - prev[0 if q == min(t, q) else 1]

    rank = [sorted(((t, q), (q, t)), key=lambda d: (-since(*d), -d[1])).index((t, q))
            for t, q in attempts]
    keys = sorted(range(len(attempts)), key=lambda k: (
        bool(group[attempts[k][0]] == group[attempts[k][1]]), rank[k],
        -max(since(*attempts[k]), since(*attempts[k][::-1])), k))
    return [attempts[k] for k in keys]


@pytest.mark.parametrize("seed", range(12))
def test_planning_matches_its_plain_reference(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 14))
    f = KeyframeState(OnlineConfig(submap_length=float(rng.choice([20.0, 60.0]))))
    trav = list(np.round(rng.uniform(0, 300, n), int(rng.integers(0, 3))))
    for i in range(n):
        for j in range(i, n):
            if rng.random() < 0.5:  # ties on purpose: coarse rounding
                f.travel_last[(i, j)] = tuple(np.round(rng.uniform(0, 1, 2) * [trav[i], trav[j]],
                                                       0))
            for t, q in ((i, j), (j, i)):
                if rng.random() < 0.3:
                    f.query_last[(t, q)] = float(np.round(rng.uniform(0, trav[q]), 0))
    sizes = list(rng.integers(0, 30, n))
    robot = None if rng.random() < 0.6 else int(rng.integers(0, n))
    due = f.due_by_travel(trav, sizes, 10, robot)
    assert due == _due_ref(f, trav, sizes, 10, robot)
    finishing = None if rng.random() < 0.5 else int(rng.integers(0, n))
    pairs = [(i, j) for i in range(n) for j in range(i, n) if rng.random() < 0.5]
    att = f.directions(pairs, trav, finishing)
    assert att == _directions_ref(f, pairs, trav, finishing)
    group = rng.integers(0, 3, n)
    assert f.ordered(att, trav, group) == _ordered_ref(f, att, trav, group)
