"""Hostile calls and files for OnlineSession: a refused keyframe, link or saved file changes
nothing and is one clear SglocError; no single bad message stops the session from accepting good
ones; a resumed session is the saved one, bit for bit."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from sgloc.errors import DatasetError, SglocError
from sgloc.evaluation.replay_scenarios import world_scenario
from sgloc.io.keyframe_checks import ROTATION_TOLERANCE, check_rigid
from sgloc.io.keyframes import make_robot_log
from sgloc.online import OnlineConfig, OnlineSession
from sgloc.replay.stream import keyframe_order


@pytest.fixture(scope="module")
def world():
    return world_scenario()


def _stream(logs):
    """(robot, stamp, T_odom_sensor, positions, labels) of every keyframe, by stamp."""
    obs = [list(g.observations()) for g in logs]
    poses = [g.poses for g in logs]
    for r, k in keyframe_order(logs):
        _, pos, lab = obs[r][k]
        yield logs[r].name, float(logs[r].stamps[k]), poses[r][k], pos, lab


def _session(world, fraction=1.0, **online):
    s = OnlineSession(online=OnlineConfig(seed=0, **online))
    frames = list(_stream(world.logs))
    for f in frames[: int(len(frames) * fraction)]:
        s.add_keyframe(*f)
    return s, frames


def _rot(scale=1.0, mirror=False, yaw=0.3):
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:3, :3] = scale * np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    if mirror:
        T[2, 2] = -scale
    T[:3, 3] = (1.0, 2.0, 0.5)
    return T


BAD_POSES = {
    "scaled x2": _rot(2.0),
    "scaled x1.001": _rot(1.001),
    "mirrored": _rot(mirror=True),
    "zero rotation": np.diag([0.0, 0.0, 0.0, 1.0]),
    "sheared": _rot() + np.array([[0, 0.3, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]]),
    "bottom row": _rot() + np.array([[0, 0, 0, 0]] * 3 + [[0, 0, 1.0, 0]]),
    "translation 1e8 m": np.array([[1, 0, 0, 1e8], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]),
    "NaN": np.full((4, 4), np.nan),
    "shape": np.eye(3),
}


def _state(s: OnlineSession, timings: bool = True) -> str:
    """Everything a session holds, as text (a refused call must leave it unchanged); without
    `timings`, the attempts' wall times left out."""
    meta, arrays = s.to_state()
    if not timings:
        for a in meta["attempts"]:
            a.pop("seconds")
    return json.dumps(meta, sort_keys=True) + repr(sorted((k, v.tobytes()) for k, v in
                                                          arrays.items()))


def test_rigid_check_accepts_float32_rotations_and_refuses_non_rigid_ones():
    R = _rot(yaw=1.234).astype(np.float32).astype(np.float64)
    assert np.abs(R[:3, :3].T @ R[:3, :3] - np.eye(3)).max() < ROTATION_TOLERANCE / 100
    check_rigid("x", R)
    for name, T in BAD_POSES.items():
        with pytest.raises(SglocError, match="x: "):
            check_rigid("x", T)
        assert name


@pytest.mark.parametrize("bad", sorted(BAD_POSES))
def test_a_non_rigid_pose_is_refused_and_changes_nothing(world, bad):
    s, frames = _session(world, 0.5)
    before = _state(s)
    robot, stamp, _, pos, lab = frames[len(frames) // 2]
    with pytest.raises(SglocError, match=f"robot {robot!r}"):
        s.add_keyframe(robot, stamp, BAD_POSES[bad], pos, lab)
    assert _state(s) == before
    with pytest.raises(SglocError, match="add_link"):
        s.add_link("world0", "world1", BAD_POSES[bad], np.eye(6) * 0.01)
    assert _state(s) == before


@pytest.mark.parametrize("step", [0.0, -0.5, -1e9])
def test_stamps_that_repeat_or_go_back_are_refused_like_the_file_readers_do(world, step):
    s, frames = _session(world, 0.3)
    before = _state(s)
    robot, stamp, T, pos, lab = frames[int(len(frames) * 0.3) - 1]
    with pytest.raises(SglocError, match="does not come after the one before"):
        s.add_keyframe(robot, stamp + step, T, pos, lab)
    assert _state(s) == before
    # The plain-layout / bag reader refuses the same stamps with the same rule.
    with pytest.raises(DatasetError, match="does not come after the one before"):
        make_robot_log("r", [10, 10 + int(step * 1e9)], np.zeros((2, 3)),
                       [[0, 0, 0, 1.0]] * 2, [], np.zeros((0, 3)), [])


def test_a_refused_first_keyframe_registers_no_robot(tmp_path):
    s = OnlineSession()
    with pytest.raises(SglocError):
        s.add_keyframe("ghost", 0.0, BAD_POSES["scaled x2"], np.zeros((3, 3)), [0, 1, 2])
    with pytest.raises(SglocError):
        s.add_keyframe("ghost2", 0.0, np.eye(4), np.zeros((3, 4)), [0, 1, 2])
    assert s.robots == [] and s.root is None
    s.add_keyframe("real", 0.0, np.eye(4), np.zeros((0, 3)), [])
    assert s.robots == ["real"] and s.root == "real"
    resumed = OnlineSession.load(s.save(tmp_path / "s.npz"))
    assert resumed.robots == ["real"] and resumed.root == "real"


def _bad_keyframes(robot, stamp, pos, lab):
    """Keyframes of `robot` (its next good one: stamp, pos, lab) that must each be refused."""
    far = np.eye(4)
    far[0, 3] = 9.9e6  # within the limit itself, but puts the sightings beyond +-1e7 m
    many = np.column_stack([np.arange(70.0), np.zeros(70), np.zeros(70)])
    return {
        "detections beyond 1e7 m": (robot, stamp, far, pos + [2e5, 0, 0], lab),
        "NaN stamp": (robot, float("nan"), np.eye(4), pos, lab),
        "stamp 1e30": (robot, 1e30, np.eye(4), pos, lab),
        "stamp as text": (robot, "soon", np.eye(4), pos, lab),
        "scaled pose": (robot, stamp, BAD_POSES["scaled x2"], pos, lab),
        "repeated stamp": (robot, -1e9, np.eye(4), pos, lab),
        "NaN position": (robot, stamp, np.eye(4), np.full((1, 3), np.nan), [1]),
        "negative class": (robot, stamp, np.eye(4), pos[:1], [-1]),
        "labels do not match": (robot, stamp, np.eye(4), pos, lab[:-1]),
        "70 classes in the map": (robot, stamp, np.eye(4), many, np.arange(70) + 100),
        "empty name": ("", stamp, np.eye(4), pos, lab),
    }


def test_no_bad_keyframe_stops_the_session_taking_good_ones(world):
    s, frames = _session(world, 0.6)
    rest = frames[int(len(frames) * 0.6):]
    kinds = None
    for n, good in enumerate(rest):
        robot, stamp, _, pos, lab = good
        bad = _bad_keyframes(robot, stamp, pos, lab)
        kinds = kinds or sorted(bad)
        name = kinds[n % len(kinds)]
        before = _state(s)
        with pytest.raises(SglocError):
            s.add_keyframe(*bad[name])
        assert _state(s) == before, name
        s.add_keyframe(*good)  # every robot's next good keyframe is still taken
    assert len(rest) > 2 * len(kinds)
    # ... and the session ends where one fed only the good keyframes ends.
    clean, _ = _session(world)
    for r in clean.robots:
        np.testing.assert_array_equal(s.T_fleet_robot(r), clean.T_fleet_robot(r))
    assert s.events == clean.events


def test_bad_links_and_stamps_of_other_calls_are_refused(world):
    s, _ = _session(world, 0.5)
    before = _state(s)
    T = np.eye(4)
    for cov, conf in ((np.full((6, 6), np.nan), 1.0), (-np.eye(6), 1.0), (np.eye(6) * 1e300, 1.0),
                      (np.eye(6) + np.triu(np.ones((6, 6)), 1), 1.0), (np.eye(6), 1.5),
                      (np.eye(6), float("nan")), (np.eye(5), 1.0)):
        with pytest.raises(SglocError, match="add_link"):
            s.add_link("world0", "world1", T, cov, conf)
    with pytest.raises(SglocError, match="stamp"):
        s.add_link("world0", "world1", T, np.eye(6), 1.0, stamp=float("inf"))
    with pytest.raises(SglocError, match="stamp"):
        s.run_pending("later")
    with pytest.raises(SglocError, match="stamp"):
        s.set_root("world1", float("nan"))
    assert _state(s) == before


@pytest.mark.parametrize("online", [{"backend": "robots"},
                                    {"backend": "keyframes", "solver": "scipy"}])
def test_a_resumed_session_is_the_saved_one_bit_for_bit(world, tmp_path, online):
    """Saved after every 7th keyframe and loaded: the same frames, links and maps at once, and
    fed the rest of the keyframes, the same events and frames as the session never saved."""
    s = OnlineSession(online=OnlineConfig(seed=0, **online))
    frames = list(_stream(world.logs))
    resumed_runs = []
    for n, f in enumerate(frames):
        s.add_keyframe(*f)
        if n % 7 == 3:
            r = OnlineSession.load(s.save(tmp_path / f"s{n}.npz"))
            assert _state(r) == _state(s)
            for robot in s.robots:
                a, b = s.T_fleet_robot(robot), r.T_fleet_robot(robot)
                assert (a is None and b is None) or np.array_equal(a, b)
            resumed_runs.append((n, r))
    assert sum(s.T_fleet_robot(r) is not None for r in s.robots) == 2
    for n, r in resumed_runs[::3]:
        for f in frames[n + 1:]:
            r.add_keyframe(*f)
        assert r.events == s.events and _state(r, False) == _state(s, False)


def test_a_resumed_isam2_session_continues_to_the_same_frames(world, tmp_path):
    """ISAM2 keeps an incremental state a save file does not hold (its own linearization
    points and elimination order): resumed, it starts again from the saved solution, so it
    gives the same events and the same frames to well under a millimetre, not bit for bit."""
    pytest.importorskip("gtsam")
    s = OnlineSession(online=OnlineConfig(seed=0, solver="gtsam"))
    frames = list(_stream(world.logs))
    half = len(frames) // 2
    for f in frames[:half]:
        s.add_keyframe(*f)
    r = OnlineSession.load(s.save(tmp_path / "s.npz"))
    assert _state(r) == _state(s)
    for f in frames[half:]:
        s.add_keyframe(*f)
        r.add_keyframe(*f)
    assert r.events == s.events and len(r.attempts) == len(s.attempts)
    for robot in s.robots:
        np.testing.assert_allclose(r.trajectory(robot)[1], s.trajectory(robot)[1], atol=1e-6)


def _edit_meta(src, dst, edit):
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays.pop("meta")))
    edit(meta, arrays)
    np.savez(dst, meta=np.array(json.dumps(meta)), **arrays)


def _scale_pose(m, a):
    a["map0_poses"] = a["map0_poses"] * 2


def _back_stamp(m, a):
    a["map1_stamps"] = a["map1_stamps"][::-1].copy()


def _mirror_link(m, a):
    m["links"][0][2]["T_a_b"][2][2] = -1.0


def _kf_link(edit):
    def apply(m, a):
        edit(m["keyframes"]["links"][0])
    return apply


EDITS = {
    "keyframe link to no robot": _kf_link(lambda d: d.update(robot_b="nobody")),
    "keyframe link past the keyframes": _kf_link(lambda d: d.update(keyframe_a=10**6)),
    "mirrored keyframe link": _kf_link(lambda d: d["T_a_b"][2].__setitem__(2, -1.0)),
    "graph factor past the keyframes": lambda m, a: a["kg_ends"].__setitem__((0, 1), 10**6),
    "robots list shortened": lambda m, a: m.update(robots=m["robots"][:1]),
    "robots list grown": lambda m, a: m.update(robots=[*m["robots"], "extra"]),
    "robots not names": lambda m, a: m.update(robots=[1, 2]),
    "robot named twice": lambda m, a: m.update(robots=[m["robots"][0]] * 2),
    "link to no robot": lambda m, a: m["links"][0].__setitem__(1, 7),
    "attempt pair out of range": lambda m, a: m.update(last=[[0, 9, 1, 1]]),
    "scaled keyframe pose": _scale_pose,
    "stamps going back": _back_stamp,
    "mirrored link": _mirror_link,
    "placed robot out of range": lambda m, a: m.update(placed=[0, 5]),
    "events not records": lambda m, a: m.update(events=[1, 2]),
    "no config": lambda m, a: m.pop("config"),
}


#: Edits of the back-end "robots"'s links (one per robot pair, between odometry frames).
ROBOTS_EDITS = {"link to no robot", "mirrored link"}


@pytest.fixture(scope="module")
def saved(world, tmp_path_factory):
    s, _ = _session(world)
    assert s.links
    return s.save(tmp_path_factory.mktemp("saved") / "s.npz")


@pytest.fixture(scope="module")
def saved_robots(world, tmp_path_factory):
    s, _ = _session(world, backend="robots")
    assert s.links
    return s.save(tmp_path_factory.mktemp("saved_robots") / "s.npz")


@pytest.mark.parametrize("edit", sorted(EDITS))
def test_an_edited_save_file_is_one_clear_error_naming_it(saved, saved_robots, tmp_path, edit):
    bad = tmp_path / "edited.npz"
    _edit_meta(saved_robots if edit in ROBOTS_EDITS else saved, bad, EDITS[edit])
    with pytest.raises(SglocError, match=f"^{bad}: "):
        OnlineSession.load(bad)


@pytest.mark.parametrize("keep", [0.1, 0.5, 0.9, 0.999])
def test_a_truncated_save_file_is_one_clear_error_naming_it(saved, tmp_path, keep):
    raw = saved.read_bytes()
    bad = tmp_path / "cut.npz"
    bad.write_bytes(raw[: int(len(raw) * keep)])
    with pytest.raises(SglocError, match=f"^{bad}: .*truncated"):
        OnlineSession.load(bad)


def test_a_save_file_with_a_damaged_member_is_one_clear_error(saved, tmp_path):
    bad = tmp_path / "flipped.npz"
    raw = bytearray(saved.read_bytes())
    with zipfile.ZipFile(saved) as z:
        info = z.getinfo("map0_sums.npy")
    at = info.header_offset + 30 + len(info.filename) + info.compress_size // 2
    raw[at] ^= 0xFF
    bad.write_bytes(bytes(raw))
    with pytest.raises(SglocError, match=f"^{bad}: "):
        OnlineSession.load(bad)
