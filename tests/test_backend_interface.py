"""The fleet back-end interface (`sgloc.online.backend`): a back-end registered in BACKENDS
runs in the session, its saves and its g2o output unchanged, and the session, the replay and
its outputs never branch on a back-end's name."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from sgloc.geometry import make_transform
from sgloc.io.g2o import write_g2o
from sgloc.online import OnlineConfig, OnlineSession
from sgloc.online.backend import BACKENDS, SessionState
from sgloc.online.records import ROBOT_JOINED

SRC = Path(__file__).resolve().parents[1] / "src" / "sgloc"


class SharedFrame:
    """Robots whose odometry frames are one frame already (e.g. aligned by GNSS): every robot
    is placed at the identity, no attempt is ever made."""

    keyframe_vertices = False

    def __init__(self, state: SessionState) -> None:
        self.s = state

    links = property(lambda self: [])

    def active_pairs(self):
        return []

    def add_keyframe(self, robot):
        pass

    def plan(self, batch, due, in_flight, budget, growth, robot, scheduler, workers):
        batch.pairs = []

    def refits_due(self, batch):
        return False

    def apply(self, batch, results):
        return set(self.s.robots) != set(self.s.placed)  # a new robot: re-solve

    def refresh(self, stamp, emit):
        for r in self.s.robots:
            if r not in self.s.placed:
                self.s.emit(emit, stamp, ROBOT_JOINED, (r,), "shares the fleet frame")
        self.s.placed = {r: np.eye(4) for r in self.s.robots}

    def final_refinement_due(self):
        return False

    def trajectory(self, robot):
        return self.s.map_list()[robot].trajectory()[1]

    def keyframe_ids(self):
        return []

    def add_link(self, i, j, T_i_j, covariance, confidence, stamp):
        pass

    def set_root(self, robot):
        pass

    def state(self):
        return {"shared": sorted(self.s.placed)}, {}

    def load_state(self, meta, arrays):
        self.s.placed = {r: np.eye(4) for r in meta["shared"]}

    def write_g2o(self, path):
        return write_g2o(path, {k: np.eye(4) for k in range(len(self.s.placed))}, [])


@pytest.fixture
def shared_frame():
    BACKENDS.register("shared_frame")(SharedFrame)
    yield "shared_frame"
    del BACKENDS["shared_frame"]


def _keyframe(s: OnlineSession, robot: str, k: int) -> list:
    rng = np.random.default_rng(k)
    T = make_transform(np.eye(3), [2.0 * k, 0.0, 0.0])
    return s.add_keyframe(robot, float(k), T, rng.uniform(-10, 10, (6, 3)),
                          rng.integers(0, 3, 6))


def test_a_registered_back_end_runs_in_the_session_and_its_saves(shared_frame, tmp_path):
    s = OnlineSession(online=OnlineConfig(backend=shared_frame))
    kinds = [e.kind for k in range(3) for r in ("a", "b") for e in _keyframe(s, r, k)]
    s.finish("a"), s.finish("b")
    assert kinds.count(ROBOT_JOINED) == 2 and not s.attempts
    assert all(np.array_equal(T, np.eye(4)) for T in s.corrections().values())
    stamps, poses = s.trajectory("b")
    np.testing.assert_array_equal(poses, s.keyframes("b")[1])
    back = OnlineSession.load(s.save(tmp_path / "s.npz"))
    assert back.corrections().keys() == {"a", "b"} and back.online.backend == shared_frame
    assert "VERTEX_SE3:QUAT 1" in back.write_g2o(tmp_path / "g.g2o").read_text()


def test_an_unknown_back_end_names_the_registered_ones():
    with pytest.raises(Exception, match=r"keyframes.*robots"):
        OnlineConfig(backend="keyframe")


@pytest.mark.parametrize("module", ["online/session.py", "replay/outputs.py", "replay/job.py",
                                    "live/server.py", "online/store.py"])
def test_no_module_branches_on_a_back_end_name(module):
    tree = ast.parse((SRC / module).read_text())
    names = {"keyframes", "robots"}
    compared = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Compare)
                for c in [n.left, *n.comparators]
                if isinstance(c, ast.Constant) and c.value in names]
    reads = [n.lineno for n in ast.walk(tree)
             if isinstance(n, ast.Attribute) and n.attr == "backend"
             and isinstance(n.ctx, ast.Load) and not isinstance(n.value, ast.Name)]
    assert not compared, f"{module}: compares with a back-end's name at lines {compared}"
    assert module.startswith("replay/outputs") or not reads, \
        f"{module}: reads the back-end's name at lines {reads}"


@pytest.mark.parametrize("backend", ["keyframes", "robots"])
def test_a_session_without_keyframes_saves_and_resumes(backend, tmp_path):
    s = OnlineSession(online=OnlineConfig(backend=backend))
    back = OnlineSession.load(s.save(tmp_path / "empty.npz"))
    assert back.robots == [] and back.corrections() == {} and back.links == []
    back.add_keyframe("a", 0.0, np.eye(4), np.zeros((0, 3)), np.zeros(0, np.int64))
    assert back.corrections().keys() == {"a"}
